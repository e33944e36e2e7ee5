"""Read what the import needs out of an IFC model: meshes in B, openings, rooms, boundaries.

Frame B is the IfcBuilding's own placement (its local coordinate system; the project's world
frame when there is no IfcBuilding), in metres whatever the file's units. Georeferenced
models carry their large offsets in the site or building placement, so B keeps coordinates
small. Every matrix below is rigid; file units are scaled to metres once, at the end.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

import ifcopenshell
import ifcopenshell.geom
import ifcopenshell.util.element
import ifcopenshell.util.placement
import ifcopenshell.util.shape
import ifcopenshell.util.unit
import numpy as np
import shapely

from bimgraph.bim.faces import loop_normal
from bimgraph.errors import InputError
from bimgraph.geometry import inverse

_END_MARK = b"END-ISO-10303-21;"


@dataclass
class Mesh:
    V: np.ndarray  # vertices in B, metres
    T: np.ndarray  # triangles, indices into V
    T_B_E: np.ndarray | None = None  # the element's placement, when known


@dataclass
class Boundary:
    """A space boundary's surface: `points` (N x 3, in B) of its outer loop, `normal` its
    unit normal (None if degenerate), computed once for all the faces of its wall."""

    space_guid: str
    wall_guid: str
    points: np.ndarray
    normal: np.ndarray | None = field(init=False)

    def __post_init__(self):
        self.normal = loop_normal(self.points)


def open_model(path) -> ifcopenshell.file:
    """Open an IFC file; a missing, non-IFC or truncated file is an InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    with open(path, "rb") as stream:
        head = stream.read(64)
        stream.seek(0, 2)
        stream.seek(max(0, stream.tell() - 1024))
        tail = stream.read()
    if not head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"ISO-10303-21;"):  # a BOM is allowed
        raise InputError(f"{path}: not an IFC file (no ISO-10303-21 header)")
    if _END_MARK not in tail:
        raise InputError(f"{path}: truncated IFC file (no {_END_MARK.decode()} at its end)")
    try:
        return ifcopenshell.open(str(path))
    except Exception as err:  # ifcopenshell raises several unrelated types on bad files
        raise InputError(f"{path}: cannot parse IFC ({str(err).splitlines()[0] if str(err) else type(err).__name__})") from None


