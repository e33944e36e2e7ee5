"""The as-built world: the planned wall faces as they were really built, plus what the model
does not know (floors and ceilings where it has no slabs, clutter, temporary partitions).

Every surface is a planar `Element` in frame B with its BIM face id, or None where no face of
the model is behind it. `deviate` draws the construction errors and records them;
`triangulate` makes the one triangle mesh (each triangle tagged with its element) that the
ray casters see. Pure computation: no files.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import shapely
from scipy.spatial.transform import Rotation
from shapely.geometry import Polygon

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.config import AsBuiltConfig
from bimgraph.errors import InputError
from bimgraph.geometry import plane_basis, plane_frame, plane_shape

UP = np.array([0.0, 0.0, 1.0])
GROUND_MARGIN_M = 10.0
# A slab top this close to the storey's elevation is its floor.
FLOOR_TOL_M = 0.3
# The least height between floor and ceiling of a storey to walk.
MIN_HEADROOM_M = 2.0


@dataclass
class Element:
    """One planar as-built surface. `plane` is (n, d) in B with n pointing into free space;
    `polygon` (N x 3) and `holes` lie on it."""

    name: str
    kind: str  # wall | floor | ceiling | clutter | board | partition
    face_id: str | None
    plane: np.ndarray
    polygon: np.ndarray
    holes: list[np.ndarray] = field(default_factory=list)

    @cached_property
    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(origin, basis) of the plane's 2-D frame: p = origin + basis @ xy."""
        return plane_frame(self.plane)

    @cached_property
    def shape(self) -> Polygon:
        """The outline (with holes) in the plane's 2-D frame."""
        return plane_shape(self.plane, self.polygon, self.holes)


@dataclass
class Deviation:
    """How one planned wall face was built: moved `offset_m` along its normal (positive into
    the room), tilted `tilt_deg` about the horizontal axis through `pivot` along its bottom
    edge, or not built at all."""

    face_id: str
    wall_guid: str
    built: bool
    offset_m: float
    tilt_deg: float
    pivot: np.ndarray
    axis: np.ndarray
    plane_planned: np.ndarray
    plane_as_built: np.ndarray


@dataclass
class Mesh:
    vertices: np.ndarray  # V x 3, frame B
    triangles: np.ndarray  # T x 3
    element: np.ndarray  # T, index into the element list


@dataclass
class Storey:
    """The storey the camera walks: its floor and ceiling heights and the faces in between."""

    name: str
    floor_z: float
    ceiling_z: float
    faces: list[BimFace]
    floors: list[BimFace] = field(default_factory=list)  # slab tops at floor height, if imported


def pick_storey(plane_map: PlaneMap, name: str = "") -> Storey:
    """The named storey, or the one with the most wall area. Its floor is the storey's
    elevation; its ceiling the median top of its walls (gables and parapets stick out above),
    or the underside of a slab below that, where the walls run up through the slab to the
    next storey (AC20-FZK-Haus: 2.5 m, not 2.7; a run given the slabs matched the ceiling to
    the plan and put the floor, and the walk, 20 cm off)."""
    walls = plane_map.walls()
    if not walls:
        raise InputError(f"{plane_map.source or 'the model'}: no wall faces, nothing to walk through")
    area: dict[str, float] = {}
    for f in walls:
        area[f.storey] = area.get(f.storey, 0.0) + f.area
    if name and name not in area:
        raise InputError(f"no walls on storey {name!r}; storeys with walls: {', '.join(sorted(area))}")
    name = name or max(sorted(area), key=area.get)
    own = [f for f in walls if f.storey == name]
    floor_z = float(np.median([f.elevation for f in own]))
    ceiling_z = float(np.median([np.asarray(f.polygon)[:, 2].max() for f in own]))
    if ceiling_z - floor_z < MIN_HEADROOM_M:
        raise InputError(f"storey {name!r}: walls only {ceiling_z - floor_z:.2f} m high, too low to walk")
    undersides = [f for f in plane_map.faces
                  if f.kind == "slab_bottom" and floor_z + MIN_HEADROOM_M <= _height(f) < ceiling_z]
    if undersides:  # the largest such slab, not a landing's or a canopy's
        ceiling_z = _height(max(undersides, key=lambda f: f.area))
    faces = []
    for f in plane_map.faces:
        z = np.asarray(f.polygon)[:, 2]
        if f.kind == "wall" and z.max() > floor_z + 0.1 and z.min() < ceiling_z - 0.1:
            faces.append(f)
    floors = [f for f in plane_map.faces
              if f.kind == "slab_top" and abs(_height(f) - floor_z) < FLOOR_TOL_M]
    return Storey(name=name, floor_z=floor_z, ceiling_z=ceiling_z, faces=faces, floors=floors)


def _height(slab_face: BimFace) -> float:
    """The mean height of a horizontal face's corners."""
    return float(np.mean(np.asarray(slab_face.polygon)[:, 2]))


