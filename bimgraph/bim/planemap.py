"""The BIM plane map: one record per wall-face section, in frame B (metres, z up).

It is what `bimgraph bim` writes from an IFC model and what a user with only a floor plan
writes by hand; both load through `load_plane_map`. The schema is documented in
docs/formats.md; `PlaneMap.model_json_schema()` gives it as JSON Schema.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bimgraph.errors import FormatError
from bimgraph.files import read_json, write_atomic
from bimgraph.geometry import plane_frame, plane_shape
from bimgraph.validation import Pose7, parse_model, require_unit

FORMAT = "bimgraph.planemap"
VERSION = 1

Vec3 = tuple[float, float, float]

# A hand-written map is accepted if its points lie this close to the face's plane.
_ON_PLANE_TOL_M = 0.01
# A face of less area is one whose corners lie in a line (rounding leaves them a trace of it).
_MIN_AREA_M2 = 1e-6
# A slab face's normal is at most about 25 degrees off the vertical.
_SLAB_MIN_UP = 0.9
# A wall's face leaning further than this out of vertical is where a roof cuts it, not a side
# (the IFC import leaves it out); a steeper "wall" in a hand-written map is a floor or a
# ceiling, and would be matched as one.
WALL_MAX_LEAN_RAD = np.radians(30.0)
# faces farther than this from B's origin (the variable `E` is T_S_B, turned about B's origin:
# 3 km out a hand-written map made every run singular; a map in millimetres reads as this)
_FAR_M = 1000.0


class Space(BaseModel):
    """The IfcSpace (room) a face section bounds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    guid: str
    name: str = ""


