"""The factor graph: keyframe poses `X(k) = T_S_Ck`, plane landmarks `L(j)` anchored in the
keyframe that first saw them, and the extrinsic `E = T_S_B` (its inverse is the reported
`T_B_S`; stored this way round the plane-to-BIM factor is gtsam's C++
LocalOrientedPlane3Factor).

`FactorBuilder` makes the factors from the configuration (shared by the online iSAM2 graph,
`bimgraph.backend.incremental`, and the offline batch graph); `BatchSolver` solves a batch
graph.
"""

from __future__ import annotations

import functools
import re
from contextlib import contextmanager

import gtsam
import numpy as np

from bimgraph.config import BackendConfig
from bimgraph.errors import SingularError
from factors import (deviation_cov_in_residual, face_tolerance_coordinates, local_plane_factor, plane_prior_factor,
                     plane_to_bim_factor)

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L
E = gtsam.symbol("e", 0)
# per observation of a frozen landmark, a copy of its anchor pose and of its plane
ANCHOR_COPY = gtsam.symbol_shorthand.A
PLANE_COPY = gtsam.symbol_shorthand.F
# the robust alignment's reduced graph (`bimgraph.backend.reduced`) holds the landmarks in S:
# landmark j's plane in S, anchored at the frame S itself, a pose pinned at the identity
PLANE_S = gtsam.symbol_shorthand.P
S_FRAME = gtsam.symbol("s", 0)
# planes from depth images (`bimgraph.backend.depth_tilt`): keyframe k's depth tilt, and per
# observation the landmark's anchor as that tilt moved it
TILT = gtsam.symbol_shorthand.T
MOVED_ANCHOR = gtsam.symbol_shorthand.M
_VARIABLES = {"x": "keyframe {}", "l": "landmark {}", "e": "the extrinsic", "a": "a frozen landmark's anchor copy {}",
              "f": "frozen landmark copy {}", "p": "landmark {} in S", "s": "the frame S",
              "t": "keyframe {}'s depth tilt", "m": "a tilted observation's moved anchor {}"}


@contextmanager
def singular_as_error():
    """gtsam's IndeterminantLinearSystemException (a RuntimeError in Python) as a
    `SingularError` that names the variable it was found at; numpy's LinAlgError (a Cholesky)
    as one too."""
    try:
        yield
    except np.linalg.LinAlgError:  # (the robust alignment's Cholesky of a marginal: `reduced`)
        raise SingularError("the graph's information matrix is not positive definite: a variable no factor constrains, "
                            "covariances far overconfident against the others, or poses too far from S's origin for "
                            "double precision") from None
    except RuntimeError as err:
        if "Indetermin" not in str(err):
            raise
        found = re.search(r"\(Symbol: ([a-z])(\d+)\)", str(err))
        where = _VARIABLES.get(found[1], found[1] + "{}").format(found[2]) if found else "an unknown variable"
        raise SingularError(f"the graph's linear system became singular at {where}: a variable no factor constrains, "
                            "or covariances far overconfident against the others (the front-end's odometry, "
                            "the planes')") from None


def pose3(T: np.ndarray) -> gtsam.Pose3:
    # (by keyword: pybind then skips the overloads it would try to convert the matrix to first)
    return gtsam.Pose3(mat=np.asarray(T, dtype=float))


def sigmas_cov(rot_rad: float, trans_m: float) -> np.ndarray:
    return np.diag([rot_rad**2] * 3 + [trans_m**2] * 3)


def plane_cov(normal_rad: float, offset_m: float) -> np.ndarray:
    return np.diag([normal_rad**2, normal_rad**2, offset_m**2])


def extrinsic_cov_E(T_B_S: np.ndarray, cov_T_B_S: np.ndarray) -> np.ndarray:
    """Covariance of `E = T_S_B` from that of `T_B_S` (both in gtsam's right-perturbation
    tangent): inverting a pose maps xi to -Ad(T) xi."""
    Ad = pose3(T_B_S).AdjointMap()
    return Ad @ cov_T_B_S @ Ad.T


def joint_covariance(marginals: gtsam.Marginals | gtsam.ISAM2, keys: list[int]) -> np.ndarray:
    """The joint marginal covariance of `keys` (from batch marginals or iSAM2), blocks in the
    order given (gtsam's own `fullMatrix` orders them by key value instead)."""
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector(list(keys)))
    return np.block([[joint.at(ki, kj) for kj in keys] for ki in keys])


def landmark_keys(anchor: int | None, j: int) -> tuple[int, int]:
    """The variables that hold landmark j: its anchor keyframe's pose and its plane in that
    keyframe; or, with `anchor` None (a landmark held in S, in the reduced graph), `S_FRAME`
    and its plane in S."""
    return (S_FRAME, PLANE_S(j)) if anchor is None else (X(anchor), L(j))


