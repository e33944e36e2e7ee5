"""The bimgraph sequence format: a folder with `sequence.json` and `keyframes.jsonl`.

One keyframe a line: its stamp, the front-end's pose `T_S_C` and the planes detected in the
camera frame. Simulated sequences also carry `groundtruth/`. The schema is documented in
docs/formats.md; every record is validated on load and an error names the line and field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bimgraph.errors import FormatError, InputError
from bimgraph.files import existing_file, parse_json, read_json, write_atomic, write_json
from bimgraph.geometry import pose_from_tum
from bimgraph.sequence.tum import not_seconds
from bimgraph.validation import Pose7, parse_model, require_unit

FORMAT = "bimgraph.sequence"
VERSION = 1
META_FILE = "sequence.json"
KEYFRAMES_FILE = "keyframes.jsonl"

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


_MIN_SIGMA = 1e-9


def _check_square_psd(value, size: int):
    if value is None:
        return value
    m = np.asarray(value, dtype=float)
    if m.shape != (size, size):
        raise ValueError(f"must be {size}x{size}")
    if not np.allclose(m, m.T, atol=1e-9 * max(1.0, np.abs(m).max())):
        raise ValueError("covariance is not symmetric")
    smallest = np.linalg.eigvalsh(m).min()
    if smallest <= 0:
        raise ValueError("covariance is not positive definite")
    # (a keyframe's pose given to 1e-15 m made the graph singular, found elsewhere, far from it)
    if smallest < _MIN_SIGMA**2:
        raise ValueError(f"covariance has a sigma of {np.sqrt(smallest):.1g}, below {_MIN_SIGMA:g} (m or rad): "
                         "no sensor measures so finely, and the graph would be singular")
    return value


_MAX_FOV_DEG = 170.0


class Camera(BaseModel):
    """Pinhole intrinsics of the depth (and colour) images; depth PNG value = metres * depth_scale."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    depth_scale: float = Field(default=5000.0, gt=0)

    @model_validator(mode="after")
    def _principal_point_in_the_image(self):
        if not (0 <= self.cx <= self.width and 0 <= self.cy <= self.height):
            raise ValueError(f"the principal point ({self.cx}, {self.cy}) lies outside the {self.width}x{self.height} image")
        # (a pinhole sees less than 180 degrees; fx = 1e-9 px gave planes of 1e22 m2)
        fov = np.degrees(2 * np.arctan(max(self.width / self.fx, self.height / self.fy) / 2))
        if fov > _MAX_FOV_DEG:
            raise ValueError(f"fx {self.fx:g} and fy {self.fy:g} px give the {self.width}x{self.height} image a field of view "
                             f"of {fov:.1f} degrees (at most {_MAX_FOV_DEG:g}): focal lengths are in pixels")
        return self

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


class InitialAlignment(BaseModel):
    """The user's initial (manual) alignment `T_B_S` and its one-sigma uncertainty."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    T_B_S: Pose7
    sigma_rot_deg: float = Field(default=2.0, gt=0, le=180)
    sigma_trans_m: float = Field(default=0.2, gt=0, le=1000)


# A detection's polygon is its boundary on its plane; a front-end's noisy boundary points may
# stray from the fitted plane by centimetres, not this much.
_POLYGON_OFF_PLANE_M = 0.25


class PlaneObservation(BaseModel):
    """A plane detected in the camera frame C, `n . x + d = 0`, normal toward the camera (d > 0).

    `cov` is 3x3 in the tangent space of gtsam's OrientedPlane3 (two normal directions of
    its Unit3 basis, then d). `polygon` is the extent in C.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    n: Vec3
    d: float
    cov: Mat3 | None = None
    polygon: list[Vec3] | None = None
    area: float | None = Field(default=None, ge=0)
    centre: Vec3 | None = None
    inliers: int | None = Field(default=None, ge=0)
    track_id: int | None = None

    @field_validator("n")
    @classmethod
    def _unit(cls, n):
        return require_unit(n, "normal")

    @field_validator("d")
    @classmethod
    def _facing(cls, d):
        if not d > 0:
            raise ValueError(f"{d:g}: d is the camera's distance to the plane, > 0, with n toward the camera (with d < 0, "
                             "flip n and d; planes are given in the camera frame C, not in S)")
        return d

    @field_validator("cov")
    @classmethod
    def _cov(cls, cov):
        return _check_square_psd(cov, 3)

    @field_validator("polygon")
    @classmethod
    def _polygon(cls, polygon):
        if polygon and len(polygon) < 3:
            raise ValueError(f"a polygon has at least 3 points, not {len(polygon)} (or none: [] or null)")
        return polygon

    @model_validator(mode="after")
    def _polygon_on_plane(self):
        # (its points grow the landmark's extent, which gates association: one far off would
        # let planes of other rooms join it)
        if self.polygon:
            off = float(np.abs(np.asarray(self.polygon) @ self.plane[:3] + self.d).max())
            if off > _POLYGON_OFF_PLANE_M:
                raise ValueError(f"polygon: a point lies {off:.2f} m off the plane (at most {_POLYGON_OFF_PLANE_M})")
        return self

    @property
    def plane(self) -> np.ndarray:
        """(n, d) with n scaled to unit length (the file's is unit to its printed digits)."""
        norm = math.sqrt(sum(x * x for x in self.n))  # (math on three floats: numpy's calls cost more)
        return np.array([self.n[0] / norm, self.n[1] / norm, self.n[2] / norm, self.d])


