"""The factor graph: keyframe poses `X(k) = T_S_Ck`, plane landmarks `L(j)` anchored in the
keyframe that first saw them, and the extrinsic `E = T_S_B` (its inverse is the reported
`T_B_S`; stored this way round the plane-to-BIM factor is gtsam's C++
LocalOrientedPlane3Factor).

`FactorBuilder` makes the factors from the configuration (shared by the online iSAM2 graph and
the offline batch graph); `IncrementalGraph` wraps iSAM2 and keeps the index of every
plane-to-BIM factor, so that a revised association can be removed again, and of every odometry
factor, so that the front-end's drift, once measured, can be taken out of them all.
"""

from __future__ import annotations

import re
import time
from contextlib import contextmanager
from dataclasses import dataclass

import gtsam
import numpy as np

from bimgraph.config import BackendConfig
from bimgraph.errors import SingularError
from bimgraph.geometry import normalise_plane
from factors import (deviation_cov_in_residual, face_tolerance_coordinates, local_plane_factor, plane_prior_at,
                     plane_prior_factor, plane_to_bim_factor)

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
_VARIABLES = {"x": "keyframe {}", "l": "landmark {}", "e": "the extrinsic", "a": "a frozen landmark's anchor copy {}",
              "f": "frozen landmark copy {}", "p": "landmark {} in S", "s": "the frame S"}


@contextmanager
def singular_as_error():
    """gtsam's IndeterminantLinearSystemException (a RuntimeError in Python) as a
    `SingularError` that names the variable it was found at."""
    try:
        yield
    except RuntimeError as err:
        if "Indetermin" not in str(err):
            raise
        found = re.search(r"\(Symbol: ([a-z])(\d+)\)", str(err))
        where = _VARIABLES.get(found[1], found[1] + "{}").format(found[2]) if found else "an unknown variable"
        raise SingularError(f"the graph's linear system became singular at {where}: a variable no factor constrains, "
                            "or covariances far overconfident against the others (the front-end's odometry, "
                            "the planes')") from None


def pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=float))


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


def _robust(kernel: str, width: float, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    if kernel == "none":
        return base
    estimator = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[kernel]
    return gtsam.noiseModel.Robust.Create(estimator.Create(width), base)


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
        self.gravity_noise = gtsam.noiseModel.Isotropic.Sigma(2, np.radians(n.gravity_deg))
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
        up_C = np.asarray(T_S_C)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        return gtsam.AttitudeFactorPose3(X(k), gtsam.Unit3(np.array([0.0, 0.0, 1.0])), self.gravity_noise, gtsam.Unit3(up_C))

    def odometry(self, k_prev: int, k: int, T_prev_k: np.ndarray, cov: np.ndarray | None) -> gtsam.NonlinearFactor:
        noise = gtsam.noiseModel.Gaussian.Covariance(self.default_odometry_cov if cov is None else np.asarray(cov))
        return gtsam.BetweenFactorPose3(X(k_prev), X(k), pose3(T_prev_k), noise)

    def observation_cov(self, cov) -> np.ndarray:
        """A plane observation's covariance as the graph and the association take it: the
        default where it has none, its diagonal raised to the floor where it is below."""
        if cov is None:
            return self.default_plane_cov
        cov = np.array(cov, dtype=float)
        diagonal = cov.diagonal()
        if (diagonal < self._plane_cov_floor).any():  # (rarely: checking costs less than raising)
            cov[np.diag_indices(3)] = np.maximum(diagonal, self._plane_cov_floor)
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


@dataclass(frozen=True)
class FrozenPlane:
    """A frozen landmark as `IncrementalGraph.add_frozen_observation` copies it: its anchor
    pose, its plane in the anchor and the square-root information of that plane's prior."""

    T_S_A: gtsam.Pose3
    plane_A: gtsam.OrientedPlane3
    plane_R: np.ndarray

    @classmethod
    def of(cls, T_S_A: np.ndarray, plane_A: np.ndarray, cov_A: np.ndarray) -> FrozenPlane:
        """A landmark's plane `plane_A` (covariance `cov_A`) of the anchor pose `T_S_A`, as they
        are now."""
        return cls(pose3(T_S_A), gtsam.OrientedPlane3(normalise_plane(plane_A)),
                   gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov_A)).R())


