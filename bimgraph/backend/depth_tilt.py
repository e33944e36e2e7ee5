"""The depth sensor's tilt of each keyframe, as a variable of the graph.

The depth sensor's tilt (a depth error linear across and down the image, growing as z^2,
drawn anew per frame; `factors.depth_tilt`) moves every plane fitted to that frame's depth, all
by one cause: the planes of a keyframe err together (two walls' whitened yaw errors correlate
0.70 on the simulated office), which independent plane factors cannot express, and online the
extrinsic came out centimetres off under a covariance that claimed millimetres
(docs/experiments.md, twenty-third and twenty-fourth sessions). So each keyframe whose planes
came from its own depth image gets the two tilt coefficients `TILT(k)` as a variable with a
prior of the sensor's sigma, and each of its plane observations sees the landmark from a moved
copy of its anchor, `MOVED_ANCHOR(i)`, that the tilt moves. A Python factor on (pose, anchor,
landmark, tilt) does the same at 25 times the time (measured on the simulated office): gtsam
copies every variable into each of its calls.
"""

from __future__ import annotations

import gtsam
import numpy as np

from bimgraph.backend.graph import MOVED_ANCHOR, TILT, FactorBuilder, L, X
from bimgraph.geometry import normalise_plane
from bimgraph.sequence.format import Camera
from factors import anchor_step, inverse_depth_sensitivity, predict_local_plane, tilt_link_factor

_SYMBOLS = {gtsam.Symbol(TILT(0)).chr(), gtsam.Symbol(MOVED_ANCHOR(0)).chr()}
# the tie is a constraint, not a measurement: tight against any plane's sigma (0.01 deg, 0.1
# mm at the floor), loose enough to keep iSAM2's system well conditioned
_LINK_SIGMA = 1e-4


class DepthTilt:
    """The tilt variable's prior and ties, for planes from depth images of this camera."""

    def __init__(self, camera: Camera, sigma_per_m: float):
        self.sigma_per_m = sigma_per_m
        self.dm_dtau = inverse_depth_sensitivity(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        self.prior_noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_per_m)
        self.link_noise = gtsam.noiseModel.Isotropic.Sigma(6, _LINK_SIGMA)

    def prior(self, k: int) -> gtsam.NonlinearFactor:
        return gtsam.PriorFactorVector(TILT(k), np.zeros(2), self.prior_noise)

    def observation(self, build: FactorBuilder, k: int, j: int, anchor: int, moved: int, T_S_C: gtsam.Pose3,
                    T_S_A: gtsam.Pose3, plane_A: np.ndarray, plane_C: np.ndarray, cov: np.ndarray) -> list[gtsam.NonlinearFactor]:
        """Keyframe k (at `T_S_C`) sees landmark j (`plane_A` in its anchor keyframe, at
        `T_S_A`) as `plane_C`, from the moved anchor `moved`: the tie of the moved anchor to the
        anchor, made there (where the moved anchor starts, too), and the plane factor."""
        _, J = predict_local_plane(T_S_C, T_S_A, gtsam.OrientedPlane3(normalise_plane(plane_A)), jacobian=True)
        K = anchor_step(plane_C, J[:, 6:12], self.dm_dtau)
        return [tilt_link_factor(X(anchor), moved, TILT(k), T_S_A, K, self.link_noise),
                build.observation_of(X(k), moved, L(j), plane_C, cov)]


def without_tilt(values: gtsam.Values) -> gtsam.Values:
    """`values` without tilt variables and moved anchors: the online graph's, for the offline
    rounds, which key their moved anchors their own way (by observation and landmark, as their
    rebuilt graphs share them) and start the tilts afresh."""
    for key in values.keys():
        if gtsam.Symbol(key).chr() in _SYMBOLS:
            values.erase(key)
    return values