def bim_keys(landmarks) -> list[int]:
    """The variables of these landmarks' plane-to-BIM factors: the extrinsic, each landmark
    and its anchor (`bimgraph.backend.landmarks.Landmark`s; `landmark_keys`), sorted."""
    return sorted({E} | {key for lm in landmarks for key in landmark_keys(lm.anchor, lm.id)})


def cov_T_B_S(T_S_B: gtsam.Pose3, cov_E: np.ndarray) -> np.ndarray:
    Ad = T_S_B.AdjointMap()
    return Ad @ cov_E @ Ad.T


def extrinsic_difference(T_S_B: gtsam.Pose3, T_S_B_other: gtsam.Pose3) -> np.ndarray:
    """`d` with `T_B_S_other = T_B_S Exp(d)`: another estimate of the extrinsic in the tangent
    `cov_T_B_S` is written in."""
    return gtsam.Pose3.Logmap(T_S_B * T_S_B_other.inverse())


class BatchSolver:
    """Solves a batch graph from a starting estimate, to `max_iterations` or until an iteration
    improves the error by less than `relative_error_tol` of it: Powell's dogleg (gtsam's), which
    solves the linear system once per iteration however many trust regions it then tries.
    Levenberg-Marquardt solves it again for every damping it tries, and near the optimum, where
    the robust kernels' reweighted model promises a decrease the cost does not show, it tried
    eleven before it stopped (measured on the offline solves at 2000 keyframes: 0.5 s a solve
    from the optimum; dogleg 30 % less over all of them, to the same errors)."""

    def __init__(self, max_iterations: int, relative_error_tol: float):
        self.params = gtsam.DoglegParams()
        self.params.setMaxIterations(max_iterations)
        self.params.setRelativeErrorTol(relative_error_tol)

    def __call__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        return gtsam.DoglegOptimizer(graph, values, self.params).optimize()


