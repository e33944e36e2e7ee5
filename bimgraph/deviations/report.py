"""deviations.json and deviations.csv: the deviation report on disk (schema in docs/formats.md,
"Deviations"). The JSON is the reference and is validated on load; the CSV holds the same rows
for spreadsheets, one per face, one per unplanned plane, one per room width, one per wall
thickness and one per face of each explanation of a contest."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

from bimgraph.deviations.estimate import DeviationReport, FaceReport
from bimgraph.errors import FormatError
from bimgraph.files import existing_file, read_json, write_atomic, write_json
from bimgraph.validation import parse_model

FORMAT = "bimgraph.deviations"
VERSION = 4  # 2: `contested`, `widths`; 3: `thicknesses`; 4: faces' `centre`, `area_m2` (earlier files load as ever)
JSON_FILE = "deviations.json"
CSV_FILE = "deviations.csv"

Vec3 = tuple[float, float, float]
FaceStatus = Literal["within_tolerance", "deviating", "not_enough_evidence", "possibly_not_built"]
FACE_STATUSES: tuple[str, ...] = get_args(FaceStatus)
WidthStatus = Literal["within_tolerance", "deviating", "not_enough_evidence"]  # (also a thickness's)
WIDTH_STATUSES: tuple[str, ...] = get_args(WidthStatus)


class FaceRecord(BaseModel):
    """One BIM face: measured (offset and tilt with one-sigma) or possibly not built."""

    model_config = ConfigDict(extra="forbid")
    face_id: str
    wall_guid: str
    wall_name: str = ""
    storey: str = ""
    status: FaceStatus
    offset_m: float | None = None
    offset_sigma_m: float | None = Field(default=None, ge=0)
    tilt_deg: float | None = Field(default=None, ge=0)
    tilt_sigma_deg: float | None = Field(default=None, ge=0)
    n_keyframes: int = Field(default=0, ge=0)
    expected_keyframes: int = Field(default=0, ge=0)
    landmark: int | None = None
    matched_by: Literal["graph", "proximity", ""] = ""
    centre: Vec3 | None = None  # (the plane map's face centre in B, where `offset_m` is measured)
    area_m2: float | None = Field(default=None, ge=0)

    @model_validator(mode="after")
    def _measured_faces_have_their_figures(self):
        figures = ("offset_m", "offset_sigma_m", "tilt_deg", "tilt_sigma_deg")
        if self.status != "possibly_not_built" and (missing := [f for f in figures if getattr(self, f) is None]):
            raise ValueError(f"a face {self.status.replace('_', ' ')} has its {', '.join(missing)}")
        return self


class UnplannedRecord(BaseModel):
    """A large observed plane that matches no face: `normal . x + offset = 0` in B."""

    model_config = ConfigDict(extra="forbid")
    landmark: int
    normal: Vec3
    offset: float
    centre: Vec3 | None = None
    area_m2: float = Field(ge=0)
    n_keyframes: int = Field(ge=0)


class ExplanationRecord(BaseModel):
    """One of two alignments the data barely choose between: its probability and the faces
    built off plan under it (status `deviating`, measured under it alone)."""

    model_config = ConfigDict(extra="forbid")
    probability: float = Field(ge=0, le=1)
    deviating: list[FaceRecord]

    @model_validator(mode="after")
    def _faces_deviate(self):
        if any(f.status != "deviating" for f in self.deviating):
            raise ValueError("the faces of an explanation are deviating ones")
        return self


class DistanceRecord(BaseModel):
    """The distance between two opposite faces (m): a room width's or a wall thickness's figures."""

    model_config = ConfigDict(extra="forbid")
    faces: tuple[str, str]
    planned_m: float = Field(ge=0)
    built_m: float
    sigma_m: float = Field(ge=0)
    n_keyframes: int = Field(ge=0)
    status: WidthStatus


class WidthRecord(DistanceRecord):
    """A room's clear width between two of its wall faces facing each other."""

    space_guid: str
    space_name: str = ""


class ThicknessRecord(DistanceRecord):
    """A wall's thickness between two faces on its two sides."""

    wall_guid: str
    wall_name: str = ""


class DeviationsFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    format: Literal["bimgraph.deviations"] = FORMAT
    version: Literal[1, 2, 3, 4] = VERSION
    tolerance_m: float = Field(gt=0)
    tilt_tolerance_deg: float = Field(gt=0)
    k_sigma: float = Field(ge=0)
    faces: list[FaceRecord]
    unplanned: list[UnplannedRecord]
    contested: list[ExplanationRecord] = Field(default_factory=list, max_length=2)
    widths: list[WidthRecord] = Field(default_factory=list)
    thicknesses: list[ThicknessRecord] = Field(default_factory=list)

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.faces:
            out[f.status] = out.get(f.status, 0) + 1
        out["unplanned"] = len(self.unplanned)
        return out