def planned_elements(storey: Storey) -> list[Element]:
    """The storey's wall faces as planned, and a floor and a ceiling spanning them (no model
    face behind those: slabs are not part of the plane map by default). The floor reaches
    GROUND_MARGIN_M beyond the walls, so that a view out of a door or window meets the ground."""
    elements = [
        Element(f.id, "wall", f.id, f.plane.copy(), np.asarray(f.polygon, dtype=float),
                [np.asarray(h, dtype=float) for h in f.holes])
        for f in storey.faces
    ]
    xy = np.concatenate([e.polygon[:, :2] for e in elements])
    for kind, z, sign, margin in [("floor", storey.floor_z, 1.0, GROUND_MARGIN_M), ("ceiling", storey.ceiling_z, -1.0, 0.5)]:
        (x0, y0), (x1, y1) = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        ring = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
        elements.append(Element(kind, kind, None, np.array([0.0, 0.0, sign, -sign * z]), ring))
    return elements


def deviate(elements: list[Element], walls_by_guid: dict[str, str], cfg: AsBuiltConfig,
            rng: np.random.Generator) -> tuple[list[Element], list[Deviation]]:
    """Draw the construction errors: faces moved or tilted, whole walls not built. Returns
    the built elements and one `Deviation` per planned wall face. `walls_by_guid` maps each
    face id to its wall's GlobalId."""
    faces = [e for e in elements if e.kind == "wall"]
    guids = sorted({walls_by_guid[e.face_id] for e in faces})
    n_missing = min(int(round(cfg.missing_wall_fraction * len(guids))), len(guids) - 1)
    missing = set(rng.permutation(guids)[:n_missing].tolist())
    out, deviations = [], []
    for e in elements:
        if e.kind != "wall":
            out.append(e)
            continue
        # every face draws alike whatever the fractions, so that a scenario with and without
        # offsets (or tilts) differs in those alone
        moved, size, sign, tilted, angle = rng.random(), rng.random(), rng.choice([-1.0, 1.0]), rng.random(), rng.random()
        offset = sign * (cfg.offset_min_m + size * (cfg.offset_max_m - cfg.offset_min_m)) if moved < cfg.offset_fraction else 0.0
        tilt = cfg.tilt_max_deg * (2.0 * angle - 1.0) if tilted < cfg.tilt_fraction else 0.0
        n = e.plane[:3]
        axis = plane_basis(n)[:, 0]
        centre = e.polygon.mean(axis=0)
        pivot = np.array([centre[0], centre[1], e.polygon[:, 2].min()]) + offset * n
        R = Rotation.from_rotvec(np.radians(tilt) * axis).as_matrix()

        def move(points):
            return pivot + (points + offset * n - pivot) @ R.T

        n_built = R @ n
        plane = np.concatenate([n_built, [-n_built @ pivot]])
        guid = walls_by_guid[e.face_id]
        built = guid not in missing
        deviations.append(Deviation(e.face_id, guid, built, float(offset), float(tilt), pivot, axis,
                                    e.plane.copy(), plane))
        if built:
            out.append(replace(e, plane=plane, polygon=move(e.polygon), holes=[move(h) for h in e.holes]))
    return out, deviations


def box_elements(name: str, kind: str, centre: np.ndarray, size: np.ndarray, R_B_O: np.ndarray,
                 bottom: bool = False) -> list[Element]:
    """The faces of a box (object frame O at its centre, `size` along O's axes), outward
    normals; the bottom face is left out when the box stands on the floor."""
    elements = []
    half = np.asarray(size) / 2.0
    for axis in range(3):
        for sign in (1.0, -1.0):
            if axis == 2 and sign < 0 and not bottom:
                continue
            n_O = np.zeros(3)
            n_O[axis] = sign
            a, b = [i for i in range(3) if i != axis]
            corners = []
            for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]:
                p = n_O * half
                p[a], p[b] = sa * half[a], sb * half[b]
                corners.append(p)
            polygon = centre + np.array(corners) @ R_B_O.T
            n_B = R_B_O @ n_O
            side = "top" if axis == 2 and sign > 0 else "bottom" if axis == 2 else f"side{2 * axis + (sign < 0)}"
            elements.append(Element(f"{name}/{side}", kind, None, np.concatenate([n_B, [-n_B @ polygon[0]]]), polygon))
    return elements


def triangulate(elements: list[Element]) -> Mesh:
    """One mesh of every element (constrained Delaunay of each outline with its holes)."""
    vertices, triangles, owner = [], [], []
    count = 0
    for index, e in enumerate(elements):
        shape = e.shape
        if shape.is_empty:
            continue
        origin, basis = e.frame
        tris = shapely.constrained_delaunay_triangles(shape).geoms
        xy = np.array([np.asarray(t.exterior.coords)[:3] for t in tris]).reshape(-1, 2)
        vertices.append(origin + xy @ basis.T)
        triangles.append(count + np.arange(len(xy)).reshape(-1, 3))
        owner.append(np.full(len(tris), index))
        count += len(xy)
    return Mesh(np.concatenate(vertices), np.concatenate(triangles), np.concatenate(owner))
