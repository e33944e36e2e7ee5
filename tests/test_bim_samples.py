"""The importer on real IFC models from ArchiCAD and Revit, checked against ifcopenshell's own
triangulated geometry (openings subtracted, the expensive way) and the models' space
boundaries."""

from collections import defaultdict
from functools import lru_cache

import ifcopenshell
import ifcopenshell.geom
import ifcopenshell.util.placement
import ifcopenshell.util.shape
import ifcopenshell.util.unit
import numpy as np
import open3d as o3d
import pytest
import shapely
from conftest import sample_models

from bimgraph.bim.faces import Face, long_axis
from bimgraph.bim.ifc_import import import_ifc
from bimgraph.config import BimImportConfig
from bimgraph.geometry import inverse

MODELS = sample_models() or ["(no samples)"]
CFG = BimImportConfig()


@lru_cache(maxsize=None)
def imported(path, include_slabs=False):
    return import_ifc(path, CFG.model_copy(update={"include_slabs": include_slabs}), WARNINGS[path, include_slabs].append)[0]


WARNINGS = defaultdict(list)  # what each model's import warned about, by (path, include_slabs)


@lru_cache(maxsize=None)
def reference(path):
    """The model, T_B_W, and each wall's and space's mesh in B, by GlobalId, from
    ifcopenshell's default settings (openings subtracted)."""
    model = ifcopenshell.open(str(path))
    scale = ifcopenshell.util.unit.calculate_unit_scale(model)
    T_W_B = ifcopenshell.util.placement.get_local_placement(model.by_type("IfcBuilding")[0].ObjectPlacement)
    T_W_B[:3, 3] *= scale
    T_B_W = inverse(T_W_B)
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    meshes = {}
    elements = model.by_type("IfcWall") + model.by_type("IfcSpace") + model.by_type("IfcSlab")
    iterator = ifcopenshell.geom.iterator(settings, model, 2, include=elements)
    assert iterator.initialize()
    while True:
        shape = iterator.get()
        V = ifcopenshell.util.shape.get_vertices(shape.geometry) @ T_B_W[:3, :3].T + T_B_W[:3, 3]
        meshes[shape.guid] = (V, ifcopenshell.util.shape.get_faces(shape.geometry))
        if not iterator.next():
            break
    return model, T_B_W, meshes


