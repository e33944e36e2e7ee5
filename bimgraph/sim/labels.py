"""Ground truth for planes extracted from a simulated depth sequence: the as-built element
behind each detected plane, read from the label image the simulator rendered beside the
depth image. This is what makes association precision and recall measurable in depth mode."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimgraph.errors import InputError
from bimgraph.planes.extractor import Extraction
from bimgraph.sequence.format import Keyframe
from bimgraph.sequence.groundtruth import FOLDER, LABELS_FOLDER, GroundTruth, load_groundtruth, write_groundtruth

# A detection is of an element if at least this share of its pixels show that element.
_MIN_SHARE = 0.6


class DetectionLabeller:
    def __init__(self, root: Path, gt: GroundTruth):
        self.folder = Path(root) / FOLDER / LABELS_FOLDER
        self.elements = gt.as_built["elements"]
        self.gt = gt

    def label(self, position: int, kf: Keyframe, extraction: Extraction | None) -> None:
        """Set the ground truth of keyframe `position` to its extracted planes, in order."""
        import cv2

        records = []
        if extraction is not None and kf.depth is not None:
            path = self.folder / Path(kf.depth).name
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:  # (the run stops before anything is written: the ground truth would lack it)
                raise InputError(f"{path}: no such label image (ground truth of {kf.depth})")
            element_px = image.astype(np.int64) - 1
            plane_px = extraction.labels
            R_B_C = self.gt.T_B_C[position][:3, :3]
            for p, plane in enumerate(extraction.planes):
                ids, counts = np.unique(element_px[plane_px == p], return_counts=True)
                best = int(np.argmax(counts)) if len(counts) else -1
                element = int(ids[best]) if best >= 0 and counts[best] >= _MIN_SHARE * counts.sum() else -1
                # A single-sided element seen from behind (through an opening) is not its face.
                if element >= 0 and np.dot(self.elements[element]["plane"][:3], R_B_C @ plane.n) <= 0:
                    element = -1
                records.append(self._record(element))
        self.gt.observations[position] = records

    def _record(self, element: int) -> dict:
        if element < 0:
            return {"face_id": None, "element": None, "kind": "mixed"}
        e = self.elements[element]
        return {"face_id": e["face_id"], "element": e["name"], "kind": e["kind"]}

    def save(self, root: Path) -> None:
        write_groundtruth(root, self.gt)


def simulated_labeller(root: Path) -> DetectionLabeller | None:
    """A labeller for a simulated depth sequence (one with label images), else None."""
    if not (Path(root) / FOLDER / LABELS_FOLDER).is_dir():
        return None
    return DetectionLabeller(root, load_groundtruth(root))
