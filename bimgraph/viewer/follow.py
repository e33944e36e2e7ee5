"""Following a backend run in the viewer: the backend's `Listener` hooks turned into
`RerunViewer` calls. The backend's results carry estimates only; the inputs (front-end pose,
detected planes, depth image) come from the keyframes the estimator is fed: either they pass
through `RerunListener.watch` on their way, or the listener reads them again from the
sequence folder."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np

from bimgraph.backend.records import KeyframeResult, Listener
from bimgraph.sequence.format import KEYFRAMES_FILE, Keyframe, PlaneObservation
from bimgraph.viewer.rerun_viewer import FaceState, RerunViewer


def read_keyframes_unchecked(root: Path) -> Iterator[Keyframe]:
    """The keyframes of a sequence without validation: for following a run whose pipeline
    reads (and validates) the same file. A quarter of the cost of `iter_keyframes`, which
    is mostly pydantic checking the polygons."""
    with (Path(root) / KEYFRAMES_FILE).open() as fh:
        for line in fh:
            if line.strip():
                data = json.loads(line)
                data["planes"] = [PlaneObservation.model_construct(**p) for p in data.get("planes", [])]
                yield Keyframe.model_construct(**data)


def read_depth(path: Path) -> np.ndarray | None:
    """A 16-bit depth PNG as stored (metres * depth_scale), or None if it cannot be read."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return image if image is not None and image.ndim == 2 else None


class RerunListener(Listener):
    """Logs every keyframe result of an online or offline run into `viewer`.

    Pass the keyframes through `watch` before the estimator sees them:
    `backend.process(kf) for kf in listener.watch(keyframes)`. Keyframes that did not pass
    through it are read from `sequence_root` (which costs a second parsing of each line);
    depth images are read from there too."""

    def __init__(self, viewer: RerunViewer, sequence_root: Path | None = None):
        self.viewer = viewer
        self.sequence_root = None if sequence_root is None else Path(sequence_root)
        self._inputs: dict[int, Keyframe] = {}
        self._reader: Iterator[Keyframe] | None = None
        self._matched: dict[int, str] = {}  # landmark -> face
        self._started = False

    def watch(self, keyframes: Iterable[Keyframe]) -> Iterator[Keyframe]:
        for kf in keyframes:
            self._inputs[kf.index] = kf
            yield kf

    def on_keyframe(self, result: KeyframeResult) -> None:
        self._started = True
        kf = self._input(result.index)
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

    def _input(self, index: int) -> Keyframe:
        kf = self._inputs.pop(index, None)
        if kf is not None:
            return kf
        if self.sequence_root is None:
            raise KeyError(f"keyframe {index} did not pass through RerunListener.watch and no sequence folder was given")
        if self._reader is None:
            self._reader = read_keyframes_unchecked(self.sequence_root)
        for kf in self._reader:  # keyframes arrive in order: read on from where we stopped
            if kf.index == index:
                return kf
        raise KeyError(f"keyframe {index} is not in {self.sequence_root}")

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
    """Colour the faces whose deviation status is "deviating" (deviations.json); returns
    how many. Call at the end of a run, before `viewer.close()`."""
    deviating = [face for face, status in status_by_face.items() if status == "deviating"]
    for face in deviating:
        viewer.set_face_state(face, FaceState.DEVIATING)
    return len(deviating)
