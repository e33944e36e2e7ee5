"""The depth sensor's tilt: how it moves a plane fitted to a depth image, and the factor that
lets a keyframe's tilt variable move what its plane observations see.

A depth sensor's systematic error includes a field linear across and down the image that
grows as z^2 (a disparity error; `bimgraph.sim.render.systematic_depth_error`): with
coefficients `tau = (t1, t2)` (metres of depth error per squared metre of depth, at the
image's border), a pixel at `(x, y)` (from -1 to 1 across the image) reads `z + (t1 x + t2 y)
z^2`. It moves a fitted plane exactly, whatever pixels it was fitted to: in inverse depth a
plane is linear, `1/z = m . (x_n, y_n, 1)` with `m = -n/d`, and the error is the inverse-depth
error `-(t1 x + t2 y)`, itself linear in the normalised image coordinates `(x_n, y_n)`:

    m -> m + M tau,    M = -[[fx/hw, 0], [0, fy/hh], [(cx - hw)/hw, (cy - hh)/hh]]

(hw, hh: half the image's width and height less half a pixel), and with `n = -m/|m|`, `d =
1/|m|`, `G = d(n, d)/d(tau)` (`tilt_sensitivity`). It needs the intrinsics, not the pixels.

The factor: an observation of keyframe k sees its landmark from a pose of its own, the
landmark's anchor moved by the tilt, tied to the anchor by

    e = Log(T0^-1 moved) - Log(T0^-1 anchor) - K tau,    K = pinv(dplane/danchor) G

(linearised at the anchor's pose T0 when the observation came; its Jacobians are -I, I and
-K), `K` the smallest motion of the anchor that moves the predicted plane as the tilt does.
The observation itself stays gtsam's C++ plane factor. A pose, not an auxiliary plane: a
linear factor keeps its Jacobian in the tangent of its linearisation point, and gtsam's `Unit3`
basis turns by 90 degrees where the two smallest components of a normal swap (a wall seen
face-on, normal (0.002, 0.001, -1)); a linear tie between two planes, crossed there, steered
Gauss-Newton sideways and was left violated by tens of sigma. A pose's tangent turns smoothly.
"""

from __future__ import annotations

import gtsam
import numpy as np


def inverse_depth_sensitivity(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """3x2: `M`, how the tilt moves a plane's inverse-depth coefficients `m = -n/d`."""
    hw, hh = (width - 1) / 2, (height - 1) / 2  # (x = -1 at pixel 0, 1 at the last)
    return -np.array([[fx / hw, 0.0], [0.0, fy / hh], [(cx - hw) / hw, (cy - hh) / hh]])


def tilt_sensitivity(plane_C: np.ndarray, dm_dtau: np.ndarray) -> np.ndarray:
    """4x2: `G = d(n, d)/d(t1, t2)` of the plane `plane_C` (unit normal, d > 0) fitted to a
    depth image, from `inverse_depth_sensitivity`."""
    m = -np.asarray(plane_C[:3], dtype=float) / plane_C[3]
    r = np.linalg.norm(m)
    dn_dm = -(np.eye(3) / r - np.outer(m, m) / r**3)
    dd_dm = -m / r**3
    return np.vstack([dn_dm, dd_dm]) @ dm_dtau


def anchor_step(plane_C: np.ndarray, dplane_dA: np.ndarray, dm_dtau: np.ndarray) -> np.ndarray:
    """6x2: `K`, the smallest motion of the landmark's anchor (in its tangent) that moves the
    predicted `plane_C` as the tilt does; `dplane_dA` (4x6) is the prediction's Jacobian in the
    anchor (`factors.predict_local_plane`)."""
    return np.linalg.pinv(dplane_dA) @ tilt_sensitivity(plane_C, dm_dtau)


def tilt_link_factor(key_anchor: int, key_moved: int, key_tilt: int, T_S_A: gtsam.Pose3, K: np.ndarray,
                     noise: gtsam.noiseModel.Base) -> gtsam.NonlinearFactor:
    """The tie `moved = anchor * Exp(K tau)`, linearised at the anchor's pose `T_S_A` (the
    moved anchor's starting value too) and no tilt."""
    point = gtsam.Values()
    point.insert(key_anchor, T_S_A)
    point.insert(key_moved, T_S_A)
    point.insert(key_tilt, np.zeros(2))
    return gtsam.LinearContainerFactor(
        gtsam.JacobianFactor(key_anchor, -np.eye(6), key_moved, np.eye(6), key_tilt, -K, np.zeros(6), noise), point)