class BimFace(BaseModel):
    """One planar face section of a wall (or a slab), as planned.

    `normal` points out of the material into the free space (into the room for a wall face).
    `offset` is d in `normal . x + offset = 0`. `polygon` is the outer boundary in B, its
    vertices being the face's corners; `holes` are the openings cut out of it. `area` and
    `centre` are of the polygon minus its holes and are computed when omitted.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    id: str = Field(min_length=1)
    wall_guid: str
    wall_name: str = ""
    kind: Literal["wall", "slab_top", "slab_bottom"] = "wall"
    storey: str = ""
    elevation: float = 0.0
    normal: Vec3
    offset: float
    polygon: list[Vec3] = Field(min_length=3)
    holes: list[Annotated[list[Vec3], Field(min_length=3)]] = []
    area: float | None = Field(default=None, gt=0)
    centre: Vec3 | None = None
    space: Space | None = None
    split: Literal["space_boundary", "space_boundary_projected", "space_footprint", "junction", "none"] = "none"

    @field_validator("normal")
    @classmethod
    def _unit(cls, normal):
        return require_unit(normal, "normal")

    @field_validator("polygon")
    @classmethod
    def _open_polygon(cls, ring):
        return open_ring(ring)

    @field_validator("holes")
    @classmethod
    def _open_holes(cls, holes):
        return [open_ring(hole) for hole in holes]

    @model_validator(mode="after")
    def _check_geometry(self):
        n = np.asarray(self.normal)
        for name, ring in [("polygon", self.polygon)] + [(f"holes[{i}]", h) for i, h in enumerate(self.holes)]:
            dist = np.abs(np.asarray(ring) @ n + self.offset).max()
            if dist > _ON_PLANE_TOL_M:
                raise ValueError(f"{name} lies up to {dist:.3f} m off the plane normal.x + offset = 0")
        # (given an area, its corners must still span one: in a line they would break every use
        # of it; the outline's vector area says so without building the shape, which was a
        # quarter of an import and most of loading a map that gives area and centre)
        if self.area is None or self.centre is None:
            area, centre = polygon_area_centre(self.polygon, self.holes, n)
        else:
            area, centre = outline_area(self.polygon, n), None
        if area <= _MIN_AREA_M2:
            corners = np.asarray(self.polygon, dtype=float)
            spread = np.linalg.svd(corners - corners.mean(axis=0), compute_uv=False)
            # (corners spanning a plane whose outline's areas cancel: a bow tie)
            why = "its outline crosses itself (a bow tie)" if spread[1] > _ON_PLANE_TOL_M else "its corners lie on a line"
            raise ValueError(f"polygon has zero area: {why}")
        if self.kind != "wall" and abs(n[2]) < _SLAB_MIN_UP:
            raise ValueError(f"a {self.kind} face must be horizontal, its normal is {self.normal}")
        if self.kind == "wall" and abs(n[2]) > np.sin(WALL_MAX_LEAN_RAD):
            raise ValueError(f"a wall face must be within {np.degrees(WALL_MAX_LEAN_RAD):.0f} degrees of vertical, its normal is {self.normal} "
                             f"(a floor or ceiling is a slab_top or slab_bottom)")
        if self.centre is not None:
            given = np.asarray(self.centre)
            corners = np.asarray(self.polygon)
            if abs(given @ n + self.offset) > _ON_PLANE_TOL_M or (given < corners.min(axis=0) - _ON_PLANE_TOL_M).any() \
                    or (given > corners.max(axis=0) + _ON_PLANE_TOL_M).any():
                raise ValueError(f"centre {self.centre} is not on the face (its plane, within its polygon's bounds)")
        self.area = self.area if self.area is not None else area
        self.centre = self.centre if self.centre is not None else tuple(centre)
        return self

    @property
    def plane(self) -> np.ndarray:
        """(nx, ny, nz, d) as a numpy array."""
        return np.array([*self.normal, self.offset])

    def moved_to(self, plane: Sequence[float], polygon: list | None = None, holes: list | None = None) -> BimFace:
        """The face on another plane `(n, d)` (a wall built off plan), with area and centre
        recomputed: its outline `polygon` and `holes` where given (as built), else its own
        projected onto the plane."""
        scale = float(np.linalg.norm(plane[:3]))
        n, d = np.asarray(plane[:3], dtype=float) / scale, float(plane[3]) / scale

        def project(ring):
            points = np.asarray(ring, dtype=float)
            return [tuple(p) for p in points - np.outer(points @ n + d, n)]

        return BimFace(**{**self.model_dump(), "normal": tuple(n), "offset": d,
                          "polygon": project(self.polygon if polygon is None else polygon),
                          "holes": [project(h) for h in (self.holes if holes is None else holes)],
                          "area": None, "centre": None})


class PlaneMap(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    format: Literal["bimgraph.planemap"] = FORMAT
    version: Literal[1] = VERSION
    source: str = ""
    # The IfcProject's GlobalId, which BCF files name beside `source` so that BIM tools open
    # their topics on the right model; empty where unknown (a hand-written map).
    ifc_project: str = ""
    # Free text for people: what frame B is (the importer says; a hand-written map may too).
    origin: str = "as the author of the map chose: metres, z up"
    # Where B sits in the IFC file's world frame, so that results can go back into the model
    # (BCF viewpoints): [tx, ty, tz, qx, qy, qz, qw], metres; None when B is that frame.
    T_W_B: Pose7 | None = None
    faces: list[BimFace]

    @model_validator(mode="after")
    def _unique_ids(self):
        seen = set()
        for i, face in enumerate(self.faces):
            if face.id in seen:
                raise ValueError(f"faces[{i}].id {face.id!r} is not unique")
            seen.add(face.id)
        return self

    @model_validator(mode="after")
    def _shapes(self):
        for i, problem in shape_problems(self.faces):
            raise ValueError(f"faces[{i}] ({self.faces[i].id!r}): {problem}")
        return self

    @cached_property
    def planes(self) -> np.ndarray:
        """F x 4 array of every face's (n, d), in the order of `faces`."""
        return np.array([f.plane for f in self.faces]).reshape(-1, 4)

    @cached_property
    def centres(self) -> np.ndarray:
        return np.array([f.centre for f in self.faces]).reshape(-1, 3)

    @cached_property
    def index(self) -> dict[str, int]:
        return {f.id: i for i, f in enumerate(self.faces)}

    def far_warning(self) -> str | None:
        """Why faces far from B's origin will go wrong, or None."""
        far = float(np.linalg.norm(self.centres, axis=1).max(initial=0.0))
        if far <= _FAR_M:
            return None
        return (f"the plane map's faces lie up to {far / 1000:.3g} km from B's origin: the graph's extrinsic turns "
                "about it, so it loses precision, and beyond a few km the graph is singular; give the faces in metres "
                "and in a frame near the building (subtract a point of it from every face's polygon, centre and "
                "offset, and from T_B_S's translation)")

    def walls(self) -> list[BimFace]:
        return [f for f in self.faces if f.kind == "wall"]


