"""The depth sensor's tilt of each keyframe, as a variable of the graph.

A depth sensor's systematic error includes a field linear across and down the image that
grows as z^2 (a disparity error; `bimgraph.sim.render.systematic_depth_error`), drawn anew
per frame. It tilts every plane fitted to that frame's depth, all by one cause: the planes of
a keyframe err together (two walls' whitened yaw errors correlate 0.70 on the simulated
office), which independent plane factors cannot express, and online the extrinsic came out
centimetres off under a covariance that claimed millimetres (docs/experiments.md, twenty-third
session). So each keyframe whose planes came from its own depth image gets the two tilt
coefficients `tau_k = (t1, t2)` (in metres of depth error per squared metre of depth, at the
image's border) as a variable with a prior of the sensor's sigma, and each of its plane
observations sees the landmark moved by that tilt.

The tilt moves a plane exactly, whatever pixels it was fitted to: in inverse depth a plane
is linear, `1/z = m . (x_n, y_n, 1)` with `m = -n/d`, and the depth error `(t1 x + t2 y) z^2`
(x, y from -1 to 1 across the image) is the inverse-depth error `-(t1 x + t2 y)`, itself
linear in the normalised image coordinates `(x_n, y_n)`. `tilt_sensitivity` is the
resulting `d(n, d)/d(tau)`; it needs the camera's intrinsics, not the pixels.

In the graph the observation keeps gtsam's C++ factor, with the landmark's anchor replaced by
a pose of its own (`MOVED_ANCHOR(i)`): the anchor as keyframe k's tilted depth saw it, which a
linear factor ties to the anchor, `MOVED_ANCHOR(i) = X(A) * Exp(K tau_k)`, `K` the smallest
motion of the anchor that moves the predicted plane as the tilt does, taken where the
landmark stood when the observation came. A pose, not an auxiliary plane: a linear factor
keeps its Jacobian in the tangent of its linearisation point, and gtsam's `Unit3` basis
turns by 90 degrees where the two smallest components of a normal swap (a wall seen face-on,
normal (0.002, 0.001, -1)), so that a linear tie between two planes, crossed there, steered
Gauss-Newton sideways and left the ties violated by tens of sigma; a pose's tangent turns
smoothly. A Python factor on (pose, anchor, landmark, tilt) does the same at 25 times the
time (measured on the simulated office): gtsam copies every variable into each of its calls.
"""

from __future__ import annotations

import gtsam
import numpy as np

from bimgraph.sequence.format import Camera

TILT = gtsam.symbol_shorthand.T
MOVED_ANCHOR = gtsam.symbol_shorthand.M
# the tie is a constraint, not a measurement: tight against any plane's sigma (0.01 deg, 0.1
# mm at the floor), loose enough to keep iSAM2's system well conditioned
_LINK_SIGMA = 1e-4


def inverse_depth_sensitivity(camera: Camera) -> np.ndarray:
    """3x2: how the tilt `(t1, t2)` moves a plane's inverse-depth coefficients `m = -n/d`."""
    hw, hh = (camera.width - 1) / 2, (camera.height - 1) / 2  # (x = -1 at pixel 0, 1 at the last)
    return -np.array([[camera.fx / hw, 0.0], [0.0, camera.fy / hh],
                      [(camera.cx - hw) / hw, (camera.cy - hh) / hh]])


def tilt_sensitivity(plane_C: np.ndarray, dm_dtau: np.ndarray) -> np.ndarray:
    """4x2: `d(n, d)/d(t1, t2)` of the plane `plane_C` (unit normal, d > 0) fitted to a depth
    image, from `inverse_depth_sensitivity`."""
    m = -np.asarray(plane_C[:3], dtype=float) / plane_C[3]
    r = np.linalg.norm(m)
    # n = -m/|m|, d = 1/|m|
    dn_dm = -(np.eye(3) / r - np.outer(m, m) / r**3)
    dd_dm = -m / r**3
    return np.vstack([dn_dm, dd_dm]) @ dm_dtau


class DepthTilt:
    """The tilt variable's prior and links, for planes from depth images of this camera."""

    def __init__(self, camera: Camera, sigma_per_m: float):
        self.dm_dtau = inverse_depth_sensitivity(camera)
        self.prior_noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_per_m)
        self.link_noise = gtsam.noiseModel.Isotropic.Sigma(6, _LINK_SIGMA)

    def prior(self, k: int) -> gtsam.NonlinearFactor:
        return gtsam.PriorFactorVector(TILT(k), np.zeros(2), self.prior_noise)

    def anchor_step(self, plane_C: np.ndarray, dplane_dA: np.ndarray) -> np.ndarray:
        """6x2: the smallest motion of the landmark's anchor (in its tangent) that moves the
        predicted `plane_C` as the tilt does; `dplane_dA` (4x6) is the prediction's Jacobian in
        the anchor (`factors.predict_local_plane`)."""
        return np.linalg.pinv(dplane_dA) @ tilt_sensitivity(plane_C, self.dm_dtau)

    def link(self, key_anchor: int, key_moved: int, k: int, T_S_A: gtsam.Pose3, dplane_dA: np.ndarray,
             plane_C: np.ndarray) -> gtsam.NonlinearFactor:
        """The factor `moved = anchor * Exp(K tau_k)` of keyframe k's observation `plane_C`,
        linearised at the anchor's pose `T_S_A` (also the moved anchor's starting value)."""
        point = gtsam.Values()
        point.insert(key_anchor, T_S_A)
        point.insert(key_moved, T_S_A)
        point.insert(TILT(k), np.zeros(2))
        K = self.anchor_step(plane_C, dplane_dA)
        linear = gtsam.JacobianFactor(key_anchor, -np.eye(6), key_moved, np.eye(6), TILT(k), -K, np.zeros(6), self.link_noise)
        return gtsam.LinearContainerFactor(linear, point)


def without_tilt(values: gtsam.Values) -> gtsam.Values:
    """`values` without tilt variables and moved anchors, for a graph built without them (the
    offline rounds': measured offline, the tilt variable gains nothing, at 8-10x the time)."""
    for key in values.keys():
        if gtsam.Symbol(key).chr() in (ord("t"), ord("m")):
            values.erase(key)
    return values
