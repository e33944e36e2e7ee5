"""Write a `Building` as an IFC model with ifcopenshell.api (IFC4 or IFC2X3, metres or mm).

The model is what an authoring tool would export: project, site, building, storeys; each wall
an IfcWall with a rectangular extruded body and an axis, voided by IfcOpeningElements that
IfcDoors and IfcWindows fill; each room an IfcSpace extruded from its footprint to the storey
height; and 2nd-level space boundaries on the wall faces (as ArchiCAD writes them). The
building sits at the origin of the project's world frame, so frame B of the import is the
frame the `Building` is written in.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import ifcopenshell
import ifcopenshell.api.aggregate
import ifcopenshell.api.boundary
import ifcopenshell.api.context
import ifcopenshell.api.feature
import ifcopenshell.api.geometry
import ifcopenshell.api.owner
import ifcopenshell.api.owner.settings
import ifcopenshell.api.project
import ifcopenshell.api.root
import ifcopenshell.api.spatial
import ifcopenshell.api.unit
import numpy as np

from bimgraph.bim.building import Building, Space, Wall
from bimgraph.geometry import make_pose

# Openings stick out of both wall faces by this much, as authoring tools make them, so that
# the subtraction never leaves a skin.
_OPENING_MARGIN_M = 0.01
_FILLING_THICKNESS_M = 0.05
# A footprint edge bounds a wall face when it lies this close to the face's line.
_ON_FACE_TOL_M = 1e-6


def write_ifc(building: Building, path, schema: str = "IFC4", length_unit: str = "m") -> None:
    """Write `building` to `path` as IFC (`schema` "IFC4" or "IFC2X3"; `length_unit` "m" or
    "mm"). Coordinates in `building` are metres; the file stores them in `length_unit`."""
    if schema not in ("IFC4", "IFC2X3") or length_unit not in ("m", "mm"):
        raise ValueError(f"unsupported schema {schema!r} or length unit {length_unit!r}")
    file = ifcopenshell.api.project.create_file(version=schema)
    with _owner_history(file):
        _Writer(file, building, length_unit)
        if file.schema == "IFC2X3":  # a few api calls leave it out (IfcRelFillsElement)
            history = file.by_type("IfcOwnerHistory")[0]
            for entity in file.by_type("IfcRoot"):
                entity.OwnerHistory = entity.OwnerHistory or history
    file.write(str(Path(path)))


@contextmanager
def _owner_history(file):
    """IFC2X3 requires an owner history on every rooted entity; ifcopenshell.api finds the
    user and application through module-level hooks, which are restored afterwards."""
    settings = ifcopenshell.api.owner.settings
    saved = settings.get_user, settings.get_application
    if file.schema == "IFC2X3":
        organisation = file.createIfcOrganization(None, "bimgraph")
        user = file.createIfcPersonAndOrganization(file.createIfcPerson(), organisation)
        application = file.createIfcApplication(organisation, "1", "bimgraph", "bimgraph")
        settings.get_user, settings.get_application = (lambda f: user), (lambda f: application)
    try:
        yield
    finally:
        settings.get_user, settings.get_application = saved


class _Writer:
    def __init__(self, file, building: Building, length_unit: str):
        api = ifcopenshell.api
        self.file = f = file
        self.scale = 1000.0 if length_unit == "mm" else 1.0  # file units per metre
        project = api.root.create_entity(f, ifc_class="IfcProject", name=building.name)
        prefix = "MILLI" if length_unit == "mm" else None
        api.unit.assign_unit(f, units=[
            api.unit.add_si_unit(f, unit_type="LENGTHUNIT", prefix=prefix),
            api.unit.add_si_unit(f, unit_type="AREAUNIT"),
            api.unit.add_si_unit(f, unit_type="VOLUMEUNIT"),
            api.unit.add_si_unit(f, unit_type="PLANEANGLEUNIT"),
        ])
        model = api.context.add_context(f, context_type="Model")
        self.body = api.context.add_context(f, context_type="Model", context_identifier="Body",
                                            target_view="MODEL_VIEW", parent=model)
        self.axis = api.context.add_context(f, context_type="Model", context_identifier="Axis",
                                            target_view="GRAPH_VIEW", parent=model)

        site = self._spatial("IfcSite", "Site", project, np.eye(4))
        ifc_building = self._spatial("IfcBuilding", building.name, site, np.eye(4))
        self.storeys = []
        for storey in building.storeys:
            element = self._spatial("IfcBuildingStorey", storey.name, ifc_building,
                                    make_pose(np.eye(3), [0.0, 0.0, storey.elevation]))
            element.Elevation = storey.elevation * self.scale
            self.storeys.append(element)

        walls = [self._wall(wall, building) for wall in building.walls]
        for space in building.spaces:
            ifc_space = self._space(space, building)
            self._space_boundaries(ifc_space, space, building, walls)

    def _spatial(self, ifc_class, name, parent, T_W_E):
        api = ifcopenshell.api
        element = api.root.create_entity(self.file, ifc_class=ifc_class, name=name)
        if hasattr(element, "CompositionType"):  # mandatory in IFC2X3
            element.CompositionType = "ELEMENT"
        api.aggregate.assign_object(self.file, relating_object=parent, products=[element])
        api.geometry.edit_object_placement(self.file, product=element, matrix=T_W_E)
        return element

    def _placed(self, ifc_class, name, storey_index, T_W_E, representation):
        api = ifcopenshell.api
        element = api.root.create_entity(self.file, ifc_class=ifc_class, name=name)
        if ifc_class != "IfcOpeningElement":
            api.spatial.assign_container(self.file, relating_structure=self.storeys[storey_index],
                                         products=[element])
        api.geometry.edit_object_placement(self.file, product=element, matrix=T_W_E)
        api.geometry.assign_representation(self.file, product=element, representation=representation)
        return element

    def _box(self, length, height, thickness):
        """A box along local x from 0 to `length`, centred on y, from z = 0 up `height`."""
        return ifcopenshell.api.geometry.add_wall_representation(
            self.file, context=self.body, length=length, height=height, thickness=thickness,
            offset=-thickness / 2)

    def _wall(self, wall: Wall, building: Building):
        api = ifcopenshell.api
        start, end = np.asarray(wall.start, float), np.asarray(wall.end, float)
        length = float(np.linalg.norm(end - start))
        x = np.append((end - start) / length, 0.0)
        R = np.column_stack([x, np.cross([0.0, 0.0, 1.0], x), [0.0, 0.0, 1.0]])
        elevation = building.storeys[wall.storey].elevation
        T_W_wall = make_pose(R, [*start, elevation])
        ifc_wall = self._placed("IfcWall", wall.name, wall.storey, T_W_wall,
                                self._box(length, wall.height, wall.thickness))
        axis = api.geometry.add_axis_representation(
            self.file, context=self.axis, axis=[(0.0, 0.0), (length, 0.0)])
        api.geometry.assign_representation(self.file, product=ifc_wall, representation=axis)
        for i, opening in enumerate(wall.openings):
            T_W_opening = T_W_wall @ make_pose(np.eye(3), [opening.along, 0.0, opening.sill])
            void = self._placed("IfcOpeningElement", f"{wall.name} opening {i}", wall.storey, T_W_opening,
                                self._box(opening.width, opening.height, wall.thickness + 2 * _OPENING_MARGIN_M))
            api.feature.add_feature(self.file, feature=void, element=ifc_wall)
            filling_class = "IfcDoor" if opening.kind == "door" else "IfcWindow"
            filling = self._placed(filling_class, f"{wall.name} {opening.kind} {i}", wall.storey, T_W_opening,
                                   self._box(opening.width, opening.height, _FILLING_THICKNESS_M))
            api.feature.add_filling(self.file, opening=void, element=filling)
        return ifc_wall

    def _space(self, space: Space, building: Building):
        f = self.file
        storey = building.storeys[space.storey]
        points = [f.createIfcCartesianPoint((float(x * self.scale), float(y * self.scale)))
                  for x, y in space.footprint]
        profile = f.createIfcArbitraryClosedProfileDef("AREA", None, f.createIfcPolyline(points + points[:1]))
        origin = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
        solid = f.createIfcExtrudedAreaSolid(profile, origin, f.createIfcDirection((0.0, 0.0, 1.0)),
                                             storey.height * self.scale)
        representation = f.createIfcShapeRepresentation(self.body, "Body", "SweptSolid", [solid])
        api = ifcopenshell.api
        element = api.root.create_entity(f, ifc_class="IfcSpace", name=space.name)
        element.CompositionType = "ELEMENT"
        if hasattr(element, "InteriorOrExteriorSpace"):  # mandatory in IFC2X3
            element.InteriorOrExteriorSpace = "INTERNAL"
        api.aggregate.assign_object(f, relating_object=self.storeys[space.storey], products=[element])
        api.geometry.edit_object_placement(f, product=element, matrix=make_pose(np.eye(3), [0, 0, storey.elevation]))
        api.geometry.assign_representation(f, product=element, representation=representation)
        return element

    def _space_boundaries(self, ifc_space, space: Space, building: Building, ifc_walls):
        """One 2nd-level boundary per stretch of footprint edge that lies on a wall face, in
        the space's coordinates: x along the face, y up, z (the plane's normal) into the room."""
        storey = building.storeys[space.storey]
        footprint = np.asarray(space.footprint, float)
        for a, b in zip(footprint, np.roll(footprint, -1, axis=0)):
            for wall, ifc_wall in zip(building.walls, ifc_walls):
                if wall.storey != space.storey:
                    continue
                overlap = edge_on_wall_face(a, b, wall)
                if overlap is None:
                    continue
                p0, p1 = overlap
                direction = (b - a) / np.linalg.norm(b - a)
                z_axis = np.array([-direction[1], direction[0], 0.0])  # left of a CCW edge: inside
                x_axis = np.cross([0.0, 0.0, 1.0], z_axis)
                width = float(np.dot(np.append(p0 - p1, 0.0), x_axis))
                height = min(wall.height, storey.height)
                rel = ifcopenshell.api.root.create_entity(self.file, ifc_class="IfcRelSpaceBoundary", name="2ndLevel")
                rel.Description = "2a"
                rel.RelatingSpace = ifc_space
                rel.RelatedBuildingElement = ifc_wall
                rel.PhysicalOrVirtualBoundary = "PHYSICAL"
                rel.InternalOrExternalBoundary = "INTERNAL"
                ifcopenshell.api.boundary.assign_connection_geometry(
                    self.file, rel_space_boundary=rel,
                    outer_boundary=[(0.0, 0.0), (width, 0.0), (width, height), (0.0, height)],
                    location=(float(p1[0]), float(p1[1]), 0.0), axis=tuple(z_axis), ref_direction=tuple(x_axis),
                    unit_scale=1.0 / self.scale)


def edge_on_wall_face(a, b, wall: Wall):
    """The stretch (p0, p1) of footprint edge a->b that lies on a side face of `wall`, or None."""
    start, end = np.asarray(wall.start, float), np.asarray(wall.end, float)
    length = np.linalg.norm(end - start)
    x = (end - start) / length
    y = np.array([-x[1], x[0]])
    edge = b - a
    if abs(x[0] * edge[1] - x[1] * edge[0]) / np.linalg.norm(edge) > _ON_FACE_TOL_M:
        return None
    offset = np.dot(a - start, y)
    if abs(abs(offset) - wall.thickness / 2) > _ON_FACE_TOL_M:
        return None
    ta, tb = np.dot(a - start, x), np.dot(b - start, x)
    lo, hi = max(min(ta, tb), 0.0), min(max(ta, tb), length)
    if hi - lo <= _ON_FACE_TOL_M:
        return None
    # Order the stretch like the edge, so that it keeps the footprint's orientation.
    t0, t1 = (lo, hi) if ta <= tb else (hi, lo)
    return start + t0 * x + offset * y, start + t1 * x + offset * y