def open_ring(ring: list) -> list:
    """`ring` without a repeated closing point: a closed polyline copied from a drawing
    repeats its first point last, which would count that corner twice."""
    if len(ring) > 3 and tuple(ring[-1]) == tuple(ring[0]):
        return ring[:-1]
    return ring


def polygon_area_centre(polygon, holes, normal) -> tuple[float, np.ndarray]:
    """Area and centroid of a planar polygon with holes in 3-D."""
    normal = np.asarray(normal, dtype=float)
    plane = np.array([*normal, -normal @ np.asarray(polygon[0], dtype=float)])
    shape = plane_shape(plane, polygon, holes)
    if shape.area <= 0:
        return 0.0, np.asarray(polygon[0], dtype=float)
    origin, basis = plane_frame(plane)
    return float(shape.area), origin + basis @ np.array(shape.centroid.coords[0])


def shape_problems(faces: list[BimFace]):
    """(index, what) for each face whose polygon and holes do not make the shape they say:
    an outline that crosses itself (a bow tie), a hole outside it or across its edge (a hole
    touching it, a door at floor level, is fine), or a given `area` that is not theirs.
    All faces at once (shapely's array functions): a map of thousands loads in a blink."""
    import shapely

    if not faces:
        return
    normals = np.array([f.normal for f in faces])
    drop = np.argmax(np.abs(normals), axis=1)  # each face seen along its normal's main axis
    rings = [ring for f in faces for ring in (f.polygon, *f.holes)]
    owner = np.repeat(np.arange(len(faces)), [1 + len(f.holes) for f in faces])
    sizes = [len(ring) for ring in rings]
    points = np.array([p for ring in rings for p in ring])
    keep = np.array([[1, 2], [0, 2], [0, 1]])[np.repeat(drop[owner], sizes)]
    flat = np.take_along_axis(points, keep, axis=1)
    rings_2d = shapely.linearrings(flat, indices=np.repeat(np.arange(len(rings)), sizes))
    shapes = shapely.polygons(rings_2d, indices=owner)
    scale = np.abs(normals[np.arange(len(faces)), drop])
    area = shapely.area(shapely.buffer(shapes, 0)) / scale  # (the shape plane_shape makes)
    ring_areas = shapely.area(shapely.polygons(rings_2d))
    first = np.concatenate([[True], owner[1:] != owner[:-1]])
    enclosed = np.bincount(owner, np.where(first, ring_areas, -ring_areas)) / scale
    for i in np.flatnonzero(np.abs(area - enclosed) > 1e-6 + 1e-6 * enclosed):
        yield int(i), (f"its polygon and holes are not one shape ({shapely.is_valid_reason(shapes[i])}): "
                       f"an outline crossing itself, or a hole outside it or across its edge")
    given = np.array([f.area for f in faces])
    for i in np.flatnonzero(np.abs(given - area) > 1e-4 + 1e-3 * area):
        yield int(i), f"area {given[i]:.4g} m2 is not its polygon's less its holes, {area[i]:.4g} m2 (leave it out to have it computed)"


def outline_area(polygon, normal) -> float:
    """The area a planar 3-D ring encloses (its vector area along `normal`, the shoelace
    formula in 3-D; 0 for corners in a line), without its holes."""
    ring = np.asarray(polygon, dtype=float)
    return abs(float(np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0) @ np.asarray(normal, dtype=float))) / 2


def load_plane_map(path: Path) -> PlaneMap:
    """Read and validate a plane map; a FormatError names the bad field."""
    data = read_json(path)
    if isinstance(data, dict) and data.get("format") not in (None, FORMAT):
        raise FormatError(f"{path}: format is {data.get('format')!r}, expected {FORMAT!r}")
    return parse_model(PlaneMap, data, str(path))


def save_plane_map(plane_map: PlaneMap, path: Path) -> None:
    """Write atomically, so that a failure never leaves a half-written map behind."""
    write_atomic(path, json.dumps(plane_map.model_dump(mode="json"), indent=1))
