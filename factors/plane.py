"""Plane factors: an anchored plane seen from a pose, the same plane against a BIM face, and
the anchor's own observation.

Landmark planes live in the frame of the keyframe that first saw them (the anchor `a`, Kaess,
ICRA 2015, eq. 25). One residual serves both the plane observations and the plane-to-BIM
factors:

    plane_i = plane_a.transform(T_a_i),    T_a_i = T_W_a^-1 * T_W_i
    e       = ( B(n_z)^T n_i ,  d_z - d_i )

where `(n_z, d_z)` is the measured plane and `B(n_z)` the 3x2 basis of gtsam's `Unit3` at
the measured normal (`measured.errorVector(predicted)`). That is gtsam_unstable's C++ `LocalOrientedPlane3Factor`. With the pose
of keyframe k as `T_W_i` and a camera measurement it is a plane observation; with the
extrinsic `E = T_S_B` as `T_W_i` and a BIM face plane as the measurement it is the
plane-to-BIM factor (the landmark mapped into B, compared with the face).

The anchor keyframe's own observation cannot use that factor (pose and anchor would be the
same key, on which it silently diverges); it is a Gaussian prior on the landmark in the
tangent space of the measurement, `e = localCoordinates(z, plane_a)`.
"""

from __future__ import annotations

import gtsam
import gtsam_unstable
import numpy as np

from bimgraph.geometry import normalise_plane


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def predict_local_plane(T_W_i: gtsam.Pose3, T_W_a: gtsam.Pose3, plane_a: gtsam.OrientedPlane3,
                        jacobian: bool = False):
    """The anchored plane expressed in frame i, `(n_i, d_i)`, and, if asked, its 4x15
    Jacobian in R^4 with respect to `T_W_i`, `T_W_a` (Pose3 right perturbations) and
    `plane_a` (its retraction). Also what the association propagates covariances with."""
    T_a_i = T_W_a.between(T_W_i)
    R, t = T_a_i.rotation().matrix(), T_a_i.translation()
    p_a = plane_a.planeCoefficients()
    n_a, d_a = p_a[:3], p_a[3]
    n_i = R.T @ n_a
    plane_i = np.array([*n_i, d_a + n_a @ t])
    if not jacobian:
        return plane_i
    # right perturbation (w, v) of T_a_i: n_i turns by -w, d_i moves by n_i . v
    dplane_dT = np.zeros((4, 6))
    dplane_dT[:3, :3] = _skew(n_i)
    dplane_dT[3, 3:] = n_i
    # the anchor enters inverted: T_a_i -> exp(-w_a) T_a_i
    dplane_da = -dplane_dT @ T_a_i.inverse().AdjointMap()
    # plane_a moves along its Unit3 basis and its offset
    B_a = plane_a.normal().basis()
    dplane_dL = np.zeros((4, 3))
    dplane_dL[:3, :2] = R.T @ B_a
    dplane_dL[3, :2] = t @ B_a
    dplane_dL[3, 2] = 1.0
    return plane_i, np.hstack([dplane_dT, dplane_da, dplane_dL])


def error_jacobian_wrt_plane(plane_z: np.ndarray) -> np.ndarray:
    """d e / d(n_i, d_i): the 3x4 map from a predicted plane in R^4 to the residual against
    the measurement `plane_z`; constant because the basis is the measurement's."""
    D = np.zeros((3, 4))
    D[:2, :3] = gtsam.Unit3(plane_z[:3]).basis().T
    D[2, 3] = -1.0
    return D


def local_plane_error(T_W_i: gtsam.Pose3, T_W_a: gtsam.Pose3, plane_a: gtsam.OrientedPlane3,
                      plane_z: np.ndarray, jacobians: bool = False):
    """The anchored-plane residual (see the module docstring) and, if asked, its Jacobians
    with respect to `T_W_i`, `T_W_a` and `plane_a`, in that order."""
    D = error_jacobian_wrt_plane(plane_z)
    if not jacobians:
        plane_i = predict_local_plane(T_W_i, T_W_a, plane_a)
    else:
        plane_i, J = predict_local_plane(T_W_i, T_W_a, plane_a, jacobian=True)
    e = D @ plane_i + np.r_[0.0, 0.0, plane_z[3]]
    if not jacobians:
        return e
    H = D @ J
    return e, [H[:, :6], H[:, 6:12], H[:, 12:]]


def local_plane_factor(plane_z, noise: gtsam.noiseModel.Base, key_pose: int, key_anchor: int,
                       key_plane: int) -> gtsam.NonlinearFactor:
    """The C++ factor the graph uses for `local_plane_error` (robust noise models work)."""
    if key_pose == key_anchor:
        raise ValueError("pose and anchor must be different keys: use plane_prior_factor for the anchor")
    return gtsam_unstable.LocalOrientedPlane3Factor(normalise_plane(plane_z), noise, key_pose, key_anchor, key_plane)


def plane_to_bim_factor(plane_B, noise: gtsam.noiseModel.Base, key_T_S_B: int, key_anchor: int,
                        key_plane: int) -> gtsam.NonlinearFactor:
    """Plane-to-BIM: the landmark (anchored at `key_anchor`) mapped into B by the extrinsic
    `E = T_S_B`, against the fixed BIM face plane `plane_B`."""
    return local_plane_factor(plane_B, noise, key_T_S_B, key_anchor, key_plane)


