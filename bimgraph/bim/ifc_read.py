"""Read what the import needs out of an IFC model: meshes in B, openings, rooms, boundaries.

Frame B is the IfcBuilding's own placement (its local coordinate system; the project's world
frame when there is no IfcBuilding), in metres whatever the file's units. Georeferenced
models carry their large offsets in the site or building placement, so B keeps coordinates
small. Every matrix below is rigid; file units are scaled to metres once, at the end.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import ifcopenshell
import ifcopenshell.geom
import ifcopenshell.util.element
import ifcopenshell.util.placement
import ifcopenshell.util.shape
import ifcopenshell.util.unit
import numpy as np
import shapely

from bimgraph.bim import ifc_schema as schema
from bimgraph.bim.faces import loop_normal
from bimgraph.errors import InputError
from bimgraph.geometry import inverse

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
    wall_id: int  # the wall's entity id (GlobalIds may be shared, by a slip)
    points: np.ndarray
    normal: np.ndarray | None = field(init=False)

    def __post_init__(self):
        self.normal = loop_normal(self.points)


class ModelReader:
    """An open model with its unit scale and frame B; caches placements and storeys."""

    def __init__(self, model: ifcopenshell.file, threads: int, missing: dict[int, set[int]] | None = None):
        """`missing`: `missing_references` of the file's parse problems."""
        self.model = model
        self.threads = threads
        self.missing = missing or {}
        self.scale = ifcopenshell.util.unit.calculate_unit_scale(model)  # metres per file unit
        schema.clear_cache()  # one model's placements at a time: each import starts cold, as a new process would
        self._placements = {}
        buildings = model.by_type("IfcBuilding")
        self.T_W_B = self.placement(buildings[0]) if buildings and buildings[0].ObjectPlacement else np.eye(4)
        self.T_B_W = inverse(self.T_W_B)
        self._storeys = {}  # element id -> (storey name, elevation)
        self._storey_rows = {}  # storey id -> (name, elevation)
        self.unread_boundaries = 0  # space boundaries whose geometry `boundaries` could not read
        self.unreadable: dict[int, str] = {}  # element id -> why its geometry cannot be read
        self.kernel_fallbacks: list[str] = []  # bodies the schema reader failed on, left to the kernel
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
        """Placements chain up to the building and the site: each link is computed once,
        walking up the chain without recursion (a file may nest them deeper than Python's
        stack, or in a cycle, which is an InputError)."""
        chain, seen = [], set()
        while placement.id() not in self._placements:
            if placement.id() in seen:
                raise InputError(f"placement #{placement.id()} is placed relative to itself")
            seen.add(placement.id())
            chain.append(placement)
            if not placement.is_a("IfcLocalPlacement") or placement.PlacementRelTo is None:
                break
            placement = placement.PlacementRelTo
        for link in reversed(chain):
            if not link.is_a("IfcLocalPlacement"):  # grid or linear placements
                T = self.to_metres(ifcopenshell.util.placement.get_local_placement(link))
            else:
                T = self.to_metres(schema.axis2placement(link.RelativePlacement))
                if link.PlacementRelTo is not None:
                    T = self._placements[link.PlacementRelTo.id()] @ T
            self._placements[link.id()] = T
        return self._placements[chain[0].id() if chain else placement.id()]

    def meshes(self, elements, subtract_openings: bool = False) -> dict[int, Mesh]:
        """Triangulated geometry of `elements` in B, by entity id; elements whose geometry
        fails are absent. Wall openings are cut out of the face polygons afterwards, at a
        fraction of the cost of `subtract_openings`."""
        out = {}
        elements = [e for e in elements if self._placeable(e)]  # (the kernel crashes on a placement cycle)
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

    def _placeable(self, element) -> bool:
        """Whether the element's placement can be read (it is in no cycle, and neither it nor
        its body names an entity the file lacks); why not goes to `unreadable`."""
        if element.id() in self.unreadable:
            return False
        if self.missing and (user := self._missing_in(element)) is not None:
            self.unreadable[element.id()] = f"its placement or body names an entity the file lacks (in #{user})"
            return False
        try:
            self.placement(element)
            return True
        except Exception as err:
            self.unreadable[element.id()] = f"its placement cannot be read ({err})"
            return False

    def _missing_in(self, element) -> int | None:
        """The first entity of the element's placement chain or body that names an entity the
        file lacks (the element itself, where its own placement or body attribute does)."""
        own = {element.attribute_name(i) for i in self.missing.get(element.id(), ())}
        if own & {"ObjectPlacement", "Representation"}:
            return element.id()
        for root in (element.ObjectPlacement, element.Representation):
            if root is not None:
                for entity in self.model.traverse(root):
                    if entity.id() in self.missing:
                        return entity.id()
        return None

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
                    elevation = float((self.T_B_W @ self.placement(container))[2, 3]) if self._placeable(container) else 0.0
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
            points = schema.curve_points(item)  # a polyline: read at once, without the kernel
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
        """`meshes(elements)`, and closed meshes in B of `solids` by entity id (a list of parts
        each). Bodies that are extrusions of polygons or faceted breps (nearly all openings
        and rooms, most walls) are built here, exactly and at a fraction of the geometry
        iterator's cost; the others go through the iterator in one run (setting it up costs
        as much as a dozen walls). Elements without geometry are absent; solids built here
        come first, each part in the order of `solids`."""
        built, others = {}, []
        for element in [*elements, *solids]:
            if not self._placeable(element):  # (a placement cycle: the geometry kernel would crash on it)
                continue
            try:
                parts = self._built(element)
            except Exception as err:  # a body the schema reader cannot follow (a broken reference, a
                parts = None          # degenerate loop): the geometry kernel has its go at it
                self.kernel_fallbacks.append(f"{element.GlobalId} ({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})")
            if parts is None:
                others.append(element)
            else:
                built[element.id()] = parts
        meshes = self.meshes(others)
        built.update({e.id(): [meshes.pop(e.id())] for e in solids if e.id() in meshes})
        for element in elements:
            if element.id() in built:
                meshes[element.id()] = _joined(built.pop(element.id()))
        return meshes, built

    def _built(self, element) -> list[Mesh] | None:
        """The parts of an element's body in B (each with the element's placement), built from
        the schema; None where the body is not all extrusions of polygons and faceted breps."""
        items = schema.body_items(element)
        prisms = [schema.prism(item) if item.is_a("IfcExtrudedAreaSolid") else schema.brep(item) for item in items]
        if not items or any(p is None for p in prisms):
            return None
        T_B_E = self.T_B_W @ self.placement(element)
        return [Mesh((V * self.scale) @ T_B_E[:3, :3].T + T_B_E[:3, 3], T, T_B_E) for V, T in prisms]

    def boundaries(self, walls) -> list[Boundary]:
        """Surface space boundaries on the given walls, as point loops in B."""
        wall_ids = {wall.id() for wall in walls}
        spaces = {}  # id -> (guid, T_B_S), read once for the room's many boundaries
        out = []
        for rel in self.model.by_type("IfcRelSpaceBoundary"):
            wall = rel.RelatedBuildingElement
            if wall is None or wall.id() not in wall_ids:  # most are on slabs, doors, windows
                continue
            space, geometry = rel.RelatingSpace, rel.ConnectionGeometry
            if space is None or not space.is_a("IfcSpace"):
                continue
            if geometry is None or not geometry.is_a("IfcConnectionSurfaceGeometry"):
                continue
            try:
                points = schema.surface_points(geometry.SurfaceOnRelatingElement)
                if points is None or len(points) < 3:
                    continue
                if space.id() not in spaces:
                    spaces[space.id()] = (space.GlobalId, self.T_B_W @ self.placement(space))
            except Exception:  # (a broken reference or a cycle: the room is found by its solid, or not at all)
                self.unread_boundaries += 1
                continue
            guid, T_B_S = spaces[space.id()]
            points = points * self.scale
            out.append(Boundary(guid, wall.id(), points @ T_B_S[:3, :3].T + T_B_S[:3, 3]))
        return out


def _joined(parts: list[Mesh]) -> Mesh:
    """The parts of one body as one mesh (the layers of a wall touch: its faces are found on
    them together), at the element's placement, which every part carries."""
    starts = np.cumsum([0] + [len(part.V) for part in parts[:-1]])
    return Mesh(np.vstack([part.V for part in parts]), np.vstack([part.T + start for part, start in zip(parts, starts)]),
                parts[0].T_B_E)


def available_cores() -> int:
    """The cores this process may run on (the geometry iterator's default thread count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