def _face_record(f: FaceReport) -> FaceRecord:
    dev = f.deviation
    return FaceRecord(
        face_id=f.face_id, wall_guid=f.wall_guid, wall_name=f.wall_name, storey=f.storey, status=f.status,
        offset_m=dev.offset_m if dev else None, offset_sigma_m=dev.offset_sigma_m if dev else None,
        tilt_deg=dev.tilt_deg if dev else None, tilt_sigma_deg=dev.tilt_sigma_deg if dev else None,
        n_keyframes=f.n_keyframes, expected_keyframes=f.expected_keyframes, landmark=f.landmark,
        matched_by=f.matched_by, centre=f.centre, area_m2=f.area_m2,
    )


def to_file(report: DeviationReport) -> DeviationsFile:
    faces = [_face_record(f) for f in report.faces]
    unplanned = [
        UnplannedRecord(landmark=u.landmark, normal=tuple(map(float, u.plane_B[:3])), offset=float(u.plane_B[3]),
                        centre=None if u.centre_B is None else tuple(map(float, u.centre_B)),
                        area_m2=u.area_m2, n_keyframes=u.n_keyframes)
        for u in report.unplanned
    ]
    contested = [ExplanationRecord(probability=e.probability, deviating=[_face_record(f) for f in e.deviating])
                 for e in report.contested]
    return DeviationsFile(tolerance_m=report.tolerance_m, tilt_tolerance_deg=report.tilt_tolerance_deg,
                          k_sigma=report.k_sigma, faces=faces, unplanned=unplanned, contested=contested,
                          widths=[WidthRecord(**vars(w)) for w in report.widths],
                          thicknesses=[ThicknessRecord(**vars(t)) for t in report.thicknesses])


CSV_COLUMNS = ["status", "face_id", "wall_guid", "wall_name", "storey", "offset_m", "offset_sigma_m", "tilt_deg",
               "tilt_sigma_deg", "n_keyframes", "expected_keyframes", "landmark", "matched_by",
               "area_m2", "centre_x", "centre_y", "centre_z", "probability", "room", "planned_m", "built_m"]


def to_csv(data: DeviationsFile) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for f in data.faces:
        writer.writerow(_face_row(f))
    for u in data.unplanned:
        writer.writerow({"status": "unplanned", "landmark": u.landmark, "n_keyframes": u.n_keyframes,
                         "area_m2": u.area_m2, **_centre_columns(u.centre)})
    for w in data.widths:
        writer.writerow({"status": f"width_{w.status}", "face_id": " ".join(w.faces), "room": w.space_name or w.space_guid,
                         "offset_m": w.built_m - w.planned_m, "offset_sigma_m": w.sigma_m, "n_keyframes": w.n_keyframes,
                         "planned_m": w.planned_m, "built_m": w.built_m})
    for t in data.thicknesses:
        writer.writerow({"status": f"thickness_{t.status}", "face_id": " ".join(t.faces), "wall_guid": t.wall_guid,
                         "wall_name": t.wall_name, "offset_m": t.built_m - t.planned_m, "offset_sigma_m": t.sigma_m,
                         "n_keyframes": t.n_keyframes, "planned_m": t.planned_m, "built_m": t.built_m})
    for explanation in data.contested:
        for f in explanation.deviating:
            writer.writerow({**_face_row(f), "status": "contested", "probability": explanation.probability})
    return out.getvalue()


def _face_row(f: FaceRecord) -> dict:
    return {**{k: ("" if v is None else v) for k, v in f.model_dump(exclude={"centre"}).items()}, **_centre_columns(f.centre)}


def _centre_columns(centre: Vec3 | None) -> dict:
    return dict(zip(("centre_x", "centre_y", "centre_z"), centre or ("", "", "")))


def write_deviations(report: DeviationReport, out_dir: Path) -> DeviationsFile:
    """Write deviations.json and deviations.csv into `out_dir` (atomically, each)."""
    data = to_file(report)
    write_json(Path(out_dir) / JSON_FILE, data.model_dump(mode="json"))
    write_atomic(Path(out_dir) / CSV_FILE, to_csv(data))
    return data


def load_deviations(path: Path) -> DeviationsFile:
    path = Path(path)
    data = read_json(path)
    if isinstance(data, dict) and data.get("format") not in (None, FORMAT):
        raise FormatError(f"{path}: format is {data.get('format')!r}, expected {FORMAT!r}")
    return parse_model(DeviationsFile, data, str(path))


def run_report(out_dir: Path, finished: bool) -> DeviationsFile | None:
    """A run's deviation report from its output folder, None if it wrote none or did not
    finish (`finished`, its summary's): a run writes its report before it says it finished, and
    one killed while it wrote the report left part of one."""
    path = Path(out_dir) / JSON_FILE
    return load_deviations(path) if finished and path.is_file() else None


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The CSV's rows as strings, for checks and spreadsheets' round trips."""
    path = existing_file(path)
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))
