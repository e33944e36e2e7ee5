"""Following a backend run in the viewer: the backend's `Listener` hooks turned into
`RerunViewer` calls. Each keyframe result carries its input keyframe (front-end pose,
detected planes, depth image path); depth images are read from the sequence folder."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bimgraph.backend.records import KeyframeResult, Listener
from bimgraph.viewer.rerun_viewer import FaceState, RerunViewer


def read_depth(path: Path) -> np.ndarray | None:
    """A 16-bit depth PNG as stored (metres * depth_scale), or None if it cannot be read."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return image if image is not None and image.ndim == 2 else None


class RerunListener(Listener):
    """Logs every keyframe result of an online or offline run into `viewer`; depth images
    are read from `sequence_root` when given."""

    def __init__(self, viewer: RerunViewer, sequence_root: Path | None = None):
        self.viewer = viewer
        self.sequence_root = None if sequence_root is None else Path(sequence_root)
        self._matched: dict[int, str] = {}  # landmark -> face
        self._started = False

    def on_keyframe(self, result: KeyframeResult) -> None:
        self._started = True
        kf = result.keyframe
        planes = kf.planes
        plane_faces: list[str | None] = [None] * len(planes)
        for a in result.associations:
            if 0 <= a.observation < len(planes):
                plane_faces[a.observation] = a.face
        depth = None
        if kf.depth is not None and self.sequence_root is not None and self.viewer.cfg.depth_images:
            depth = read_depth(self.sequence_root / kf.depth)
        latency = result.latency_s if np.isfinite(result.latency_s) else None
        self.viewer.keyframe(result.index, result.stamp, T_S_C=kf.pose, T_B_C=result.T_B_C, T_B_S=result.T_B_S,
                             cov_T_B_S=result.cov_T_B_S, planes=planes, plane_faces=plane_faces,
                             associations=len(self._matched), latency_s=latency, depth=depth)

    def on_association(self, landmark_id: int, face_id: str, score: float) -> None:
        # The face turns "associated" when a keyframe result shows the match.
        self._matched[landmark_id] = face_id

    def on_association_removed(self, landmark_id: int, face_id: str, reason: str) -> None:
        self._matched.pop(landmark_id, None)
        # Before the first result these are an offline run's intermediate rounds, whose
        # outcome the per-keyframe results show.
        if self._started and face_id not in self._matched.values():
            self.viewer.set_face_state(face_id, FaceState.OBSERVED)


def mark_deviations(viewer: RerunViewer, status_by_face: Mapping[str, str]) -> int:
    """Colour the faces whose deviation status is "deviating" or "contested"
    (`session.face_statuses`); returns how many. Call at the end of a run, before
    `viewer.close()`."""
    states = {"deviating": FaceState.DEVIATING, "contested": FaceState.CONTESTED}
    marked = [(face, states[status]) for face, status in status_by_face.items() if status in states]
    for face, state in marked:
        viewer.set_face_state(face, state)
    return len(marked)