def inside(V, T, points):
    """Whether each point is inside a closed triangle mesh (open3d counts ray crossings, so
    the winding of the triangles does not matter)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(V, dtype=np.float32)), o3d.core.Tensor(np.asarray(T, dtype=np.uint32)))
    return scene.compute_occupancy(o3d.core.Tensor(np.asarray(points, dtype=np.float32))).numpy() > 0.5


def section_frame(section):
    face = Face(np.asarray(section.normal), section.offset, None)
    polygon = shapely.Polygon(face.to_2d(np.array(section.polygon)), [face.to_2d(np.array(h)) for h in section.holes])
    return face, polygon


@pytest.fixture(params=MODELS)
def model_path(request, ifc_samples):
    return ifc_samples / request.param


def test_import_succeeds_with_unit_horizontal_normals(model_path):
    """Without a warning: the samples are sound files, whose every wall body the schema
    reader or the kernel reads (none left to the kernel after the schema reader failed)."""
    plane_map = imported(model_path)
    model = reference(model_path)[0]
    assert plane_map.faces and WARNINGS[model_path, False] == []
    assert {f.wall_guid for f in plane_map.faces} <= {w.GlobalId for w in model.by_type("IfcWall")}
    normals = np.array([f.normal for f in plane_map.faces])
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    assert np.abs(normals[:, 2]).max() < 1e-9
    for f in plane_map.faces:
        points = np.vstack([f.polygon, *f.holes])
        assert np.abs(points @ f.normal + f.offset).max() < 1e-6, f.id
        assert f.area >= CFG.min_face_area_m2


def test_normals_point_out_of_their_own_wall(model_path):
    """5 cm in front of a point inside each section is outside the wall's solid (openings
    subtracted), 5 cm behind it inside."""
    plane_map = imported(model_path)
    _, _, meshes = reference(model_path)
    for section in plane_map.faces:
        face, polygon = section_frame(section)
        p = face.to_3d(np.asarray(polygon.representative_point().coords))[0]
        V, T = meshes[section.wall_guid]
        front, back = inside(V, T, np.array([p + 0.05 * face.normal, p - 0.05 * face.normal]))
        assert not front and back, f"{section.id} ({section.wall_name}): inside in front {front}, behind {back}"


def visible_fraction(V, T, side, guid, meshes, walls, rng, samples=4000):
    """(fraction, its standard error) of the side triangles `side` of wall `guid` (one plane)
    not hidden by another wall along them: random points on the triangles, pushed out of the
    wall (whichever way OpenCASCADE wound them) by `lining_gap_m`, inside the solid of a wall
    (of `walls`, GlobalIds) whose long axis is parallel to the plane."""
    A, B, C = (V[T[side, k]] for k in range(3))
    cross = np.cross(B - A, C - A)
    weights = np.linalg.norm(cross, axis=1)
    pick = rng.choice(len(A), samples, p=weights / weights.sum())
    r1, r2 = np.sqrt(rng.random((samples, 1))), rng.random((samples, 1))
    points = (1 - r1) * A[pick] + r1 * (1 - r2) * B[pick] + r1 * r2 * C[pick]
    normal = cross[0] / np.linalg.norm(cross[0])
    if inside(V, T, points + CFG.lining_gap_m * normal).mean() > 0.5:
        normal = -normal
    points = points + CFG.lining_gap_m * normal
    hidden = np.zeros(samples, dtype=bool)
    for other, (V2, T2) in meshes.items():
        parallel = other != guid and other in walls and abs(long_axis(V2) @ normal) < np.sin(np.radians(CFG.axis_tol_deg))
        if parallel and (points.max(axis=0) > V2.min(axis=0)).all() and (points.min(axis=0) < V2.max(axis=0)).all():
            hidden |= inside(V2, T2, points)
    p = 1 - hidden.mean()
    return p, np.sqrt(max(p * (1 - p), 1 / samples) / samples)


def test_side_face_area_and_count_agree_with_the_triangulated_walls(model_path):
    """Independently: side faces are the vertical triangles of the wall (openings subtracted
    by OpenCASCADE) whose normal is across the wall's long axis, grouped by plane, less what
    another wall along them hides (Duplex's furring over its party walls)."""
    plane_map = imported(model_path)
    model, _, meshes = reference(model_path)
    walls = {w.GlobalId for w in model.by_type("IfcWall")}  # (reference() meshes slabs and spaces too)
    rng = np.random.default_rng(0)
    ours = {}
    for f in plane_map.faces:
        ours.setdefault(f.wall_guid, []).append(f)
    checked = 0
    for guid, (V, T) in meshes.items():
        if guid not in ours:
            continue
        cross = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
        area = np.linalg.norm(cross, axis=1) / 2
        n = cross / np.maximum(2 * area, 1e-300)[:, None]
        side = (np.abs(n[:, 2]) < 1e-3) & (np.abs(n @ long_axis(V)) < 1e-3) & (area > 0)
        centroids = V[T[side]].mean(axis=1)
        keys = np.round(np.column_stack([n[side][:, :2], -np.sum(n[side] * centroids, axis=1)]), 3)
        planes, spread = {}, 0.0
        for key in set(map(tuple, keys)):
            on_plane = np.flatnonzero(side)[(keys == key).all(axis=1)]
            fraction, error = visible_fraction(V, T, on_plane, guid, meshes, walls, rng)
            planes[key] = area[on_plane].sum() * fraction
            spread += (area[on_plane].sum() * error) ** 2 if fraction < 1 else 0.0
        planes = {k: a for k, a in planes.items() if a >= CFG.min_face_area_m2}
        our_planes = {tuple(np.round([*f.normal[:2], f.offset], 3)) for f in ours[guid]}
        our_area = sum(f.area for f in ours[guid])
        assert len(our_planes) == len(planes), f"wall {guid}: {sorted(our_planes)} against {sorted(planes)}"
        assert our_area == pytest.approx(sum(planes.values()), rel=1e-3, abs=0.01 + 4 * np.sqrt(spread)), f"wall {guid}"
        checked += 1
    assert checked >= len(ours) * 0.9, f"only {checked} of {len(ours)} walls had a long axis to check"


def _extruded_line(surface):
    """An IfcSurfaceOfLinearExtrusion of an open polyline (Duplex's boundaries, which
    ifcopenshell's create_shape does not take), from the schema's definition: the line swept
    along the direction by the depth, one quad per segment. (Vertices in file units, in the
    space's coordinates; the importer reads them through its own code.)"""
    curve = surface.SweptCurve
    if not curve.is_a("IfcArbitraryOpenProfileDef") or not curve.Curve.is_a("IfcPolyline"):
        return None
    line = np.array([p.Coordinates for p in curve.Curve.Points], dtype=float)
    line = np.hstack([line, np.zeros((len(line), 3 - line.shape[1]))])
    direction = np.asarray(surface.ExtrudedDirection.DirectionRatios, dtype=float)
    M = ifcopenshell.util.placement.get_axis2placement(surface.Position)
    V = np.vstack([line, line + direction / np.linalg.norm(direction) * surface.Depth]) @ M[:3, :3].T + M[:3, 3]
    n = len(line)
    T = [t for i in range(n - 1) for t in ([i, i + 1, n + i + 1], [i, n + i + 1, n + i])]
    return V, np.array(T)


def _bounded_plane(surface):
    """An IfcCurveBoundedPlane with a polyline outer boundary (ExternalEarth's, which
    create_shape returns empty), from the schema's definition: the loop in the basis
    plane's placement, triangulated in that plane."""
    loop = surface.OuterBoundary
    if not loop.is_a("IfcPolyline"):
        return None
    points = np.array([p.Coordinates for p in loop.Points], dtype=float)[:, :2]
    triangles = shapely.get_coordinates(shapely.constrained_delaunay_triangles(shapely.Polygon(points))).reshape(-1, 4, 2)[:, :3]
    M = ifcopenshell.util.placement.get_axis2placement(surface.BasisSurface.Position)
    flat = triangles.reshape(-1, 2)
    V = np.hstack([flat, np.zeros((len(flat), 1))]) @ M[:3, :3].T + M[:3, 3]
    return V, np.arange(len(V)).reshape(-1, 3)


def boundary_regions(model, T_B_W, path):
    """(space guid, wall guid, boundary points in B, triangles) of every surface space
    boundary on a wall, and how many of those could not be made into triangles."""
    settings = ifcopenshell.geom.settings()
    scale = ifcopenshell.util.unit.calculate_unit_scale(model)
    out, failed = [], 0
    for rel in model.by_type("IfcRelSpaceBoundary"):
        wall, geometry = rel.RelatedBuildingElement, rel.ConnectionGeometry
        if wall is None or not wall.is_a("IfcWall") or geometry is None or not geometry.is_a("IfcConnectionSurfaceGeometry"):
            continue
        surface = geometry.SurfaceOnRelatingElement
        try:
            shape = ifcopenshell.geom.create_shape(settings, surface)
            V, T = ifcopenshell.util.shape.get_vertices(shape), ifcopenshell.util.shape.get_faces(shape)
        except RuntimeError:
            V = ()
        if len(V) == 0:
            own = {"IfcSurfaceOfLinearExtrusion": _extruded_line, "IfcCurveBoundedPlane": _bounded_plane}.get(surface.is_a())
            made = own(surface) if own is not None else None
            if made is None:
                failed += 1
                continue
            V, T = made[0] * scale, made[1]
        T_W_S = ifcopenshell.util.placement.get_local_placement(rel.RelatingSpace.ObjectPlacement)
        T_W_S[:3, 3] *= scale
        T_B_S = T_B_W @ T_W_S
        out.append((rel.RelatingSpace.GlobalId, wall.GlobalId, V @ T_B_S[:3, :3].T + T_B_S[:3, 3], T))
    return out, failed


def test_sections_agree_with_space_boundaries(model_path):
    """Where a model's space boundary lies on one of our wall faces (ArchiCAD), or inside the
    wall parallel to a face whose front is in the boundary's room (Revit's centre-line
    boundaries), the section under it belongs to that boundary's room."""
    plane_map = imported(model_path)
    model, T_B_W, meshes = reference(model_path)
    by_wall = {}
    for f in plane_map.faces:
        by_wall.setdefault(f.wall_guid, []).append(f)
    checked, missed = 0, []
    boundaries, failed = boundary_regions(model, T_B_W, model_path)
    assert failed <= 0.1 * (failed + len(boundaries)), f"{failed} boundaries on walls could not be triangulated"
    for space, wall, V, T in boundaries:
        planes = {tuple(f.plane): f for f in by_wall.get(wall, [])}
        for f in planes.values():
            distance = V @ f.normal + f.offset
            face, _ = section_frame(f)
            region = shapely.union_all(shapely.polygons(face.to_2d(V[T])))
            if np.abs(distance).max() > CFG.boundary_on_face_m:
                behind = distance.max() < 0 and any(np.dot(g.normal, f.normal) < -0.999 and
                                                    (V @ g.normal + g.offset).max() < 0 for g in planes.values())
                if not behind or space not in meshes:
                    continue
                probe = face.to_3d(np.asarray(region.representative_point().coords)) + 0.1 * face.normal
                if not inside(*meshes[space], probe)[0]:
                    continue  # the room is on the other side of the wall
            mine = [s for s in by_wall[wall] if np.allclose(s.plane, f.plane)]
            covered = {s.id: section_frame(s)[1].intersection(region).area for s in mine}
            best = max(mine, key=lambda s: covered[s.id])
            if covered[best.id] < 0.5 * sum(covered.values()) or sum(covered.values()) < 0.1 * region.area:
                missed.append(best.id)  # no section under most of the boundary
                continue
            assert best.space is not None and best.space.guid == space, f"{best.id}: {best.space} under a boundary of {space}"
            checked += 1
    assert checked >= 0.9 * (checked + len(missed)), f"{len(missed)} boundaries over no section: {missed}"
    assert checked > 0 or not boundaries


def test_every_room_section_faces_its_room(model_path):
    """10 cm in front of some point of every section that names a room lies inside that
    room's solid (independent of how the section was split)."""
    plane_map = imported(model_path)
    _, _, meshes = reference(model_path)
    rng = np.random.default_rng(0)
    wrong, checked = [], 0
    for section in plane_map.faces:
        if section.space is None or section.space.guid not in meshes:
            continue
        checked += 1
        face, polygon = section_frame(section)
        u0, v0, u1, v1 = polygon.bounds
        samples = rng.uniform([u0, v0], [u1, v1], size=(400, 2))
        samples = samples[shapely.contains_xy(polygon, samples[:, 0], samples[:, 1])]
        V, T = meshes[section.space.guid]
        if not inside(V, T, face.to_3d(samples) + 0.1 * face.normal).any():
            wrong.append(section.id)
    assert not wrong, f"sections not facing their room: {wrong}"
    spaces = ifcopenshell.open(str(model_path)).by_type("IfcSpace")
    assert checked > 0 or not spaces


def test_slab_faces_are_horizontal_and_face_out_of_their_slab(model_path):
    plane_map = imported(model_path, include_slabs=True)
    _, _, meshes = reference(model_path)
    walls = [f for f in plane_map.faces if f.kind == "wall"]
    assert [f.id for f in walls] == [f.id for f in imported(model_path).faces]
    slabs = [f for f in plane_map.faces if f.kind != "wall"]
    assert {f.kind for f in slabs} == {"slab_top", "slab_bottom"}
    for section in slabs:
        assert section.normal == (0.0, 0.0, 1.0 if section.kind == "slab_top" else -1.0)
        face, polygon = section_frame(section)
        p = face.to_3d(np.asarray(polygon.representative_point().coords))[0]
        V, T = meshes[section.wall_guid]
        depth = min(0.05, np.ptp(V[:, 2]) / 2)  # thin slabs too
        front, back = inside(V, T, np.array([p + depth * face.normal, p - depth * face.normal]))
        assert not front and back, f"{section.id} ({section.wall_name})"
