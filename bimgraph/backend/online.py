"""Online estimation: keyframe by keyframe, one iSAM2 update plus the plane-to-BIM factors it
triggers, emitting the causal `T_B_C` and `T_B_S` (with covariance) after every keyframe."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

import gtsam
import numpy as np

from bimgraph.backend.alignment import Alignment, levelled, lock_directions, unlocked_covariance, unobservable_directions
from bimgraph.backend.associate_bim import FaceIndex
from bimgraph.backend.associate_slam import Observation, SlamAssociator
from bimgraph.backend.depth_tilt import DepthTilt
from bimgraph.backend.graph import MOVED_ANCHOR, TILT, E, L, X, FactorBuilder, cov_T_B_S, pose3, singular_as_error
from bimgraph.backend.incremental import FrozenPlane, IncrementalGraph
from bimgraph.backend.landmarks import Landmark, LandmarkTable, observation_points, transform_points
from bimgraph.backend.odometry import OdometryModel
from bimgraph.backend.records import Association, KeyframeResult, Listener, Results
from bimgraph.backend.online_bim import OnlineBimAssociation
from bimgraph.backend.online_judgement import OnlineJudgement
from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import BackendConfig, Isam2Config
from bimgraph.errors import InputError, SingularError
from bimgraph.sequence.format import Keyframe, out_of_order

Oracle = Mapping[tuple[int, int], "str | None"]


def observations_of(kf: Keyframe, build: FactorBuilder) -> list[Observation]:
    return [Observation(i, p.plane, build.observation_cov(p.cov), observation_points(p.polygon, p.centre), p.area)
            for i, p in enumerate(kf.planes)]


def covariance_due(n: int, cfg: Isam2Config) -> bool:
    """Whether a landmark seen `n` times has its marginal re-read now. Marginals settle after a
    few observations: re-read them early, then rarely, and the more rarely the longer the
    landmark has been seen (a plane seen for hundreds of keyframes sits deep in iSAM2's tree,
    where one marginal cost 4.7 ms against 0.1 ms for a young one, at 2000 synthetic
    keyframes)."""
    every = max(cfg.covariance_every, 2 ** int(np.log2(max(1.0, n * cfg.covariance_growth))))
    return n <= cfg.covariance_early or n % every == 0


class Backend:
    """The online estimator. `process(keyframe)` returns that keyframe's causal result.

    `oracle` maps (keyframe index, observation index) to the true face id (or None): landmarks
    are then one per face and matched at once, the reference the association is measured by.
    `tilt`: the planes come from the keyframes' depth images, and each keyframe's depth
    sensor tilt is a variable its plane observations share (`bimgraph.backend.depth_tilt`).
    """

    def __init__(self, plane_map: PlaneMap, cfg: BackendConfig, initial: Alignment,
                 listener: Listener | None = None, oracle: Oracle | None = None, covariance: bool = True,
                 drift_every: int | None = None, judge_every: int | None = None, merge: bool = True,
                 extrinsic_last: bool = True, tilt: DepthTilt | None = None):
        self.cfg = cfg
        self.tilt = tilt
        self._tilted: set[int] = set()  # keyframes with a tilt variable
        self._moved = 0  # observations seen through a tilt so far
        # False: results carry NaN covariances, for callers that read it rarely
        # (`extrinsic_covariance`): on the simulated walks the extrinsic's marginal costs iSAM2
        # about as much as its update
        self.covariance = covariance
        self.drift_every = cfg.isam2.drift_every if drift_every is None else drift_every
        self.judge_every = cfg.isam2.judge_every if judge_every is None else judge_every
        self.faces = FaceIndex(plane_map, cfg.bim_association)
        self.slam = SlamAssociator(cfg.slam_association)
        self.gravity_aligned = initial.gravity_aligned
        if initial.gravity_aligned:
            initial = levelled(initial, np.radians(cfg.noise.gravity_deg))
        # directions neither the faces of the map nor gravity can observe keep the initial alignment
        self.never_observable = self.unobservable_with(self.faces.planes[:, :3])
        self.prior = Alignment(initial.T_B_S, lock_directions(initial, self.never_observable,
                                                              np.radians(cfg.lock_rot_deg), cfg.lock_trans_m))
        self.locked_cov = unlocked_covariance(initial, self.never_observable)
        # (`extrinsic_last`: iSAM2 keeps E in its root clique, where its marginal is cheap; see
        # `IncrementalGraph._ordering_groups`)
        self.graph = IncrementalGraph(cfg, self.prior.T_B_S, self.prior.cov, extrinsic_last)
        self.build = self.graph.build
        self.landmarks = LandmarkTable()
        self.listener = listener or Listener()
        self.oracle = oracle
        self.seeds = initial.seeds
        self._landmark_of_face: dict[str, int] = {}
        self._previous: tuple[Keyframe, np.ndarray] | None = None  # the keyframe before and its estimate
        self.odometry = OdometryModel(self.build, self.prior.T_B_S[2, :3])  # the front-end's drift, taken out as found
        self._keyframes: list[Keyframe] = []  # so far, for the drift's fit
        self._count = 0
        self._due: dict[int, bool] = {}  # observation count -> `covariance_due` (numpy's log2 per landmark and keyframe costs)
        self._stopped: int | None = None  # the keyframe where the graph became singular
        self.matches = OnlineBimAssociation(self.faces, cfg, self.graph, self.landmarks, self.listener,
                                            self.extrinsic_covariance, self.slam.gate, self._observe if merge else None)
        self.judge = OnlineJudgement(self.faces, self.build, self.landmarks, cfg)

    # -- the step ---------------------------------------------------------------------------
    def process(self, kf: Keyframe) -> KeyframeResult:
        """Keyframe `kf` into the graph; its causal result. An InputError (a keyframe that does
        not follow, a value not finite) leaves the backend as it was. A SingularError (the
        graph's linear system became singular) stops it: gtsam's iSAM2 holds that keyframe in
        part, and every later call raises the error again (a new Backend starts over)."""
        if self._stopped is not None:
            raise SingularError(f"keyframe {kf.index}: this Backend stopped at keyframe {self._stopped}, where the "
                                "graph became singular; start a new one")
        start = time.perf_counter()
        isam2_before = self.graph.update_seconds
        try:
            with singular_as_error():
                observations, observed, values = self.advance(kf)
                T_S_B = values.atPose3(E)
                cov = self.extrinsic_covariance(T_S_B) if self.covariance else np.full((6, 6), np.nan)
        except SingularError as err:
            self._stopped = kf.index
            raise SingularError(f"keyframe {kf.index}: {err}") from None
        T_S_C = values.atPose3(X(kf.index)).matrix()
        T_B_S = T_S_B.inverse().matrix()
        result = KeyframeResult(
            index=kf.index, stamp=kf.stamp, T_S_C=T_S_C, T_B_C=T_B_S @ T_S_C, T_B_S=T_B_S, cov_T_B_S=cov,
            associations=[Association(obs.index, j, self._face_of(j, T_B_S))
                          for obs, j in zip(observations, map(self._current, observed))],
            latency_s=time.perf_counter() - start, isam2_s=self.graph.update_seconds - isam2_before, keyframe=kf)
        self.listener.on_keyframe(result)
        return result

    def advance(self, kf: Keyframe) -> tuple[list[Observation], list[int], gtsam.Values]:
        """The keyframe into the graph, associated and updated, without a result (for a caller
        that reads none: the offline estimator's causal pass). Returns its observations, the
        landmark each went to, and the estimates of its pose, the extrinsic and those landmarks."""
        self._check_follows(kf)
        k = kf.index
        T_S_C_guess = self._add_pose(kf)
        observations = observations_of(kf, self.build)
        matches = self._match_observations(k, observations, T_S_C_guess)
        observed = [self._add_observation(k, obs, j, T_S_C_guess) for obs, j in zip(observations, matches)]
        self._count += 1
        refresh = range(len(self.landmarks)) if self._count % self.cfg.isam2.refresh_every == 0 else observed
        values = self.graph.update(self._keys_of(refresh) + [X(k), E])
        self._refresh(values, refresh, [j for j in set(observed) if self._covariance_due(j)])

        # (every landmark on a refresh: a match made while the extrinsic was uncertain, to a
        # plane never seen again, would otherwise never be checked against what it has become)
        if self.oracle is None and (self.matches.revise(refresh, values.atPose3(E).matrix())
                                    | self.matches.associate(observed, values.atPose3(E))):
            for _ in range(self.cfg.isam2.extra_updates):
                self.graph.update()
            merged = self.matches.take_merged()
            values = self.graph.update(self._keys_of(observed + merged) + [X(k), E])
            self._refresh(values, observed + merged, merged)
        # (the re-added odometry is applied before the judgement reads the graph)
        if self.drift_every and self._count % self.drift_every == 0 and self._correct_drift():
            values = self._update_everything(k)
        if self.judge_every and self._count % self.judge_every == 0 and self.judge(self.graph, self.odometry, self._keyframes):
            values = self._update_everything(k)
        self._previous = (kf, values.atPose3(X(k)).matrix())
        return observations, observed, values

    @property
    def drift_fitted(self) -> bool:
        """Whether the front-end's drift has been fitted yet (`isam2.drift_every`)."""
        return bool(self.drift_every) and self._count >= self.drift_every

    @property
    def bim_tolerance(self) -> tuple[float, float] | None:
        """The plane-to-BIM tolerance (normal rad, offset m) as the online judgement left it;
        None where it never judges (`isam2.judge_every` 0)."""
        return self.judge.tolerance if self.judge_every else None

    def extrinsic_covariance(self, T_S_B: gtsam.Pose3 | None = None) -> np.ndarray:
        """The covariance of `T_B_S` as the graph stands (6x6, gtsam's Pose3 tangent); `T_S_B`
        is the extrinsic's estimate, if the caller has it."""
        if T_S_B is None:
            T_S_B = self.graph.estimate([E]).atPose3(E)
        return cov_T_B_S(T_S_B, self.graph.marginal(E)) + self.locked_cov + self.judge.rival_cov

    def _update_everything(self, k: int) -> gtsam.Values:
        """Apply what was queued for the whole graph (every odometry factor, every plane-to-BIM
        factor) and refresh every landmark's cached estimate."""
        everything = range(len(self.landmarks))
        values = self.graph.update(self._keys_of(everything) + [X(k), E])
        self._refresh(values, everything, [])
        return values

    def _current(self, j: int) -> int:
        """The landmark that holds landmark j's observations now (j, unless it was merged)."""
        while self.landmarks[j].merged_into is not None:
            j = self.landmarks[j].merged_into
        return j

    def _face_of(self, j: int, T_B_S: np.ndarray) -> str | None:
        """The face behind landmark j's latest observation (a member of its matched group)."""
        lm = self.landmarks[j]
        centre_A = lm.centres_A[-1]
        if lm.face is None or centre_A is None or not self.faces.has_sections(lm.face):
            return lm.face
        centre_B = transform_points(T_B_S @ lm.T_S_A, centre_A[None])[0]
        return self.faces.member_at(self.faces.group_of(lm.face), centre_B)

    def resolve_faces(self, T_B_S: np.ndarray) -> None:
        """Give every observation of every matched landmark its face, with the current estimate."""
        for lm in self.landmarks.items:
            lm.observation_faces = self.faces.observation_faces(lm.face, lm.centres_in(T_B_S))

    def unobservable(self) -> list[dict]:
        faces = {lm.face for lm in self.landmarks.items if lm.face is not None}
        return self.unobservable_with(self.faces.planes[[self.faces.row[f] for f in sorted(faces)], :3] if faces else np.zeros((0, 3)))

    def unobservable_with(self, normals_B: np.ndarray) -> list[dict]:
        """Directions of `T_B_S` that faces with these normals (and gravity, if the sequence
        is gravity-aligned) leave unobserved."""
        return unobservable_directions(normals_B, self.cfg.unobservable_min_angle_deg, self.gravity_aligned)

    # -- pieces -----------------------------------------------------------------------------
    def _check_follows(self, kf: Keyframe) -> None:
        """InputError, before the graph is touched, for a keyframe that does not follow the
        last (gtsam would refuse its pose's key, and the graph would hold half of it) or whose
        pose or planes are not finite (`Keyframe`'s own checks pass by where a caller sets
        fields)."""
        if self._keyframes and out_of_order(last := self._keyframes[-1], kf):
            raise InputError(f"keyframe {kf.index} (stamp {kf.stamp}) does not follow keyframe {last.index} "
                             f"(stamp {last.stamp}): indices and stamps must increase")
        if not all(math.isfinite(v) for v in kf.T_S_C):
            raise InputError(f"keyframe {kf.index}: T_S_C {list(kf.T_S_C)} is not finite")
        for i, p in enumerate(kf.planes):
            if not all(math.isfinite(v) for v in (*p.n, p.d)):
                raise InputError(f"keyframe {kf.index}: plane {i} (n {list(p.n)}, d {p.d}) is not finite")

    def _add_pose(self, kf: Keyframe) -> np.ndarray:
        self._keyframes.append(kf)
        for before, gap in self.odometry.follow(kf):
            self.graph.add_odometry(gap.index, self.odometry.factor(before, gap))
        if self._previous is None:
            guess = self.odometry.pose(kf)
            self.graph.add(self.build.first_pose(kf.index, guess))
        else:
            previous, T_S_Cprev = self._previous
            odometry = self.odometry.factor(previous, kf)
            self.graph.add_odometry(kf.index, odometry)
            guess = T_S_Cprev @ odometry.measured().matrix()
            if self.gravity_aligned:  # (the first pose's prior holds its tilt already)
                self.graph.add(self.build.gravity(kf.index, self.odometry.pose(kf)))
        self.graph.insert_pose(kf.index, guess)
        if self.tilt is not None and kf.planes:
            self.graph.insert(TILT(kf.index), np.zeros(2))
            self.graph.add(self.tilt.prior(kf.index))
            self._tilted.add(kf.index)
        return guess

    def _correct_drift(self) -> bool:
        """Fit the front-end's drift rates to the estimate so far; if they changed, queue every
        odometry factor again without them (`bimgraph.backend.drift`; no extrapolation here,
        since the graph grows between fits). Whether they changed."""
        estimate = self.graph.estimate([X(kf.index) for kf in self._keyframes])  # (not the frozen copies)
        cfg = self.cfg.offline
        smoothed = [estimate.atPose3(X(kf.index)).matrix() for kf in self._keyframes]
        fitted = self.odometry.fitted_drift(self._keyframes, smoothed, cfg.drift_probability)
        if not fitted.differs(self.odometry.drift, cfg.drift_rtol):
            return False
        self.odometry.drift = fitted
        for previous, kf in zip(self._keyframes, self._keyframes[1:]):
            self.graph.add_odometry(kf.index, self.odometry.factor(previous, kf))
        return True

    def _match_observations(self, k: int, observations: list[Observation], T_S_C: np.ndarray) -> list[int | None]:
        matches = [j for j, _ in self.slam.associate(observations, T_S_C, self.landmarks)]
        if self.oracle is None:
            return matches
        out = []
        for obs, j in zip(observations, matches):
            face = self.oracle.get((k, obs.index))
            if face is not None:
                out.append(self._landmark_of_face.get(face))
            else:  # clutter, floors: associated as usual but never onto a face's landmark
                out.append(j if j is not None and self.landmarks[j].face is None else None)
        return out

    def _add_observation(self, k: int, obs: Observation, j: int | None, T_S_C: np.ndarray) -> int:
        if j is None:
            j = len(self.landmarks)
            self.landmarks.add(Landmark(j, k, obs.plane_C, obs.cov, T_S_C))
            self.graph.insert_plane(j, obs.plane_C)
            self._observe(k, j, obs.plane_C, obs.cov, T_S_C)
            face = self.oracle.get((k, obs.index)) if self.oracle is not None else None
            if face is not None:
                self._landmark_of_face[face] = j
                self.matches.set_face(j, face, 0.0)
        elif self.landmarks[j].frozen is not None:
            self.graph.add_frozen_observation(k, self.landmarks[j].frozen, obs.plane_C, obs.cov)
        else:
            self._observe(k, j, obs.plane_C, obs.cov, T_S_C)
        self.matches.seen(k, obs)
        lm = self.landmarks[j]
        if self.oracle is None and (k, obs.index) in self.seeds:
            self._seed(lm, self.seeds[k, obs.index])
        lm.add_observation(k, obs.index, transform_points(self.landmarks.T_A_S[j] @ T_S_C, obs.points_C), obs.area,
                           self.cfg.slam_association.extent_max_points)
        # (its bounding sphere is recomputed by `_refresh`, which sets every observed landmark's estimate)
        if lm.frozen is None and len(lm.observations) >= self.cfg.isam2.freeze_after and self._freezable(lm):
            lm.frozen = FrozenPlane.of(lm.T_S_A, lm.plane_A, lm.cov_A)
        return j

    def _seed(self, lm: Landmark, face: str) -> None:
        """Match the landmark of a seed pair's detection to the pair's face (the user's word),
        unless another landmark holds that face already (the face's match stands)."""
        if lm.face == face or lm.frozen is not None or any(other.face == face for other in self.landmarks.current()):
            return
        if lm.face is not None:
            self.matches.unmatch(lm, f"paired with {face} by a seed")
        self.matches.set_face(lm.id, face, 0.0)

    def _observe(self, k: int, j: int, plane_C: np.ndarray, cov: np.ndarray, T_S_C: np.ndarray | None = None) -> None:
        """Keyframe k's observation of landmark j (not frozen) into the graph; where keyframe k
        has a tilt variable, seen from a moved copy of the landmark's anchor that the tilt
        moves (`T_S_C`: keyframe k's pose as far as known; None: its current estimate, for a
        merge)."""
        lm = self.landmarks[j]
        if k not in self._tilted:
            self.graph.add_observation(j, self.build.observation(k, lm.anchor, j, plane_C, cov))
            return
        moved = MOVED_ANCHOR(self._moved)
        self._moved += 1
        T_S_A = pose3(lm.T_S_A)
        if k == lm.anchor:
            T_S_C = T_S_A
        else:
            T_S_C = self.graph.estimate([X(k)]).atPose3(X(k)) if T_S_C is None else pose3(T_S_C)
        self.graph.insert(moved, T_S_A)
        link, factor = self.tilt.observation(self.build, k, j, lm.anchor, moved, T_S_C, T_S_A, lm.plane_A, plane_C, cov)
        self.graph.add(link)
        self.graph.add_observation(j, factor)

    def _freezable(self, lm: Landmark) -> bool:
        """Whether the landmark is level (`isam2.freeze_max_tilt_deg`) and no face of the map is
        within the association's normal angle of it (both with the initial alignment's
        rotation, which is good to a few degrees). Its frozen copies keep the anchor's pose of
        the moment of freezing, from before the drift fits that come later; of a level plane,
        that pose fixes only height and tilt, which drift little."""
        n_B = self.prior.T_B_S[:3, :3] @ self.landmarks.planes_S[lm.id, :3]
        level = abs(n_B[2]) >= np.cos(np.radians(self.cfg.isam2.freeze_max_tilt_deg))
        return bool(level) and not (self.faces.planes[:, :3] @ n_B >= np.cos(np.radians(self.cfg.bim_association.max_normal_angle_deg))).any()

    def _keys_of(self, js) -> list[int]:
        return [L(j) for j in js] + [X(self.landmarks[j].anchor) for j in js]

    def _covariance_due(self, j: int) -> bool:
        n = len(self.landmarks[j].observations)
        if (due := self._due.get(n)) is None:
            due = self._due[n] = covariance_due(n, self.cfg.isam2)
        return due

    def _refresh(self, values: gtsam.Values, estimates, covariances) -> None:
        """Copy landmark estimates (and the marginals of `covariances`) from iSAM2 to the cache."""
        self.landmarks.read(values, sorted(set(estimates) | set(covariances)),
                            {j: self.graph.marginal(L(j)) for j in covariances})


def run_online(keyframes, plane_map: PlaneMap, cfg: BackendConfig, initial: Alignment,
               listener: Listener | None = None, oracle: Oracle | None = None, tilt: DepthTilt | None = None) -> Results:
    """The online estimator over a whole sequence, collected: the causal estimates as emitted."""
    backend = Backend(plane_map, cfg, initial, listener, oracle, tilt=tilt)
    start = time.perf_counter()
    emitted = [backend.process(kf) for kf in keyframes]
    last = emitted[-1]
    backend.resolve_faces(last.T_B_S)
    latency = np.array([r.latency_s for r in emitted])
    timings = {"total_s": time.perf_counter() - start, "latency_median_s": float(np.median(latency)),
               "latency_p95_s": float(np.percentile(latency, 95)), "latency_max_s": float(latency.max()),
               "isam2_median_s": float(np.median([r.isam2_s for r in emitted]))}
    return Results(mode="online", indices=[r.index for r in emitted], stamps=[r.stamp for r in emitted],
                   T_S_C=[r.T_S_C for r in emitted], T_B_C=[r.T_B_C for r in emitted], T_B_S=last.T_B_S,
                   cov_T_B_S=last.cov_T_B_S, unobservable=backend.unobservable(), landmarks=backend.landmarks.current(),
                   timings=timings, bim_tolerance=backend.bim_tolerance)