class IncrementalGraph:
    """iSAM2 over the graph. Factors and new values are queued, then `update` applies them."""

    def __init__(self, cfg: BackendConfig, T_B_S: np.ndarray, cov_T_B_S_: np.ndarray, extrinsic_last: bool = True):
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(cfg.isam2.relinearize_threshold)
        params.relinearizeSkip = cfg.isam2.relinearize_skip
        params.enablePartialRelinearizationCheck = cfg.isam2.partial_relinearization_check
        self.cfg = cfg
        self.isam = gtsam.ISAM2(params)
        self.build = FactorBuilder(cfg)
        self._factors = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        # (index table, its key, position in the queued factors) of each factor whose iSAM2 index is kept
        self._tracked: list[tuple[dict, int, int]] = []
        self._queued: set[tuple[int, int]] = set()  # (id of its table, key) of each in `_tracked`: a re-add of every odometry factor checks each
        self._remove: list[int] = []
        self._reorder = False  # the next update re-adds factors of every pose
        self.bim_index: dict[int, int] = {}  # landmark -> its plane-to-BIM factor in iSAM2
        self.odometry_index: dict[int, int] = {}  # keyframe -> its odometry factor (from the one before) in iSAM2
        self.observation_index: dict[int, list[int]] = {}  # landmark -> its observation factors in iSAM2
        self._tracked_observations: list[tuple[int, int]] = []  # (landmark, position in the queued factors)
        self._copies = 0  # observations of frozen landmarks so far
        self.update_seconds = 0.0  # total time inside iSAM2 updates
        self.extrinsic_last = extrinsic_last  # see `_ordering_groups`
        self.add(self.build.extrinsic_prior(T_B_S, cov_T_B_S_))
        self._values.insert(E, pose3(T_B_S).inverse())

    def add(self, factor: gtsam.NonlinearFactor) -> None:
        self._factors.add(factor)

    def insert(self, key: int, value) -> None:
        self._values.insert(key, value)

    def insert_pose(self, k: int, T_S_C: np.ndarray) -> None:
        self._values.insert(X(k), pose3(T_S_C))

    def insert_plane(self, j: int, plane: np.ndarray) -> None:
        self._values.insert(L(j), gtsam.OrientedPlane3(plane))

    def add_frozen_observation(self, k: int, frozen: FrozenPlane, plane_C: np.ndarray, cov) -> None:
        """Keyframe k sees a frozen landmark. Its anchor and plane enter as copies of their own,
        held by priors, so that the factor touches no variable that other keyframes share: a
        plane seen from everywhere (the floor) would otherwise put itself and its anchor into
        every clique's separator of iSAM2's Bayes tree, and every update would back-substitute
        the whole tree (measured: 5 ms per keyframe at 2000 keyframes, 0.5 ms without). Each
        copy carries the plane's whole uncertainty as if it were its own, so the poses'
        marginals come out optimistic where the frozen plane is all that holds them (measured
        on the two-room test world: height 7 mm against 15 mm unfrozen, tilt 0.15 against 0.20
        deg; the extrinsic's 2.5 %)."""
        anchor, plane = ANCHOR_COPY(self._copies), PLANE_COPY(self._copies)
        self._copies += 1
        # the plane prior's linearisation point is also the copy's initial value
        point = gtsam.Values()
        point.insert(plane, frozen.plane_A)
        self._values.insert(point)
        self._values.insert(anchor, frozen.T_S_A)
        self.add(gtsam.PriorFactorPose3(anchor, frozen.T_S_A, self.build.first_pose_noise))
        self.add(plane_prior_at(point, plane, frozen.plane_R))
        self.add(self.build.observation_of(X(k), anchor, plane, plane_C, cov))

    def add_observation(self, j: int, factor: gtsam.NonlinearFactor) -> None:
        """An observation factor of landmark j (kept track of, so that a merge can move it)."""
        self._tracked_observations.append((j, self._factors.size()))
        self._factors.add(factor)

    def retire(self, j: int, prior: gtsam.NonlinearFactor) -> None:
        """Landmark j's factors go (its observations were added to the landmark it merged into);
        `prior` keeps its plane, which iSAM2 cannot drop, determined."""
        self._remove.extend(self.observation_index.pop(j, []))
        self.remove_bim(j)
        self.add(prior)

    def _add_tracked(self, table: dict, key: int, factor: gtsam.NonlinearFactor) -> None:
        self._tracked.append((table, key, self._factors.size()))
        self._queued.add((id(table), key))
        self._factors.add(factor)

    def add_bim(self, j: int, anchor: int, plane_B: np.ndarray, centre_B: np.ndarray) -> None:
        if j in self.bim_index or (id(self.bim_index), j) in self._queued:
            raise ValueError(f"landmark {j} already has a plane-to-BIM factor")
        self._add_tracked(self.bim_index, j, self.build.bim(anchor, j, plane_B, centre_B))

    def add_odometry(self, k: int, factor: gtsam.NonlinearFactor) -> None:
        """Keyframe k's odometry factor; one it had before is removed."""
        if (id(self.odometry_index), k) in self._queued:
            raise ValueError(f"keyframe {k} already has an odometry factor queued")
        if k in self.odometry_index:
            self._remove.append(self.odometry_index.pop(k))
            self._reorder = True
        self._add_tracked(self.odometry_index, k, factor)

    def remove_bim(self, j: int) -> None:
        """Landmark j's plane-to-BIM factor goes (if it has one: the robust alignment may have
        taken it out)."""
        if j in self.bim_index:
            self._remove.append(self.bim_index.pop(j))

    def set_bim(self, j: int, factor: gtsam.NonlinearFactor | None) -> None:
        """Landmark j's plane-to-BIM factor becomes `factor` (none if None)."""
        self.remove_bim(j)
        if factor is not None:
            self._add_tracked(self.bim_index, j, factor)

    def batch(self) -> gtsam.NonlinearFactorGraph:
        """Every factor in iSAM2 as a batch graph (after `update`)."""
        return self._batch(skip=set())

    def without_bim(self, odometry: bool = True) -> gtsam.NonlinearFactorGraph:
        """Every factor in iSAM2 but the plane-to-BIM ones (and the odometry, if not
        `odometry`), as a batch graph (after `update`)."""
        skip = set(self.bim_index.values())
        return self._batch(skip if odometry else skip | set(self.odometry_index.values()))

    def _batch(self, skip: set[int]) -> gtsam.NonlinearFactorGraph:
        factors = self.isam.getFactorsUnsafe()
        graph = gtsam.NonlinearFactorGraph()
        for i in range(factors.size()):
            if i not in skip and factors.exists(i):
                graph.add(factors.at(i))
        return graph

    def update(self, keys: list[int] = ()) -> gtsam.Values:
        """Apply the queued factors and values; return the new estimates of `keys` (the first
        estimate after an update pays for iSAM2's back-substitution, so it is timed with it)."""
        start = time.perf_counter()
        params = gtsam.ISAM2UpdateParams()
        params.removeFactorIndices = self._remove
        params.constrainedKeys = self._ordering_groups()
        result = self.isam.update(self._factors, self._values, params)
        estimate = self.estimate(keys) if keys else None
        self.update_seconds += time.perf_counter() - start
        indices = result.getNewFactorsIndices()
        for table, key, position in self._tracked:
            table[key] = indices[position]
        for j, position in self._tracked_observations:
            self.observation_index.setdefault(j, []).append(indices[position])
        self._factors = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._tracked, self._tracked_observations, self._remove, self._reorder = [], [], [], False
        self._queued = set()
        return estimate

    def _ordering_groups(self) -> gtsam.KeyGroupMap:
        """The elimination groups of the next update's re-ordered variables: the extrinsic
        last, so that it stays in the root clique, where its marginal (read after every
        keyframe) needs no shortcut through the tree: left where iSAM2's own ordering puts
        it, it sinks as the walk goes on, and on the 3000-keyframe site walk the marginals came to
        cost five times the updates (2000 keyframes: 76 s online against 35 s). Before it,
        the variables of the new factors, as iSAM2 orders them by default, to keep them near
        the root too; except when the new factors touch every pose (the odometry re-added),
        which would put every pose in one root clique (a 15 s update, marginals minutes each):
        then plain COLAMD before it. Without `extrinsic_last`, iSAM2's own ordering (for a
        caller that reads no marginal of it per keyframe)."""
        groups = gtsam.KeyGroupMap()
        if not self._reorder:
            for key in set(self._factors.keyVector()) | set(self._values.keys()):
                groups.insert2(key, 1)
        if self.extrinsic_last:
            groups.insert2(E, 2)
        return groups

    def estimate(self, keys: list[int] = ()) -> gtsam.Values:
        """The current estimate of `keys` (default: every variable's, a full back-substitution)."""
        return self.isam.calculateEstimate(sorted(set(keys))) if keys else self.isam.calculateEstimate()

    def marginal(self, key: int) -> np.ndarray:
        return self.isam.marginalCovariance(key)

    def joint(self, keys: list[int]) -> np.ndarray:
        """Joint marginal covariance of `keys`, one matrix with blocks in the order given."""
        return joint_covariance(self.isam, keys)
