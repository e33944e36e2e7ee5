"""The online estimator's plane-to-BIM matches: landmarks matched to faces as they are seen,
unmatched when they stop fitting, and landmarks of one face merged into one. No I/O."""

from __future__ import annotations

import functools
from collections.abc import Callable

import gtsam
import numpy as np

from bimgraph.backend.associate_bim import BimAssociator, FaceIndex, FaceMatch, candidate
from bimgraph.backend.associate_slam import Observation
from bimgraph.backend.incremental import IncrementalGraph
from bimgraph.backend.landmarks import KEPT, Landmark, LandmarkTable
from bimgraph.backend.matches import behind, face_misfit, offset_sigma, one_plane_d2, revision_reason, unmatch
from bimgraph.backend.records import Listener
from bimgraph.config import BackendConfig


class OnlineBimAssociation:
    """Matches the landmarks of `landmarks` to the faces of `faces` and keeps the graph's
    plane-to-BIM factors as the matches stand. `extrinsic_covariance(T_S_B)` is the
    extrinsic's covariance as the graph stands; `slam_gate` the SLAM association's chi-square
    gate, which decides whether two landmarks of one face are one plane; `observe(k, j,
    plane_C, cov)` puts keyframe k's observation of landmark j into the graph, for a merge to
    move a landmark's observations to another; None keeps such landmarks apart (the offline
    rounds merge them)."""

    def __init__(self, faces: FaceIndex, cfg: BackendConfig, graph: IncrementalGraph, landmarks: LandmarkTable,
                 listener: Listener, extrinsic_covariance: Callable[[gtsam.Pose3], np.ndarray], slam_gate: float,
                 observe: Callable[[int, int, np.ndarray, np.ndarray], None] | None = None):
        self.faces, self.cfg, self.graph, self.landmarks, self.listener = faces, cfg, graph, landmarks, listener
        self.bim = BimAssociator(faces, cfg.bim_association)
        self.extrinsic_covariance = extrinsic_covariance
        self.observe = observe
        self.slam_gate = slam_gate
        # (landmark, face) pairs found not one plane with another landmark of the face: the one
        # farther from it stays apart from it (online here, offline when merging)
        self.apart: set[tuple[int, str]] = set()
        self._observations: dict[tuple[int, int], Observation] = {}  # (keyframe, index) -> as seen, for merges
        self._merged: list[int] = []  # landmarks that took another's observations since `take_merged`

    def seen(self, k: int, obs: Observation) -> None:
        """Keep keyframe k's observation, which a merge may move to another landmark."""
        if self.observe is not None:
            self._observations[k, obs.index] = obs

    def take_merged(self) -> list[int]:
        """The landmarks that took another's observations since the last call."""
        merged, self._merged = self._merged, []
        return merged

    def set_face(self, j: int, face: str, score: float) -> None:
        lm = self.landmarks[j]
        lm.face, lm.score, lm.alignment = face, score, KEPT
        row = self.faces.row[face]
        self.graph.add_bim(j, lm.anchor, self.faces.planes[row], self.faces.centres[row])
        self.listener.on_association(j, face, score)

    def unmatch(self, lm: Landmark, reason: str) -> None:
        self.graph.remove_bim(lm.id)
        unmatch(lm, reason, self.listener)

    def revise(self, landmarks, T_S_B: np.ndarray) -> bool:
        """Unmatch those of `landmarks` (ids, just refreshed) that no longer fit their face. An
        offset the extrinsic's own uncertainty explains does not count against a match: site 3
        with its initial alignment moved to 37 cm off matched a wall across x rightly three
        times and unmatched it each time 25 cm off, while its factor was still pulling the
        extrinsic over (causal ATE 21.2 -> 11.7 cm; no other walk of the six, under seven
        initial alignments, changed). Nor does a normal the BIM gate still takes (its Mahalanobis
        test and filters, on the marginal that now includes the match): after a long stretch
        without planes the heading has drifted by degrees the poses' covariance allows, the
        gate matches the walls again, and their kernels turn the heading back only over a few
        keyframes (office 2 without planes in keyframes 100-349: every such match was
        unmatched at the next keyframe "normal 5-7 deg off", the walk stayed 6.7 deg and 24 cm
        off). The gate's as-built tolerance (`face_normal_deg`) alone takes a wall turned up to
        about 6 deg from plan, however sure its landmark: such a wall stays matched, and the
        robust alignment's judgement, not this limit, decides whether it counts. Whether a
        match changed."""
        matched = [j for j in sorted(set(landmarks))
                   if self.landmarks[j].face is not None and self.landmarks[j].merged_into is None]
        if not matched:
            return False

        # (the pose and the covariance asked for only where a misfit is past its limit)
        @functools.cache
        def pose_S_B() -> gtsam.Pose3:
            return gtsam.Pose3(T_S_B)

        @functools.cache
        def extrinsic_cov() -> np.ndarray:
            return self.extrinsic_covariance(pose_S_B())

        def sigma(j: int, face: str) -> float:
            return offset_sigma(self.landmarks.planes_S[j], T_S_B, self.faces.centres[self.faces.row[face]], extrinsic_cov())

        changed = False
        # (the planes in B at once: a plane is a covector, (n, d)_B = T_S_B^T (n, d)_S; their
        # estimates were just refreshed)
        for j, plane_B in zip(matched, self.landmarks.planes_S[matched] @ T_S_B):
            lm = self.landmarks[j]
            reason = revision_reason(plane_B, self.faces, lm.face, self.cfg.bim_association,
                                     lambda: sigma(lm.id, lm.face),
                                     lambda: self._gate_takes(lm, lm.face, pose_S_B()))
            if reason is not None:
                self.unmatch(lm, reason)
                changed = True
        return changed

    def associate(self, observed: list[int], T_S_B: gtsam.Pose3) -> bool:
        """Match those of `observed` (landmark ids) that are unmatched and worth a try. Whether
        a match changed."""
        # a frozen landmark takes no plane-to-BIM factor: its later observations do not reach it
        todo = [j for j in sorted(set(observed)) if self.landmarks[j].face is None and self.landmarks[j].frozen is None
                and self.bim.eligible(self.landmarks[j].area, len(self.landmarks[j].observations),
                                      self.landmarks[j].bim_attempt)]
        if not todo:
            return False
        candidates = []
        for j in todo:
            self.landmarks[j].bim_attempt = len(self.landmarks[j].observations)
            if (c := candidate(self.landmarks[j], T_S_B, self.graph.joint, self.bim)) is not None:
                candidates.append(c)
        changed = False
        for m in self.bim.match(candidates):
            if (m.landmark, m.face) not in self.apart and not self._shadowed(m, T_S_B):
                changed |= self._claim(m, T_S_B)
        return changed

    def _shadowed(self, m: FaceMatch, T_S_B: gtsam.Pose3) -> bool:
        """Whether a landmark behind the matched one, by more than `shadow_gap_m` but within
        what the extrinsic's uncertainty at the face allows (`shadow_sigmas`;
        `matches.behind`), unmatched or matched to the same face, scores for that face too and
        is not one plane with it (`offline.merge_gate`): then the match waits, until the
        extrinsic tells the two apart or the one behind takes the face. A partition or a
        cabinet stands before the wall it parallels; while the extrinsic is uncertain by more
        than their gap, both pass the face's gate (site 13: a partition 24 cm before a wall,
        seen three times before the wall was, took its face under the initial alignment's 20
        cm; online the extrinsic ended 24 cm off, offline 0.3). Once the extrinsic is sure,
        the gate alone decides: a plane seen behind a wall through its door is no wall."""
        lm, cfg = self.landmarks[m.landmark], self.cfg.bim_association
        gaps = behind(lm, self.landmarks, self.bim.cos_max, cfg.shadow_gap_m)
        if not gaps:
            return False  # (before the extrinsic's marginal, which costs an iSAM2 query)
        row = self.faces.row[m.face]
        sigma = offset_sigma(self.landmarks.planes_S[lm.id], T_S_B.matrix(), self.faces.centres[row],
                             self.extrinsic_covariance(T_S_B))
        for k, gap in gaps.items():
            other = self.landmarks[k]
            if gap > cfg.shadow_sigmas * sigma or other.face not in (None, m.face) or other.frozen is not None:
                continue
            if self._gate_takes(other, m.face, T_S_B) and one_plane_d2(other, lm, self.graph.joint) > self.cfg.offline.merge_gate:
                return True
        return False

    def _gate_takes(self, lm: Landmark, face: str, T_S_B: gtsam.Pose3) -> bool:
        """Whether the BIM gate and the geometric filters, with the landmark's joint marginal
        as the graph has it now, take `face` (its group) for landmark `lm`."""
        c = candidate(lm, T_S_B, self.graph.joint, self.bim)
        return c is not None and self.faces.group_of(face) in self.bim.scores(c)

    def _claim(self, m: FaceMatch, T_S_B: gtsam.Pose3) -> bool:
        """Match landmark and face. If the face has a landmark that is one plane with this one
        by the SLAM association's gate (a wall seen in parts, or again after the drift grew),
        this one merges into it: a plane-to-BIM factor per landmark would count the face's
        as-built tolerance once per landmark. A pair that passes only offline merging's wider
        gate (young landmarks: a board on the wall passes it at three observations) stays two
        matches. Of a pair that is not one plane even by that (a cabinet's front before the wall
        it stands at), the one farther from the face goes without and stays apart from it.
        Whether a match changed."""
        lm = self.landmarks[m.landmark]
        for rival in [other for other in self.landmarks.items if other.face == m.face and other.id != lm.id]:
            d2 = one_plane_d2(rival, lm, self.graph.joint)
            if self.observe is not None and d2 <= self.slam_gate:
                self._merge(rival, lm)
                return True
            if d2 <= self.cfg.offline.merge_gate:
                continue
            worse = max((rival, lm), key=lambda x: face_misfit(x, m.face, self.faces, T_S_B, self.cfg.bim_association))
            self.apart.add((worse.id, m.face))
            if worse is lm:
                return False
            self.unmatch(rival, "not one plane with another landmark of its face")
        self.set_face(m.landmark, m.face, m.score)
        return True

    def _merge(self, keep: Landmark, gone: Landmark) -> None:
        """`gone` is `keep`'s plane (one face, one plane): its observations move to `keep`."""
        for k, i in gone.observations:
            obs = self._observations[k, i]
            self.observe(k, keep.id, obs.plane_C, obs.cov)
        self.graph.retire(gone.id, self.graph.build.anchor_observation(gone.id, gone.plane_A, gone.cov_A))
        self.landmarks.merge(keep, gone, self.cfg.slam_association.extent_max_points)
        self._merged.append(keep.id)

