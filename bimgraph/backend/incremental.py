"""The online graph: iSAM2 with the indices of the factors it may have to take out again.

`IncrementalGraph` wraps iSAM2 and keeps the index of every plane-to-BIM factor, so that a
revised association can be removed again, and of every odometry factor, so that the
front-end's drift, once measured, can be taken out of them all.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np

from bimgraph.backend.graph import ANCHOR_COPY, E, PLANE_COPY, L, X, FactorBuilder, joint_covariance, pose3
from bimgraph.config import BackendConfig
from bimgraph.geometry import normalise_plane
from factors import plane_prior_at


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

    # (poses and planes by keyword: pybind tries gtsam's forty-odd overloads of `insert` in
    # turn, converting the arguments to each, and the plane's comes late: 17 us against 6 by
    # name; a pose, 4 against 2)
    def insert_pose(self, k: int, T_S_C: np.ndarray) -> None:
        self._values.insert(X(k), pose3=pose3(T_S_C))

    def insert_plane(self, j: int, plane: np.ndarray) -> None:
        self._values.insert(L(j), plane=gtsam.OrientedPlane3(plane))

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
        point.insert(plane, plane=frozen.plane_A)
        self._values.insert(point)
        self._values.insert(anchor, pose3=frozen.T_S_A)
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