class ModelReader:
    """An open model with its unit scale and frame B; caches placements and storeys."""

    def __init__(self, model: ifcopenshell.file, threads: int):
        self.model = model
        self.threads = threads
        self.scale = ifcopenshell.util.unit.calculate_unit_scale(model)  # metres per file unit
        _a2p.cache_clear()  # one model's placements at a time: each import starts cold, as a new process would
        self._placements = {}
        buildings = model.by_type("IfcBuilding")
        self.T_W_B = self.placement(buildings[0]) if buildings and buildings[0].ObjectPlacement else np.eye(4)
        self.T_B_W = inverse(self.T_W_B)
        self._storeys = {}  # element id -> (storey name, elevation)
        self._storey_rows = {}  # storey id -> (name, elevation)
        self.settings = {}
        for subtract in (False, True):
            self.settings[subtract] = ifcopenshell.geom.settings()
            self.settings[subtract].set("disable-opening-subtractions", not subtract)

    def to_metres(self, T_file: np.ndarray) -> np.ndarray:
        T = np.array(T_file, dtype=float)
        T[:3, 3] *= self.scale
        return T

    def placement(self, element) -> np.ndarray:
        """T_W_E of an element's object placement, in metres (the world frame where it has
        none: the attribute is optional, and geometry kernels read it so)."""
        if element.ObjectPlacement is None:
            return np.eye(4)
        return self._local_placement(element.ObjectPlacement)

    def _local_placement(self, placement) -> np.ndarray:
        """Placements chain up to the building and the site: each link is computed once."""
        key = placement.id()
        if key not in self._placements:
            if not placement.is_a("IfcLocalPlacement"):  # grid or linear placements
                T = self.to_metres(ifcopenshell.util.placement.get_local_placement(placement))
            else:
                T = self.to_metres(_axis2placement(placement.RelativePlacement))
                if placement.PlacementRelTo is not None:
                    T = self._local_placement(placement.PlacementRelTo) @ T
            self._placements[key] = T
        return self._placements[key]

    def meshes(self, elements, subtract_openings: bool = False) -> dict[int, Mesh]:
        """Triangulated geometry of `elements` in B, by entity id; elements whose geometry
        fails are absent. Wall openings are cut out of the face polygons afterwards, at a
        fraction of the cost of `subtract_openings`."""
        out = {}
        if not elements:
            return out
        iterator = ifcopenshell.geom.iterator(self.settings[subtract_openings], self.model, self.threads or available_cores(),
                                              include=elements)
        if iterator.initialize():
            while True:
                shape = iterator.get()
                T_B_E = self.T_B_W @ ifcopenshell.util.shape.get_shape_matrix(shape)
                V = ifcopenshell.util.shape.get_vertices(shape.geometry)
                T = ifcopenshell.util.shape.get_faces(shape.geometry)
                if len(T):
                    out[shape.id] = Mesh(V @ T_B_E[:3, :3].T + T_B_E[:3, 3], np.asarray(T, dtype=int), T_B_E)
                if not iterator.next():
                    break
        return out

    def storey(self, element) -> tuple[str, float]:
        """Name and elevation in B of the storey containing `element` ("" and 0 if none)."""
        if element.id() not in self._storeys:
            container = ifcopenshell.util.element.get_container(element)
            while container is not None and not container.is_a("IfcBuildingStorey"):
                container = ifcopenshell.util.element.get_aggregate(container)
            if container is None:
                self._storeys[element.id()] = ("", 0.0)
            else:
                if container.id() not in self._storey_rows:  # each storey once, for all its elements
                    elevation = float((self.T_B_W @ self.placement(container))[2, 3])
                    self._storey_rows[container.id()] = (container.Name or "", elevation)
                self._storeys[element.id()] = self._storey_rows[container.id()]
        return self._storeys[element.id()]

    def axis(self, wall, T_B_E: np.ndarray) -> np.ndarray | None:
        """The vertices (N x 2, x and y in B) of a wall's axis representation, a curved one
        (an arc, as Revit and ArchiCAD write curved walls) as the geometry kernel tessellates
        it; None if it has none the kernel reads. `T_B_E` is the wall's placement."""
        if wall.Representation is None:
            return None
        for representation in wall.Representation.Representations:
            if representation.RepresentationIdentifier != "Axis" or len(representation.Items) != 1:
                continue
            item = representation.Items[0]
            points = _curve_points(item)  # a polyline: read at once, without the kernel
            points = points * self.scale if points is not None else self._tessellated(item)
            if points is None or len(points) < 2:
                return None
            return (points @ T_B_E[:3, :3].T + T_B_E[:3, 3])[:, :2]
        return None

    def _tessellated(self, curve) -> np.ndarray | None:
        """The vertices in order (N x 3, metres) of a curve as the kernel tessellates it (its
        linear deflection, 1 mm); None if it gives no single line."""
        try:
            shape = ifcopenshell.geom.create_shape(self.settings[False], curve)
        except RuntimeError:  # not a curve the kernel reads: as if the wall had no axis
            return None
        segments = np.asarray(shape.verts, dtype=float).reshape(-1, 3)[np.asarray(shape.edges, dtype=int).reshape(-1, 2)]
        line = shapely.line_merge(shapely.multilinestrings(shapely.linestrings(segments))) if len(segments) else None
        return shapely.get_coordinates(line, include_z=True) if isinstance(line, shapely.LineString) else None

    def meshes_and_solids(self, elements, solids) -> tuple[dict[int, Mesh], dict[int, list[Mesh]]]:
        """`meshes(elements)`, and closed meshes in B of `solids` by entity id: built here,
        exactly and cheaply, for bodies that are extrusions of polygons or faceted breps
        (openings and rooms nearly always are), by the geometry iterator for the others, in
        the same run as `elements` (setting the iterator up costs as much as a dozen walls).
        Solids without geometry are absent; those built here come first, each part in the
        order of `solids`."""
        built, others = {}, []
        for element in solids:
            items = _body_items(element)
            prisms = [_prism(item) if item.is_a("IfcExtrudedAreaSolid") else _brep(item) for item in items]
            if not items or any(p is None for p in prisms):
                others.append(element)
                continue
            T_B_E = self.T_B_W @ self.placement(element)
            built[element.id()] = [Mesh((V * self.scale) @ T_B_E[:3, :3].T + T_B_E[:3, 3], T) for V, T in prisms]
        meshes = self.meshes([*elements, *others])
        built.update({e.id(): [meshes.pop(e.id())] for e in others if e.id() in meshes})
        return meshes, built

    def boundaries(self, walls) -> list[Boundary]:
        """Surface space boundaries on the given walls, as point loops in B."""
        wall_guids = {wall.id(): wall.GlobalId for wall in walls}
        spaces = {}  # id -> (guid, T_B_S), read once for the room's many boundaries
        out = []
        for rel in self.model.by_type("IfcRelSpaceBoundary"):
            wall = rel.RelatedBuildingElement
            if wall is None or wall.id() not in wall_guids:  # most are on slabs, doors, windows
                continue
            space, geometry = rel.RelatingSpace, rel.ConnectionGeometry
            if space is None or not space.is_a("IfcSpace"):
                continue
            if geometry is None or not geometry.is_a("IfcConnectionSurfaceGeometry"):
                continue
            points = _surface_points(geometry.SurfaceOnRelatingElement)
            if points is None or len(points) < 3:
                continue
            if space.id() not in spaces:
                spaces[space.id()] = (space.GlobalId, self.T_B_W @ self.placement(space))
            guid, T_B_S = spaces[space.id()]
            points = points * self.scale
            out.append(Boundary(guid, wall_guids[wall.id()], points @ T_B_S[:3, :3].T + T_B_S[:3, 3]))
        return out


