"""The `groundtruth/` folder of a simulated sequence (schema in docs/formats.md).

- `T_B_C.tum`: the true camera pose of each keyframe in B (TUM, same stamps as keyframes.jsonl).
- `T_B_S.json`: the true extrinsic, the simulated manual alignment and its error, the
  front-end's drift.
- `observations.jsonl`: per keyframe, per detected plane (aligned with its `planes` list), the
  BIM face behind it (null for clutter, floors, partitions) and the as-built element.
- `as_built.json`: per planned wall face its deviation (offset, tilt, built), and every
  as-built element with its plane and outline.
- `visible.jsonl`: per keyframe, the BIM faces in view within range and their pixel counts.
- `labels/` (depth sensor only): 16-bit PNG per keyframe, element index + 1 per pixel (0: none).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from bimgraph.errors import FormatError, InputError
from bimgraph.files import parse_json, read_json, read_text, write_atomic, write_json
from bimgraph.geometry import pose_from_tum, pose_to_tum
from bimgraph.sequence.tum import read_tum, write_tum
from bimgraph.validation import Pose7, parse_model

FOLDER = "groundtruth"
TRAJECTORY_FILE = "T_B_C.tum"
EXTRINSIC_FILE = "T_B_S.json"
OBSERVATIONS_FILE = "observations.jsonl"
AS_BUILT_FILE = "as_built.json"
VISIBLE_FILE = "visible.jsonl"
_FILES = (TRAJECTORY_FILE, EXTRINSIC_FILE, OBSERVATIONS_FILE, AS_BUILT_FILE, VISIBLE_FILE)
LABELS_FOLDER = "labels"


class _Extrinsic(BaseModel):
    """What is read of T_B_S.json; the rest (the initial alignment, the drift) is kept as read."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)
    T_B_S: Pose7


class _PlaneTruth(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)
    face_id: str | None = None


class _Observations(BaseModel):
    """A line of observations.jsonl: the truth of each plane of keyframe `index`, in order."""

    model_config = ConfigDict(extra="forbid")
    index: int = Field(ge=0)
    planes: list[_PlaneTruth]


class _Visible(BaseModel):
    model_config = ConfigDict(extra="forbid")
    index: int = Field(ge=0)
    faces: dict[str, int]


@dataclass
class GroundTruth:
    stamps: np.ndarray  # N
    T_B_C: np.ndarray  # N x 4 x 4
    T_B_S: np.ndarray  # 4 x 4
    extrinsic: dict  # T_B_S.json as read
    observations: list[list[dict]]  # per keyframe, per plane: face_id, element, ...
    as_built: dict
    visible: list[dict]  # per keyframe: {"index", "faces": {face_id: pixels}}

    def face_of(self, keyframe: int, plane: int) -> str | None:
        return self.observations[keyframe][plane]["face_id"]

    def first(self, n: int) -> GroundTruth:
        """The ground truth of the first `n` keyframes (what a run stopped there is measured on)."""
        return replace(self, stamps=self.stamps[:n], T_B_C=self.T_B_C[:n], observations=self.observations[:n],
                       visible=self.visible[:n])


def as_planned(face: dict) -> bool:
    """Whether an `as_built.json` face record was built, and built exactly as planned."""
    return face["built"] and np.allclose(face["plane_planned"], face["plane_as_built"], rtol=0.0, atol=1e-9)


def rounded(x, digits: int = 9):
    """Floats rounded for writing: files stay short, their bytes do not hang on the last ulp,
    and -0.0 becomes 0.0. A scalar stays a scalar, anything else becomes a flat list."""
    if np.ndim(x) == 0:
        return round(float(x), digits) + 0.0
    return [round(float(v), digits) + 0.0 for v in np.asarray(x).ravel()]


def pose7(T: np.ndarray) -> list[float]:
    return rounded(pose_to_tum(T))


def _jsonl(records) -> str:
    return "".join(json.dumps(r) + "\n" for r in records)


def write_groundtruth(root: Path, gt: GroundTruth) -> None:
    folder = Path(root) / FOLDER
    write_tum(folder / TRAJECTORY_FILE, gt.stamps, gt.T_B_C)
    write_json(folder / EXTRINSIC_FILE, {"T_B_S": pose7(gt.T_B_S), **gt.extrinsic})
    write_atomic(folder / OBSERVATIONS_FILE, _jsonl({"index": k, "planes": planes} for k, planes in enumerate(gt.observations)))
    write_json(folder / AS_BUILT_FILE, gt.as_built)
    write_atomic(folder / VISIBLE_FILE, _jsonl(gt.visible))


