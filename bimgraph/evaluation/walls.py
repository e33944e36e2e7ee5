"""A deviation report scored against the walls' true as-built state: the simulator's, or walls
measured on site (a tape from a grid line, a total station, an as-built scan), given as a CSV.
Pure scoring, and the CSV's reader."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from bimgraph.deviations.report import FaceRecord
from bimgraph.errors import FormatError
from bimgraph.files import existing_file
from bimgraph.validation import parse_model

MEASURED = ("deviating", "within_tolerance")


class WallTruth(NamedTuple):
    """A face as built: its offset from plan along the planned normal at the face's centre (m,
    positive into the room, as the deviation report's), its tilt (deg) and whether it was built."""

    offset_m: float
    tilt_deg: float = 0.0
    built: bool = True


def face_scores(faces: list[FaceRecord], truth: Mapping[str, WallTruth], tolerance_m: float, tilt_tolerance_deg: float) -> dict:
    """Over the report's faces that `truth` has: detection precision and recall of `deviating`
    among the faces with enough evidence (truly deviating: built beyond either tolerance), the
    offsets' errors on built ones (share within 1 cm, 95th percentile), and precision and
    recall of `possibly_not_built`."""
    known = [f for f in faces if f.face_id in truth]

    def truly_deviating(face_id: str) -> bool:
        t = truth[face_id]
        return t.built and (abs(t.offset_m) > tolerance_m or abs(t.tilt_deg) > tilt_tolerance_deg)

    enough = [f for f in known if f.status in MEASURED]
    flagged = [f for f in enough if f.status == "deviating"]
    tp = sum(truly_deviating(f.face_id) for f in flagged)
    positives = sum(truly_deviating(f.face_id) for f in enough)
    errors = np.array([abs(f.offset_m - truth[f.face_id].offset_m) for f in enough if truth[f.face_id].built])
    not_built = [f for f in known if f.status == "possibly_not_built"]
    missing = [k for k, t in truth.items() if not t.built]
    return {
        "enough": len(enough), "flagged": len(flagged), "true_deviating_enough": positives,
        "precision": tp / len(flagged) if flagged else 1.0, "recall": tp / positives if positives else 1.0,
        "offset_within_1cm": float(np.mean(errors <= 0.01)) if len(errors) else float("nan"),
        "offset_err_p95_mm": float(np.percentile(errors, 95) * 1e3) if len(errors) else float("nan"),
        "not_built_flagged": len(not_built), "not_built_true": len(missing),
        "not_built_precision": sum(not truth[f.face_id].built for f in not_built) / len(not_built) if not_built else 1.0,
        "not_built_recall": sum(not truth[f.face_id].built for f in not_built) / len(missing) if missing else 1.0,
    }


class _Row(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    face_id: str = Field(min_length=1)
    offset_m: float = Field(default=0.0, ge=-1.0, le=1.0)  # (centimetres or millimetres would pass as metres)
    tilt_deg: float = Field(default=0.0, ge=0.0, le=10.0)
    built: bool = True


def load_measured_walls(path: Path, face_ids) -> dict[str, WallTruth]:
    """The walls measured on site, a CSV with a header: `face_id` (the deviation report's),
    `offset_m` and, optionally, `tilt_deg` and `built` (`false` for a wall not there, whose
    offset is then left empty). A FormatError names the line and the field; a face id not in
    `face_ids` (the plane map's) or given twice is one too."""
    path = existing_file(path)
    walls: dict[str, WallTruth] = {}
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or "face_id" not in reader.fieldnames:
            raise FormatError(f"{path}: no header line naming face_id (and offset_m, tilt_deg, built)")
        for lineno, row in enumerate(reader, start=2):
            where = f"{path}: line {lineno}"
            record = parse_model(_Row, {k: v for k, v in row.items() if k is not None and v not in ("", None)}, where)
            if record.face_id not in face_ids:
                raise FormatError(f"{where}: face_id {record.face_id!r} is not a face of the plane map")
            if record.face_id in walls:
                raise FormatError(f"{where}: face_id {record.face_id!r} is given twice")
            walls[record.face_id] = WallTruth(record.offset_m, record.tilt_deg, record.built)
    if not walls:
        raise FormatError(f"{path}: no wall measured")
    return walls
