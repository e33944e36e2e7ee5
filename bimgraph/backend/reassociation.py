"""The offline rounds' re-association: on the smoothed estimate and the joint marginals of a
round, matches that stopped fitting are revised, unmatched landmarks associated, landmarks
spanning coplanar sections of a wall split per section, and landmarks matched to one face
merged (the loop closures a drifting causal pass misses). Each step says whether it changed
anything; `bimgraph.backend.offline` repeats the rounds until none does."""

from __future__ import annotations

from collections import Counter

import gtsam
import numpy as np

from bimgraph.backend.associate_bim import BimAssociator, FaceIndex, candidate
from bimgraph.backend.graph import E, L, X, pose3
from bimgraph.backend.landmarks import Landmark, LandmarkTable, transform_points
from bimgraph.backend.marginals import JointMarginals
from bimgraph.backend.matches import face_misfit, one_plane_d2, revision_reason, unmatch
from bimgraph.backend.records import Listener
from bimgraph.config import BackendConfig
from bimgraph.geometry import inverse, plane_from_frame
from factors.plane import predict_local_plane


class Reassociation:
    """`apart`: (landmark, face) pairs merging found not to be one plane; shared with the
    online association, whose pairs hold here too."""

    def __init__(self, landmarks: LandmarkTable, faces: FaceIndex, bim: BimAssociator, cfg: BackendConfig,
                 listener: Listener, apart: set[tuple[int, str]]):
        self.landmarks, self.faces, self.bim, self.cfg = landmarks, faces, bim, cfg
        self.listener, self.apart = listener, apart

    def revise(self, values: gtsam.Values) -> bool:
        changed = False
        T_S_B = values.atPose3(E)
        for lm in self.landmarks.current():
            if lm.face is None:
                continue
            plane_B = predict_local_plane(T_S_B, pose3(lm.T_S_A), gtsam.OrientedPlane3(lm.plane_A))
            reason = revision_reason(plane_B, self.faces, lm.face, self.cfg.bim_association)
            if reason is not None:
                unmatch(lm, reason, self.listener)
                changed = True
        return changed

    def associate(self, values: gtsam.Values, marginals: JointMarginals) -> bool:
        todo = [lm for lm in self.landmarks.current() if lm.face is None and self.bim.eligible(lm.area, len(lm.observations))]
        if not todo:
            return False
        candidates = [c for c in (candidate(lm, values.atPose3(E), marginals, self.bim) for lm in todo) if c is not None]
        # a face merging took a landmark off would only pull it back: it stays apart
        matches = [m for m in self.bim.match(candidates) if (m.landmark, m.face) not in self.apart]
        for m in matches:
            lm = self.landmarks[m.landmark]
            lm.face, lm.score = m.face, m.score
            self.listener.on_association(lm.id, m.face, m.score)
        return bool(matches)

    def split(self, values: gtsam.Values) -> bool:
        """A landmark whose observations lie on several coplanar sections of a wall becomes one
        landmark per section: built, the sections may differ by centimetres."""
        T_B_S = values.atPose3(E).inverse().matrix()
        split = False
        for lm in self.landmarks.current():
            faces = self.faces.observation_faces(lm.face, lm.centres_in(T_B_S))
            counts = Counter(faces)
            if lm.face is None:
                continue
            if len(counts) == 1:
                # all on another section than the one matched (ExternalEarth seed 6: a wall's
                # landmark matched, while the alignment was young, to the basement wall
                # below it, coplanar; the report then blamed the basement wall)
                split |= faces[0] != lm.face
                lm.face = faces[0]
                continue
            lm.face = counts.most_common(1)[0][0]
            # (in order of first observation: iterating a set of face ids would number the new
            # landmarks by Python's string hashing, so that runs differed)
            for face in [f for f in counts if f != lm.face]:
                moved = [n for n, f in enumerate(faces) if f == face]
                anchor = lm.observations[moved[0]][0]
                T_S_A = values.atPose3(X(anchor)).matrix()
                T_new_old = inverse(T_S_A) @ lm.T_S_A
                new = Landmark(len(self.landmarks), anchor, plane_from_frame(lm.plane_A, T_new_old), lm.cov_A, T_S_A,
                               face=face, score=lm.score)
                for n in moved:
                    centre = lm.centres_A[n]
                    points = np.zeros((0, 3)) if centre is None else transform_points(T_new_old, centre[None])
                    new.add_observation(*lm.observations[n], points, None, self.cfg.slam_association.extent_max_points)
                self.landmarks.add(new)
                values.insert(L(new.id), gtsam.OrientedPlane3(new.plane_A))
                self.listener.on_association(new.id, face, new.score)
            kept = [n for n, f in enumerate(faces) if f == lm.face]
            lm.observations = [lm.observations[n] for n in kept]
            lm.centres_A = [lm.centres_A[n] for n in kept]
            split = True
        return split

    def merge(self, values: gtsam.Values, marginals: JointMarginals) -> bool:
        """Landmarks matched to one BIM face are one plane: the oldest absorbs the others, if
        they pass `offline.merge_gate` as one plane. Two that do not are not both that wall (a board
        leaning on it, a cabinet's front): the one farther from the face loses the match and
        stays apart from it. (Coplanar sections of a wall stay apart: built, they may differ.)"""
        by_face: dict[str, list] = {}
        for lm in self.landmarks.current():
            if lm.face is not None:
                by_face.setdefault(lm.face, []).append(lm)
        changed = False
        for face, same in by_face.items():
            keep = min(same, key=lambda lm: (lm.anchor, lm.id))
            for other in (lm for lm in same if lm is not keep):
                changed = True
                if one_plane_d2(keep, other, marginals) <= self.cfg.offline.merge_gate:
                    self.landmarks.merge(keep, other, self.cfg.slam_association.extent_max_points)
                    values.erase(L(other.id))
                    continue
                worse = max((keep, other), key=lambda lm: face_misfit(lm, face, self.faces, values.atPose3(E), self.cfg.bim_association))
                self.apart.add((worse.id, face))
                unmatch(worse, "not one plane with another landmark of its face", self.listener)
                break  # the face's other landmarks meet the one left next round
        return changed