def _read_jsonl(path: Path, model: type[BaseModel]) -> list[dict]:
    """The records of a JSON Lines file as read, each validated as `model`."""
    records = []
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        record = parse_json(line, f"{path}: line {lineno}")
        parse_model(model, record, f"{path}: line {lineno}")
        records.append(record)
    return records


def load_groundtruth(root: Path) -> GroundTruth:
    """Read `root/groundtruth/`; a FormatError names the file and what is inconsistent."""
    folder = _folder(root, "not a simulated sequence")
    if missing := [name for name in _FILES if not (folder / name).is_file()]:
        raise InputError(f"{folder}: no {', '.join(missing)} (the simulator writes all of {', '.join(_FILES)})")
    stamps, T_B_C = read_tum(folder / TRAJECTORY_FILE)
    T_B_S, extrinsic = _read_extrinsic(folder)
    observations = _read_observations(folder)
    visible = _read_jsonl(folder / VISIBLE_FILE, _Visible)
    for name, records in [(OBSERVATIONS_FILE, observations), (VISIBLE_FILE, visible)]:
        if len(records) != len(stamps):
            raise FormatError(f"{folder / name}: {len(records)} keyframes, {TRAJECTORY_FILE} has {len(stamps)}")
    return GroundTruth(stamps, T_B_C, T_B_S, extrinsic, observations, read_json(folder / AS_BUILT_FILE), visible)


@dataclass
class Reference:
    """What `bimgraph eval` measures against: true camera poses in B at stamps of their own
    (a simulator's at every keyframe; a total station's or a motion-capture system's at its
    own rate), and where known the true extrinsic and, per keyframe, the BIM face behind each
    detected plane."""

    stamps: np.ndarray  # N
    T_B_C: np.ndarray  # N x 4 x 4
    T_B_S: np.ndarray | None  # 4 x 4
    observations: list[list[dict]] | None  # per keyframe of the sequence, per plane: face_id, ...


def load_reference(root: Path) -> Reference:
    """Read what `root/groundtruth/` holds of a reference: `T_B_C.tum` (required), and
    `T_B_S.json` and `observations.jsonl` where present."""
    folder = _folder(root, f"put the reference trajectory in B at {FOLDER}/{TRAJECTORY_FILE}")
    if not (folder / TRAJECTORY_FILE).is_file():
        raise InputError(f"{folder}: no {TRAJECTORY_FILE} (the reference trajectory in B, TUM: docs/formats.md, Ground truth)")
    stamps, T_B_C = read_tum(folder / TRAJECTORY_FILE)
    unique, counts = np.unique(stamps, return_counts=True)
    if (counts > 1).any():  # (which of two poses is the truth? one shifted 0.5 m went into the ATE)
        raise FormatError(f"{folder / TRAJECTORY_FILE}: stamp {unique[counts > 1][0]:.6f} is given {counts[counts > 1][0]} times")
    return Reference(stamps, T_B_C, _read_extrinsic(folder)[0] if (folder / EXTRINSIC_FILE).is_file() else None,
                     _read_observations(folder) if (folder / OBSERVATIONS_FILE).is_file() else None)


def _folder(root: Path, missing: str) -> Path:
    """`root/groundtruth/`; an InputError, ending in `missing`, where there is none."""
    folder = Path(root) / FOLDER
    if not folder.is_dir():
        raise InputError(f"{root}: no {FOLDER}/ folder ({missing})")
    return folder


def _read_extrinsic(folder: Path) -> tuple[np.ndarray, dict]:
    """The true `T_B_S` of `T_B_S.json`, and the rest of the file as read."""
    extrinsic = read_json(folder / EXTRINSIC_FILE)
    T_B_S = pose_from_tum(parse_model(_Extrinsic, extrinsic, str(folder / EXTRINSIC_FILE)).T_B_S)
    del extrinsic["T_B_S"]
    return T_B_S, extrinsic


def _read_observations(folder: Path) -> list[list[dict]]:
    return [r["planes"] for r in _read_jsonl(folder / OBSERVATIONS_FILE, _Observations)]