class Keyframe(BaseModel):
    """One line of keyframes.jsonl. `T_S_C` is `tx ty tz qx qy qz qw` (TUM order); `cov` is
    the 6x6 covariance of the front-end's step from the previous keyframe to this one, in
    gtsam's Pose3 tangent order (rotation, then translation); `depth`/`rgb` are image paths
    relative to the sequence folder."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    index: int = Field(ge=0)
    stamp: float
    T_S_C: Pose7
    cov: tuple[tuple[float, ...], ...] | None = None
    planes: list[PlaneObservation] = []
    depth: str | None = None
    rgb: str | None = None

    @field_validator("cov")
    @classmethod
    def _cov(cls, cov):
        return _check_square_psd(cov, 6)

    @field_validator("stamp")
    @classmethod
    def _seconds(cls, stamp):
        if (why := not_seconds(stamp)) is not None:
            raise ValueError(why)
        return stamp

    @property
    def pose(self) -> np.ndarray:
        """T_S_C as a 4x4 matrix."""
        return pose_from_tum(self.T_S_C)


class SequenceMeta(BaseModel):
    """sequence.json. `model` is the as-planned IFC or plane map, relative to the folder or
    absolute; `initial_alignment` is the user's manual T_B_S."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    format: Literal["bimgraph.sequence"] = FORMAT
    version: Literal[1] = VERSION
    name: str = ""
    model: str | None = None
    camera: Camera | None = None
    sensor: Literal["planes", "depth", "external"] = "external"
    gravity_aligned: bool = Field(False, strict=True)  # ("yes" or 1 is a mistake, not true)
    initial_alignment: InitialAlignment | None = None
    simulated: dict | None = None


class Sequence(BaseModel):
    """A loaded sequence: its folder, metadata and keyframes in order."""

    model_config = ConfigDict(arbitrary_types_allowed=True)
    root: Path
    meta: SequenceMeta
    keyframes: list[Keyframe]

    def model_path(self) -> Path | None:
        if self.meta.model is None:
            return None
        p = Path(self.meta.model)
        return p if p.is_absolute() else self.root / p


def load_meta(root: Path, ignore: tuple[str, ...] = ()) -> SequenceMeta:
    """sequence.json, its fields `ignore` left unread (unvalidated, at their defaults)."""
    path = Path(root) / META_FILE
    data = read_json(path)
    if isinstance(data, dict):
        data = {k: v for k, v in data.items() if k not in ignore}
    return parse_model(SequenceMeta, data, str(path))


def out_of_order(previous: Keyframe, kf: Keyframe) -> str | None:
    """The field ("index", "stamp") in which `kf` does not follow `previous`, or None: both
    increase (the outputs are trajectories in time)."""
    if kf.index <= previous.index:
        return "index"
    return "stamp" if kf.stamp <= previous.stamp else None


def iter_keyframes(root: Path):
    """Yield keyframes one by one, validating each line as it comes."""
    path = existing_file(Path(root) / KEYFRAMES_FILE)
    previous = None
    with path.open(encoding="utf-8-sig") as fh:  # (a byte-order mark, as Windows editors write, is no error)
        for lineno, line in _lines(fh, path):
            if not line.strip():
                continue
            where = f"{path}: line {lineno}"
            kf = parse_model(Keyframe, parse_json(line, where), where)
            if previous is not None and (field := out_of_order(previous, kf)):
                raise FormatError(f"{where}: {field}: {getattr(kf, field)} does not follow {getattr(previous, field)}")
            previous = kf
            yield kf


def _lines(fh, path: Path):
    """(number, text) of each line; a file that is not text is a FormatError."""
    lineno = 0
    try:
        for lineno, line in enumerate(fh, start=1):
            yield lineno, line
    except UnicodeDecodeError:
        raise FormatError(f"{path}: line {lineno + 1}: not text (UTF-8)") from None


def load_sequence(root: Path) -> Sequence:
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: not a sequence folder")
    meta = load_meta(root)
    keyframes = list(iter_keyframes(root))
    if not keyframes:
        raise FormatError(f"{root / KEYFRAMES_FILE}: no keyframes")
    return Sequence(root=root, meta=meta, keyframes=keyframes)


def keyframe_line(kf: Keyframe) -> str:
    return json.dumps(kf.model_dump(mode="json", exclude_none=True)) + "\n"


def save_sequence(seq: Sequence) -> None:
    seq.root.mkdir(parents=True, exist_ok=True)
    write_json(seq.root / META_FILE, seq.meta.model_dump(mode="json", exclude_none=True))
    write_atomic(seq.root / KEYFRAMES_FILE, "".join(keyframe_line(kf) for kf in seq.keyframes))
