"""Offline estimation: the whole sequence at once.

A causal pass of the online estimator first associates observations to landmarks and gives
the starting estimate (a batch start from the drifting front-end alone leaves the far walls
too uncertain to match). Then, in rounds: the graph is built from the associations, a batch
solve (`graph.BatchSolver`) smooths it, the front-end's systematic drift is measured from the
smoothed poses and taken out of its odometry (and its noise tightened to what the smoothed
steps show: `bimgraph.backend.odometry`), and with the smoothed estimates and the joint
marginals of the landmarks (`bimgraph.backend.marginals`) the matches that
stopped fitting are revised, unmatched landmarks are associated, landmarks spanning coplanar
sections of a wall are split per section, and, in a round that split none, landmarks matched
to the same BIM face are merged into one (the loop closures a drifting causal pass misses);
until a round changes nothing. Once the association settles, the robust alignment judges
which plane-to-BIM factors the alignment keeps (`bimgraph.backend.robust_alignment`): the
walls consistent with each other decide the extrinsic and the poses, and a wall built off
plan is measured against them, to the tolerance the kept walls show. It judges on the rest of
the graph's Gaussian marginal on the judged variables (`bimgraph.backend.reduced`: its many
solves are of a few dozen variables), and the next round solves the whole graph under its
verdicts; the rounds go on until neither changes.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import gtsam
import numpy as np
from scipy.special import expit

from bimgraph.backend import drift
from bimgraph.backend.alignment import Alignment
from bimgraph.backend.depth_tilt import DepthTilt, without_tilt
from bimgraph.backend.graph import MOVED_ANCHOR, TILT, E, X, BatchSolver, bim_keys, cov_T_B_S, extrinsic_difference, pose3
from bimgraph.backend.landmarks import KEPT, Landmark
from bimgraph.backend.marginals import JointMarginals
from bimgraph.backend.odometry import OdometryModel
from bimgraph.backend.online import Backend, Oracle, observations_of
from bimgraph.backend.reassociation import Reassociation
from bimgraph.backend.records import Association, KeyframeResult, Listener, Results
from bimgraph.backend.reduced import reduced
from bimgraph.backend.robust_alignment import RobustAlignment
from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import BackendConfig
from bimgraph.deviations.estimate import RivalAlignment, about_estimate
from bimgraph.errors import InputError
from bimgraph.sequence.format import Keyframe

# a rival consensus less likely than this changes no figure the run reports
_NEGLIGIBLE = 1e-6


class OfflineEstimator:
    def __init__(self, plane_map: PlaneMap, cfg: BackendConfig, initial: Alignment,
                 listener: Listener | None = None, oracle: Oracle | None = None, causal: Backend | None = None,
                 tilt: DepthTilt | None = None):
        """`causal`: an online run's `Backend` that has seen the whole sequence, whose graph and
        associations `refine` starts from instead of a causal pass of its own. `tilt`: the
        planes come from the keyframes' depth images, and each keyframe's depth tilt is a
        variable (`bimgraph.backend.depth_tilt`); the causal pass goes without it."""
        self.cfg = cfg
        self.listener = listener or Listener()
        # the causal pass makes no results (`Backend.advance`; the listener hears the smoothed
        # ones) and leaves the drift, the robust alignment and the merging of landmarks to the
        # rounds (merged in the causal pass, on young landmarks' marginals, the deviation report
        # lost: seeds 1-3 offsets within 1 cm 35 of 37 -> 31 of 35). It reads no marginal of the
        # extrinsic per keyframe, so iSAM2 orders the variables its own way (the online
        # ordering makes its updates dearer; on deviation seed 2 it also led the rounds to the
        # other of two nearly equal consensuses, 10.5 cm off, before `_challenge`: now 2.6 cm)
        self.online = causal or Backend(plane_map, cfg, initial, None, oracle, drift_every=0, judge_every=0,
                                        merge=False, extrinsic_last=False)
        self.faces, self.landmarks = self.online.faces, self.online.landmarks
        self.oracle = oracle
        self.reassociation = Reassociation(self.landmarks, self.faces, self.online.matches.bim, cfg, self.listener, self.online.matches.apart)
        self.judge = RobustAlignment(self.faces, self.online.build, self.landmarks, cfg.offline)
        self.odometry = OdometryModel(self.online.build, self.online.odometry.up_S)  # the front-end's drift and noise, as measured
        self.odometry.drift = self.online.odometry.drift  # (an online run's, as a start)
        # (landmark, anchor, keyframe, plane index) -> its observation factor: the graph is
        # rebuilt a score of times, and its plane factors change only where landmarks do
        self._observation_factors: dict[tuple[int, int, int, int], list[gtsam.NonlinearFactor]] = {}
        self.tilt = tilt
        # how the consensus fared against its complement (`_challenge`), for the summary
        self.challenge: dict | None = None
        self._losing_verdicts: dict[tuple[int, str], str] | None = None  # the consensus that lost it

    def run(self, keyframes: list[Keyframe]) -> Results:
        if not keyframes:
            raise InputError("no keyframes to estimate from")
        start = time.perf_counter()
        for kf in keyframes:
            self.online.advance(kf)
        return self.refine(keyframes, {"online_pass_s": time.perf_counter() - start})

    def refine(self, keyframes: list[Keyframe], timings: dict | None = None) -> Results:
        """The rounds, from the causal pass's graph and associations (`keyframes` are the ones it saw)."""
        start = time.perf_counter()
        timings = {} if timings is None else timings
        values = without_tilt(self.online.graph.estimate())
        self.odometry.mark_gaps(keyframes)
        observations = {kf.index: observations_of(kf, self.online.build) for kf in keyframes}

        solve = BatchSolver(self.cfg.offline.max_iterations, self.cfg.offline.relative_error_tol)
        rounds, t_opt, t_assoc, challenged = 0, 0.0, 0.0, False
        while True:
            rounds += 1
            t0 = time.perf_counter()
            graph = self._graph(keyframes, observations, values)
            values = solve(graph, values)
            if self.cfg.offline.estimate_drift:
                graph, values = self._settle_drift(keyframes, observations, values, solve, graph)
            # the joint marginals the rounds and the results read: each active landmark's with its
            # anchor and the extrinsic
            marginals = JointMarginals(graph, values, bim_keys(self.landmarks.current()))
            t1 = time.perf_counter()
            t_opt += t1 - t0
            self.landmarks.read(values, [lm.id for lm in self.landmarks.current()])
            # a landmark spanning sections of a wall is split before any merging: compared
            # whole, a mix of sections built apart is one plane with neither, and the landmark
            # of the section alone would lose its face for good; merging waits for the next
            # round, whose marginals have the new landmarks
            # past `max_rounds`, the landmarks of one face are still merged (or all but one
            # unmatched), so that the robust alignment never counts a face twice: cut off just
            # after a split, deviation seed 2 went to the judgement with five landmarks on a
            # wall built 7 cm off, whose votes carried it (extrinsic 10.5 cm off)
            changed = self.oracle is None and (
                self.reassociation.revise(values) | self.reassociation.associate(values, marginals)
                | (self.reassociation.split(values) or self.reassociation.merge(values, marginals))
                if rounds <= self.cfg.offline.max_rounds else self.reassociation.merge(values, marginals))
            t_assoc += time.perf_counter() - t1
            if not changed and self.cfg.offline.gnc and set(self._matches()) != set(self.judge.verdicts):
                t2 = time.perf_counter()
                judged = reduced(self._graph(keyframes, observations, values, lambda lm: None), values,
                                 [lm for lm in self.landmarks.current() if lm.face is not None])
                values.update(judged.anchored(self.judge.decide(self._matches(), judged)))
                t_opt += time.perf_counter() - t2
                changed = True
            elif not changed and self.cfg.offline.gnc and not challenged:
                challenged, t2 = True, time.perf_counter()
                if (rival := self._challenge(keyframes, observations, values, solve)) is not None:
                    values, changed = rival, True
                t_opt += time.perf_counter() - t2
            if not changed:
                break
        t2 = time.perf_counter()
        rival = self._rival(keyframes, observations, values, solve)
        t_opt += time.perf_counter() - t2
        timings.update(optimisation_s=t_opt, bim_association_s=t_assoc, total_s=timings.get("online_pass_s", 0.0) + time.perf_counter() - start)
        return self._results(keyframes, values, marginals, timings, rounds, rival)

    def _challenge(self, keyframes: list[Keyframe], observations, values: gtsam.Values,
                   solve: BatchSolver) -> gtsam.Values | None:
        """The robust alignment's consensus against its complement, on the whole graph. Where
        walls built off plan happen to agree with one another (on deviation seed 2, four of the
        seven walls across x moved 7-10 cm the same way), two consensuses explain the data
        nearly alike, and which one the judgement, on the marginal at the rounds' estimate,
        picks depends on where the causal pass left it (an initial alignment 7 cm closer to
        the truth put seed 2 10 cm off). So once the rounds settle, its complement is found
        on the whole graph (`RobustAlignment.complement`: the walls it did not keep whole kept
        whole, the others taken as unsure, the graph judged again from there); both estimates
        re-solved under their verdicts without robust kernel, the one of lower
        truncated-least-squares cost stays. Returns the
        complement's estimate if it won, else None (also when every wall was kept). Records in
        `challenge` the margin between the two costs (half chi-square units: a few mean the
        data hardly choose) and the faces whose verdicts differ."""
        matches = self._matches()
        if all(verdict == KEPT for verdict in self.judge.verdicts.values()):
            return None
        ours_verdicts = dict(self.judge.verdicts)

        def solve_under(verdicts: dict, start: gtsam.Values) -> gtsam.Values:
            return solve(self._graph(keyframes, observations, start, self.judge.factors(verdicts)), start)

        without_bim = self._graph(keyframes, observations, values, lambda lm: None)
        rival_verdicts, rival = self.judge.complement(matches, solve_under, without_bim, values)
        ours = solve_under(self.judge.verdicts, values)
        margin = self.judge.margin(without_bim, matches, rival, ours)
        self.challenge = {"complement_taken": bool(margin < 0), "margin": round(abs(float(margin)), 3),
                          "contested_faces": sorted({face for (j, face) in matches
                                                     if rival_verdicts[j, face] != self.judge.verdicts[j, face]})}
        self._losing_verdicts = rival_verdicts if margin >= 0 else ours_verdicts
        if margin >= 0:
            return None
        judged = reduced(without_bim, rival, [lm for lm in self.landmarks.current() if lm.face is not None])
        rival.update(judged.anchored(self.judge.adopt(matches, judged)))
        return rival

    def _matches(self) -> list[tuple[int, str]]:
        return [(lm.id, lm.face) for lm in self.landmarks.current() if lm.face is not None]

    def _graph(self, keyframes: list[Keyframe], observations, values: gtsam.Values,
               bim_factor: Callable[[Landmark], gtsam.NonlinearFactor | None] | None = None) -> gtsam.NonlinearFactorGraph:
        """The whole graph, from the front-end poses and the current associations; each
        matched landmark's plane-to-BIM factor from `bim_factor` (default: as the robust
        alignment judged it). A variable it adds that `values` lacks (the tilt's, for a landmark
        new since the last solve) gets its starting value there."""
        build = self.online.build
        bim_factor = bim_factor or self.judge.judged_factor
        graph = gtsam.NonlinearFactorGraph()
        graph.add(build.extrinsic_prior(self.online.prior.T_B_S, self.online.prior.cov))
        graph.add(build.first_pose(keyframes[0].index, self.odometry.pose(keyframes[0])))
        for previous, kf in zip(keyframes, keyframes[1:]):
            graph.add(self.odometry.factor(previous, kf))
        if self.online.gravity_aligned:
            for kf in keyframes[1:]:
                graph.add(build.gravity(kf.index, self.odometry.pose(kf)))
        if self.tilt is not None:
            for kf in keyframes:
                if kf.planes:
                    graph.add(self.tilt.prior(kf.index))
                    if not values.exists(TILT(kf.index)):
                        values.insert(TILT(kf.index), np.zeros(2))
        for lm in self.landmarks.current():
            for k, i in lm.observations:
                key = (lm.id, lm.anchor, k, i)
                if key not in self._observation_factors:
                    self._observation_factors[key] = self._observation(lm, k, observations[k][i], values)
                for factor in self._observation_factors[key]:
                    graph.add(factor)
            factor = bim_factor(lm) if lm.face is not None else None
            if factor is not None:
                graph.add(factor)
        return graph

    def _observation(self, lm: Landmark, k: int, obs, values: gtsam.Values) -> list[gtsam.NonlinearFactor]:
        """Keyframe k's observation of landmark `lm`: its factor, and with the tilt the tie of
        its moved anchor, made where `values` has anchor and keyframe (and there it starts)."""
        build = self.online.build
        if self.tilt is None:
            return [build.observation(k, lm.anchor, lm.id, obs.plane_C, obs.cov)]
        moved = MOVED_ANCHOR(len(self._observation_factors))
        T_S_A = values.atPose3(X(lm.anchor))
        values.insert(moved, T_S_A)
        return self.tilt.observation(build, k, lm.id, lm.anchor, moved, values.atPose3(X(k)), T_S_A, lm.plane_A,
                                     obs.plane_C, obs.cov)

    def _settle_drift(self, keyframes: list[Keyframe], observations, values: gtsam.Values, solve: BatchSolver,
                      graph: gtsam.NonlinearFactorGraph) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """Fit the front-end's drift rates to the smoothed poses, take them out of the odometry
        and re-solve until they settle; then, once a round, fit its noise to the smoothed steps.
        The graph and estimate it ends with."""
        cfg = self.cfg.offline
        settle = drift.Settle()
        for _ in range(cfg.drift_iterations):
            fitted = self.odometry.fitted_drift(keyframes, [values.atPose3(X(kf.index)).matrix() for kf in keyframes],
                                                cfg.drift_probability)
            rates = settle.next(self.odometry.drift, fitted)
            if not rates.differs(self.odometry.drift, cfg.drift_rtol):
                break
            self.odometry.drift = rates
            graph = self._graph(keyframes, observations, values)
            values = solve(graph, values)
        # with no drift to take out, small step residuals cannot tell a precise front-end from
        # walls that gave way to a biased one: the noise stays as given; nor with the depth
        # tilt, where the tightened odometry cost what the tilt gains (eight depth walks:
        # extrinsic RMS 0.89 cm with the noise as given, 2.11 tightened, 2.04 without the tilt)
        if cfg.estimate_odometry_noise and not self.odometry.drift.is_zero() and self.tilt is None:
            variance = self.odometry.estimated_variance(keyframes, graph, values, cfg.tolerance_confidence,
                                                        cfg.odometry_noise_floor, cfg.odometry_noise_steps)
            if not np.allclose(variance, self.odometry.variance, rtol=2 * cfg.drift_rtol):
                self.odometry.variance = variance
                graph = self._graph(keyframes, observations, values)
                values = solve(graph, values)
        return graph, values

    def _observed_planes(self, values, marginals, bim_factor: Callable[[Landmark], gtsam.NonlinearFactor | None]) -> list:
        """Every active landmark as the deviation step reads it; a matched landmark's plane-to-BIM
        factor (`bim_factor`) is the one of the graph `values` and `marginals` solve."""
        from bimgraph.deviations.graph import observed_planes  # (it imports the backend)

        return observed_planes(self.landmarks.current(), values, marginals,
                               {lm.id: bim_factor(lm) for lm in self.landmarks.current() if lm.face is not None})

    def _rival(self, keyframes: list[Keyframe], observations, values: gtsam.Values, solve: BatchSolver) -> RivalAlignment | None:
        """The consensus `_challenge` turned down, solved again from where the rounds ended,
        with its probability against the estimate's, `1 / (1 + e^margin)`, the margin the
        difference of their truncated-least-squares costs (as `_challenge` compares them: a
        negative log-likelihood ratio). None where it judges every face as the estimate does,
        or is less likely than `_NEGLIGIBLE`. Where two parallel walls are all that place a
        direction and one of them is built off plan, the data cannot tell which one: a
        2Storey depth walk's two consensuses 0.25 apart (probability 0.44), each putting the
        other wall 5.5 cm off."""
        if self._losing_verdicts is None:
            return None
        matches = self._matches()
        verdicts = {m: self._losing_verdicts.get(m, self.judge.verdicts[m]) for m in matches}
        if all(verdicts[m] == self.judge.verdicts[m] for m in matches):
            return None
        factors = self.judge.factors(verdicts)
        graph = self._graph(keyframes, observations, values, factors)
        rival = solve(graph, values)
        without_bim = self._graph(keyframes, observations, values, lambda lm: None)
        probability = float(expit(-self.judge.margin(without_bim, matches, rival, values)))
        self.challenge["rival_probability"] = float(f"{probability:.3g}")
        if probability < _NEGLIGIBLE:
            return None
        marginals = JointMarginals(graph, rival, bim_keys(self.landmarks.current()))
        T_S_B = rival.atPose3(E)
        planes = self._observed_planes(rival, marginals, factors)
        return RivalAlignment(probability, T_S_B.matrix(), cov_T_B_S(T_S_B, marginals.marginal(E)) + self.online.locked_cov,
                              {plane.landmark: plane for plane in planes})

    def _results(self, keyframes, values, marginals, timings, rounds, rival: RivalAlignment | None) -> Results:
        start = time.perf_counter()
        planes = self._observed_planes(values, marginals, self.judge.judged_factor)
        timings["deviation_covariances_s"] = time.perf_counter() - start
        T_S_B = values.atPose3(E)
        T_B_S = T_S_B.inverse().matrix()
        cov = cov_T_B_S(T_S_B, marginals.marginal(E)) + self.online.locked_cov
        if rival is not None:
            cov = about_estimate(cov, rival.cov_T_B_S, extrinsic_difference(T_S_B, pose3(rival.T_S_B)), rival.probability)
        T_S_C = [values.atPose3(X(kf.index)).matrix() for kf in keyframes]
        self.online.resolve_faces(T_B_S)
        for lm in self.landmarks.current():
            lm.alignment = self.judge.verdicts.get((lm.id, lm.face), KEPT)
        face_of, landmark_of = {}, {}
        for lm in self.landmarks.current():
            for obs, face in zip(lm.observations, lm.observation_faces):
                face_of[obs], landmark_of[obs] = face, lm.id
        for kf, pose in zip(keyframes, T_S_C):
            self.listener.on_keyframe(KeyframeResult(
                kf.index, kf.stamp, pose, T_B_S @ pose, T_B_S, cov,
                [Association(i, landmark_of[(kf.index, i)], face_of[(kf.index, i)]) for i in range(len(kf.planes))],
                float("nan"), keyframe=kf))
        faces = sorted({lm.face for lm in self.landmarks.current() if lm.face is not None})
        normals = self.faces.planes[[self.faces.row[f] for f in faces], :3] if faces else np.zeros((0, 3))
        return Results(mode="offline", indices=[kf.index for kf in keyframes], stamps=[kf.stamp for kf in keyframes],
                       T_S_C=T_S_C, T_B_C=[T_B_S @ p for p in T_S_C], T_B_S=T_B_S, cov_T_B_S=cov,
                       unobservable=self.online.unobservable_with(normals),
                       landmarks=self.landmarks.current(), timings=timings, rounds=rounds, observed_planes=planes,
                       bim_tolerance=self.judge.tolerance, frontend_drift=self.odometry.summary() if self.cfg.offline.estimate_drift else None,
                       alignment_challenge=self.challenge, rival_alignment=rival,
                       depth_tilt_sigma_per_m=self.tilt.sigma_per_m if self.tilt is not None else None)

def run_offline(keyframes: list[Keyframe], plane_map: PlaneMap, cfg: BackendConfig, initial: Alignment,
                listener: Listener | None = None, oracle: Oracle | None = None, tilt: DepthTilt | None = None) -> Results:
    return OfflineEstimator(plane_map, cfg, initial, listener, oracle, tilt=tilt).run(keyframes)