def available_cores() -> int:
    """The cores this process may run on (the geometry iterator's default thread count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _axis2placement(placement) -> np.ndarray:
    """ifcopenshell's get_axis2placement (read-only), computed once per distinct value: the
    items of a model repeat most of them (Duplex: 79 values in 242 placements), and the
    matrix costs ten times its key."""
    location = placement.Location
    if not placement.is_a("IfcAxis2Placement3D") or not location.is_a("IfcCartesianPoint"):
        return ifcopenshell.util.placement.get_axis2placement(placement)
    axis, ref = placement.Axis, placement.RefDirection
    values = (location.Coordinates, axis.DirectionRatios if axis else None, ref.DirectionRatios if ref else None)
    return _a2p(repr(values), *values)


@functools.lru_cache(maxsize=4096)
def _a2p(spelling: str, location: tuple, axis: tuple | None, ref: tuple | None) -> np.ndarray:
    """`spelling`, the values' repr, keeps -0.0 and 0.0 apart, which tuple equality does not."""
    z = np.array(axis or (0, 0, 1), dtype=float)
    z /= np.linalg.norm(z)
    # IFC allows a RefDirection that is not perpendicular to the Axis: its projection onto the
    # plane across the axis is the x axis (as geometry kernels take it), so the frame is rigid
    x = np.array(ref or (1, 0, 0), dtype=float)
    x = x - (x @ z) * z
    M = ifcopenshell.util.placement.a2p(location, z, x / np.linalg.norm(x))
    M.flags.writeable = False
    return M


def _body_items(element) -> list:
    """The items of an element's body if all are extrusions or faceted breps, else []."""
    representation = element.Representation
    if representation is None:
        return []
    bodies = [r for r in representation.Representations if r.RepresentationIdentifier == "Body"]
    if len(bodies) != 1:
        return []
    items = list(bodies[0].Items)
    return items if all(i.is_a("IfcExtrudedAreaSolid") or i.is_a("IfcFacetedBrep") for i in items) else []


def _profile_points(profile) -> np.ndarray | None:
    """The outline of a rectangle or polyline profile, in its own 2-D coordinates."""
    if profile.is_a("IfcRectangleProfileDef"):
        x, y = profile.XDim / 2, profile.YDim / 2
        points = np.array([[-x, -y], [x, -y], [x, y], [-x, y]], dtype=float)
    elif profile.is_a() == "IfcArbitraryClosedProfileDef":
        points = _curve_points(profile.OuterCurve)
        if points is None:
            return None
        points = points[:, :2]
    else:
        return None
    position = getattr(profile, "Position", None)
    if position is not None:
        x = np.asarray(position.RefDirection.DirectionRatios[:2], dtype=float) if position.RefDirection else np.array([1.0, 0.0])
        x /= np.linalg.norm(x)
        R = np.column_stack([x, [-x[1], x[0]]])
        points = points @ R.T + np.asarray(position.Location.Coordinates[:2], dtype=float)
    return points


def _curve_points(curve) -> np.ndarray | None:
    """The vertices of a polyline-like curve (polyline, indexed poly curve of straight
    segments, composite of those), without the closing repeat; None for curved ones."""
    if curve.is_a("IfcPolyline"):
        points = _coordinates(curve.Points)
    elif curve.is_a("IfcIndexedPolyCurve"):
        if curve.Segments and any(not s.is_a("IfcLineIndex") for s in curve.Segments):
            return None
        points = np.array(curve.Points.CoordList, dtype=float)
        if curve.Segments:
            order = [i - 1 for s in curve.Segments for i in s.wrappedValue]
            points = points[order]
    elif curve.is_a("IfcCompositeCurve"):
        parts = []
        for segment in curve.Segments:
            part = _curve_points(segment.ParentCurve)
            if part is None:
                return None
            parts.append(part if segment.SameSense else part[::-1])
        points = np.concatenate(parts)
    else:
        return None
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9  # repeated vertices
    points = points[keep]
    # np.allclose's test with its default tolerances, written out: allclose costs 50 us.
    if len(points) > 1 and (np.abs(points[0] - points[-1]) <= 1e-8 + 1e-5 * np.abs(points[-1])).all():
        points = points[:-1]
    return points