@functools.cache
def _estimator(kernel: str, width: float) -> gtsam.noiseModel.mEstimator.Base:
    """One kernel shared by every factor that uses it (gtsam only reads it; making one per
    factor cost a tenth of an observation factor's making)."""
    return {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[kernel].Create(width)


def _robust(kernel: str, width: float, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    if kernel == "none":
        return base
    return gtsam.noiseModel.Robust.Create(_estimator(kernel, width), base)


class FactorBuilder:
    """Every factor of the graph, with its noise model from the configuration."""

    def __init__(self, cfg: BackendConfig):
        n = cfg.noise
        self.cfg = cfg
        self.first_pose_noise = gtsam.noiseModel.Gaussian.Covariance(
            sigmas_cov(np.radians(n.prior_first_pose_rot_deg), n.prior_first_pose_trans_m))
        self.default_odometry_cov = sigmas_cov(np.radians(n.odometry_rot_deg), n.odometry_trans_m)
        self.default_plane_cov = plane_cov(np.radians(n.plane_normal_deg), n.plane_offset_m)
        self._plane_cov_floor = np.diag(plane_cov(np.radians(n.plane_min_normal_deg), n.plane_min_offset_m))
        self._plane_cov_floor_values = tuple(self._plane_cov_floor.tolist())
        self.gravity_noise = gtsam.noiseModel.Isotropic.Sigma(2, np.radians(n.gravity_deg))
        self._up = np.array([0.0, 0.0, 1.0])
        self._up_S = gtsam.Unit3(self._up)  # (a factor per keyframe: each copies it)
        # each face's tolerance covariance, by (plane, centre, tolerance): the robust alignment
        # makes thousands of plane-to-BIM factors a judgement, of a few dozen faces (on the
        # synthetic world's largest, 0.42 of its 1.6 s went to making these again)
        self._face_covs: dict[tuple, np.ndarray] = {}
        # each face's map from deviation to residual, by (plane, centre): the tolerance the
        # judgement tightens changes from one of its solves to the next, the face does not
        self._face_maps: dict[tuple, np.ndarray] = {}

    def first_pose(self, k: int, T_S_C: np.ndarray) -> gtsam.NonlinearFactor:
        return gtsam.PriorFactorPose3(X(k), pose3(T_S_C), self.first_pose_noise)

    def gravity(self, k: int, T_S_C: np.ndarray) -> gtsam.NonlinearFactor:
        """Keyframe k's up direction as the gravity-aligned front-end reports it: its tilt does
        not drift, only its heading does."""
        up_C = np.asarray(T_S_C)[:3, :3].T @ self._up
        return gtsam.AttitudeFactorPose3(X(k), self._up_S, self.gravity_noise, gtsam.Unit3(up_C))

    def odometry(self, k_prev: int, k: int, T_prev_k: np.ndarray, cov: np.ndarray | None) -> gtsam.NonlinearFactor:
        noise = gtsam.noiseModel.Gaussian.Covariance(self.default_odometry_cov if cov is None else np.asarray(cov))
        return gtsam.BetweenFactorPose3(X(k_prev), X(k), pose3(T_prev_k), noise)

    def observation_cov(self, cov) -> np.ndarray:
        """A plane observation's covariance as the graph and the association take it: the
        default where it has none, its diagonal raised to the floor where it is below."""
        if cov is None:
            return self.default_plane_cov
        # (rarely: checking costs less than raising; Python's comparisons of the three given
        # floats cost a fifth of numpy's)
        low = self._plane_cov_floor_values
        below = cov[0][0] < low[0] or cov[1][1] < low[1] or cov[2][2] < low[2]
        cov = np.array(cov, dtype=float)
        if below:
            cov[np.diag_indices(3)] = np.maximum(cov.diagonal(), self._plane_cov_floor)
        return cov

    def plane_noise(self, cov: np.ndarray) -> gtsam.noiseModel.Gaussian:
        """The noise of a plane factor; `cov` as `observation_cov` gave it (or a landmark's marginal)."""
        return gtsam.noiseModel.Gaussian.Covariance(cov)

    def anchor_observation(self, j: int, plane_C: np.ndarray, cov) -> gtsam.NonlinearFactor:
        return plane_prior_factor(plane_C, self.plane_noise(cov), L(j))

    def observation(self, k: int, anchor: int, j: int, plane_C: np.ndarray, cov) -> gtsam.NonlinearFactor:
        """Keyframe k sees landmark j (anchored at `anchor`); the anchor's own observation is a
        prior on the plane (the plane factor would have pose and anchor on one key)."""
        if k == anchor:
            return self.anchor_observation(j, plane_C, cov)
        return self.observation_of(X(k), X(anchor), L(j), plane_C, cov)

    def observation_of(self, key_pose: int, key_anchor: int, key_plane: int, plane_C: np.ndarray, cov) -> gtsam.NonlinearFactor:
        n = self.cfg.noise
        noise = _robust(n.plane_kernel, n.plane_kernel_width, self.plane_noise(cov))
        return local_plane_factor(plane_C, noise, key_pose, key_anchor, key_plane)

    def bim_tolerance(self) -> tuple[float, float]:
        """The configured as-built tolerance of a wall: (normal sigma in radians, offset sigma in metres)."""
        return float(np.radians(self.cfg.noise.bim_normal_deg)), self.cfg.noise.bim_offset_m

    def bim(self, anchor: int | None, j: int, plane_B: np.ndarray, centre_B: np.ndarray | None,
            weight: float | None = None, tolerance: tuple[float, float] | None = None) -> gtsam.NonlinearFactor:
        """Landmark j (anchored at `anchor`; None: held in S, `landmark_keys`) is the face
        `plane_B`, within the as-built `tolerance` (normal sigma in radians, offset sigma in
        metres; default the configured one) about the face's centre `centre_B`: under the
        configured robust kernel, or, given a `weight` (graduated non-convexity decides it),
        Gaussian with that weight."""
        n = self.cfg.noise
        plane_B = np.asarray(plane_B, dtype=float)
        tolerance = tolerance or self.bim_tolerance()
        face = (plane_B.tobytes(), None if centre_B is None else np.asarray(centre_B, dtype=float).tobytes())
        if (cov := self._face_covs.get((face, tolerance))) is None:
            if (M_inv := self._face_maps.get(face)) is None:
                M_inv = self._face_maps[face] = np.linalg.inv(
                    face_tolerance_coordinates(gtsam.Unit3(plane_B[:3]).basis(), centre_B))
            cov = self._face_covs[face, tolerance] = deviation_cov_in_residual(M_inv, tolerance[1], tolerance[0]**2 * np.eye(2))
        if weight is None:
            noise = _robust(n.bim_kernel, n.bim_kernel_width, gtsam.noiseModel.Gaussian.Covariance(cov))
        else:
            noise = gtsam.noiseModel.Gaussian.Covariance(cov / weight)
        return plane_to_bim_factor(plane_B, noise, E, *landmark_keys(anchor, j))

    def extrinsic_prior(self, T_B_S: np.ndarray, cov_T_B_S_: np.ndarray) -> gtsam.NonlinearFactor:
        noise = gtsam.noiseModel.Gaussian.Covariance(extrinsic_cov_E(T_B_S, cov_T_B_S_))
        return gtsam.PriorFactorPose3(E, pose3(T_B_S).inverse(), noise)