def face_tolerance_coordinates(basis: np.ndarray, centre: np.ndarray | None) -> np.ndarray:
    """The 3x3 map `M` from the plane-to-BIM residual `e = (basis^T n_B, d_F - d_B)` to the
    as-built deviation it stands for, to first order: `(offset at the face centre, tilt_1,
    tilt_2)` (m, rad, rad). Since the face centre is `c = basis^T centre` along the face,
    `offset = e_3 - e_12 . c`. `centre` None: the origin's foot on the plane (c = 0)."""
    c = np.zeros(2) if centre is None else np.asarray(basis).T @ np.asarray(centre, dtype=float)
    return np.array([[-c[0], -c[1], 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def face_tolerance_cov(basis: np.ndarray, centre: np.ndarray | None, sigma_normal_rad: float, sigma_offset_m: float,
                       sigma_plumb_rad: float | None = None) -> np.ndarray:
    """Covariance of the plane-to-BIM residual `e` when the built plane strays from the face
    by a tilt of `sigma_normal_rad` and an offset *at the face centre* of `sigma_offset_m`,
    independently (`face_tolerance_coordinates`). A face far from B's origin so gets a large,
    correlated `e_3` variance, not the origin's `sigma_offset_m`, which would let its tilt
    stand for metres of offset at the face. With `sigma_plumb_rad`, the tilt out of plumb (the
    normal turning toward B's z) has that sigma, and `sigma_normal_rad` is left to the turn
    about the vertical, blended toward `sigma_plumb_rad` as the face tilts toward level (by the
    squared sine of its inclination): a level face has tilt out of level alone."""
    basis = np.asarray(basis, dtype=float)
    cov_tilt = sigma_normal_rad**2 * np.eye(2)
    if sigma_plumb_rad is not None:
        n = np.cross(basis[:, 0], basis[:, 1])
        h = np.cross([0.0, 0.0, 1.0], n)  # the horizontal direction in the face
        inclined = float(h @ h)  # sin^2 of the face's inclination from level
        cov_tilt = sigma_plumb_rad**2 * np.eye(2)
        if inclined > 1e-12:
            h /= np.sqrt(inclined)
            turn = sigma_normal_rad**2 * inclined + sigma_plumb_rad**2 * (1.0 - inclined)
            cov_tilt += (turn - sigma_plumb_rad**2) * np.outer(basis.T @ h, basis.T @ h)
    return deviation_cov_in_residual(np.linalg.inv(face_tolerance_coordinates(basis, centre)), sigma_offset_m, cov_tilt)


def deviation_cov_in_residual(M_inv: np.ndarray, sigma_offset_m: float, cov_tilt: np.ndarray) -> np.ndarray:
    """Covariance of the plane-to-BIM residual for a deviation of offset sigma `sigma_offset_m`
    and tilt covariance `cov_tilt` (2x2, rad^2), independent, through `M_inv`, the inverse of
    `face_tolerance_coordinates` (which a caller making many for one face can keep)."""
    cov = np.zeros((3, 3))
    cov[0, 0] = sigma_offset_m**2
    cov[1:, 1:] = cov_tilt
    return M_inv @ cov @ M_inv.T


def _custom(plane_z, noise, keys):
    plane_z = normalise_plane(plane_z)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
        k_i, k_a, k_L = this.keys()
        out = local_plane_error(values.atPose3(k_i), values.atPose3(k_a), values.atOrientedPlane3(k_L),
                                plane_z, jacobians=H is not None)
        if H is None:
            return out
        e, jac = out
        for slot, J in enumerate(jac):
            H[slot] = J
        return e

    return gtsam.CustomFactor(noise, keys, error)


def local_plane_custom_factor(plane_z, noise, key_pose: int, key_anchor: int, key_plane: int) -> gtsam.CustomFactor:
    """Python reference of `local_plane_factor` (slow inside optimisers; for tests)."""
    return _custom(plane_z, noise, [key_pose, key_anchor, key_plane])


def plane_to_bim_custom_factor(plane_B, noise, key_T_S_B: int, key_anchor: int, key_plane: int) -> gtsam.CustomFactor:
    """Python reference of `plane_to_bim_factor` (slow inside optimisers; for tests)."""
    return _custom(plane_B, noise, [key_T_S_B, key_anchor, key_plane])


def plane_prior_error(plane_a: gtsam.OrientedPlane3, plane_z: np.ndarray) -> np.ndarray:
    """The anchor observation's residual: the landmark in the tangent space of the measurement
    (Unit3 log of the normal, then the difference of offsets). Its Jacobian at the
    measurement is the identity, which is what `plane_prior_factor` keeps."""
    return gtsam.OrientedPlane3(normalise_plane(plane_z)).localCoordinates(plane_a)


def plane_prior_factor(plane_z, noise: gtsam.noiseModel.Gaussian, key_plane: int) -> gtsam.NonlinearFactor:
    """A C++ prior on an OrientedPlane3 (gtsam's Python wrapper has no PriorFactor for it): a
    Gaussian factor linearised at the measurement, kept by `LinearContainerFactor`, which
    re-evaluates it through `localCoordinates`, i.e. `plane_prior_error`."""
    point = gtsam.Values()
    point.insert(key_plane, plane=gtsam.OrientedPlane3(normalise_plane(plane_z)))  # (by keyword: see plane_prior_at)
    return plane_prior_at(point, key_plane, noise.R())


def plane_prior_at(point: gtsam.Values, key_plane: int, R: np.ndarray) -> gtsam.NonlinearFactor:
    """`plane_prior_factor` with its measurement given as `point`, a Values holding it at
    `key_plane` (which a caller may reuse: inserting a plane through gtsam's Python overloads
    costs 17 us, by keyword, `insert(key, plane=...)`, which pybind matches by name, 6), and
    its noise as the square-root information `R`."""
    linear = gtsam.JacobianFactor(key_plane, R, np.zeros(3), gtsam.noiseModel.Unit.Create(3))
    return gtsam.LinearContainerFactor(linear, point)