def _coordinates(points) -> np.ndarray:
    """The coordinates of IfcCartesianPoints (N x 2 or 3): their only attribute, read by
    index at a third of the cost of by name."""
    return np.array([p[0] for p in points], dtype=float)


def _prism(solid) -> tuple[np.ndarray, np.ndarray] | None:
    """A closed triangle mesh (vertices in the item's parent frame, file units) of an
    extrusion of a polygon profile; None for other profiles."""
    profile = _profile_points(solid.SweptArea)
    if profile is None or len(profile) < 3:
        return None
    polygon = shapely.Polygon(profile)
    if not polygon.is_valid or polygon.area <= 0:
        return None
    n = len(profile)
    direction = np.asarray(solid.ExtrudedDirection.DirectionRatios, dtype=float)
    length = float(np.linalg.norm(direction))
    if not (length > 0 and solid.Depth > 0 and np.isfinite(direction).all()):
        return None  # degenerate: left to the geometry kernel, which warns and skips it
    direction = direction / length * solid.Depth
    bottom = np.column_stack([profile, np.zeros(n)])
    V = np.vstack([bottom, bottom + direction])
    caps = _corner_ids(shapely.constrained_delaunay_triangles(polygon), profile, np.arange(n))
    i = np.arange(n)
    j = (i + 1) % n
    T = np.vstack([caps, caps + n, np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n])])
    if solid.Position is not None:
        M = _axis2placement(solid.Position)
        V = V @ M[:3, :3].T + M[:3, 3]
    return V, T


def _brep(brep) -> tuple[np.ndarray, np.ndarray] | None:
    """A closed triangle mesh (file units, the item's frame) of a faceted brep whose faces
    are polygons without holes; None otherwise."""
    loops = []
    for face in brep.Outer.CfsFaces:
        bounds = face.Bounds
        if len(bounds) != 1 or not (bound := bounds[0].Bound).is_a("IfcPolyLoop"):
            return None
        loop = _coordinates(bound.Polygon)
        loops.append(loop if bounds[0].Orientation else loop[::-1])
    # Shared corners get one index, so that the faces' common edges are cut at one point.
    V, index = np.unique(np.concatenate(loops), axis=0, return_inverse=True)
    ids = np.split(index.reshape(-1), np.cumsum([len(loop) for loop in loops])[:-1])
    triangles = [i[None, :] for i in ids]  # the triangles' own; the others' below
    # Each polygon is laid flat in its own plane and triangulated there, those with as many
    # corners together: numpy's and shapely's calls cost more than their work on one.
    for n in {len(loop) for loop in loops} - {3}:
        which = [i for i, loop in enumerate(loops) if len(loop) == n]
        stack = np.array([loops[i] for i in which])
        axes = np.linalg.svd(stack - stack.mean(axis=1, keepdims=True))[2][:, :2]  # the loops' planes
        flat = stack @ axes.transpose(0, 2, 1)
        polygons = shapely.polygons(flat)
        if not shapely.is_valid(polygons).all() or (shapely.area(polygons) <= 0).any():
            return None
        for i, points, cdt in zip(which, flat, shapely.constrained_delaunay_triangles(polygons)):
            triangles[i] = _corner_ids(cdt, points, ids[i])
    return V, np.concatenate(triangles)


def _corner_ids(triangles, points: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The corners of `triangles` (a constrained Delaunay triangulation of a polygon of
    vertices `points`, N x 2) as the `ids` of those vertices."""
    lookup = {p: i for p, i in zip(map(tuple, points.tolist()), ids.tolist())}
    corners = shapely.get_coordinates(triangles).reshape(-1, 4, 2)[:, :3]
    return np.array([[lookup[tuple(c)] for c in triangle] for triangle in corners.tolist()], dtype=int)


def _surface_points(surface) -> np.ndarray | None:
    """The outer loop of a boundary surface in its space's coordinates (file units)."""
    if surface.is_a("IfcCurveBoundedPlane"):
        loop = _curve_points(surface.OuterBoundary)
        if loop is None:
            return None
        M = _axis2placement(surface.BasisSurface.Position)
        return loop @ M[:3, :3].T + M[:3, 3]
    if surface.is_a("IfcSurfaceOfLinearExtrusion") and surface.SweptCurve.is_a("IfcArbitraryOpenProfileDef"):
        line = _curve_points(surface.SweptCurve.Curve)
        if line is None:
            return None
        direction = np.asarray(surface.ExtrudedDirection.DirectionRatios, dtype=float)
        direction = direction / np.linalg.norm(direction) * surface.Depth
        loop = np.vstack([line, line[::-1] + direction])
        M = _axis2placement(surface.Position)
        return loop @ M[:3, :3].T + M[:3, 3]
    return None
