"""A model with known geometry, written with ifcopenshell.api, re-extracted by the importer."""

import json
import os

import numpy as np
import pytest
import shapely
from typer.testing import CliRunner

from bimgraph.bim.building import Building, Opening, Space, Storey, Wall
from bimgraph.bim.faces import Face
from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_write import edge_on_wall_face, write_ifc
from bimgraph.bim.planemap import load_plane_map
from bimgraph.cli import app
from bimgraph.config import BimImportConfig
from bimgraph.errors import InputError

T, t, H = 0.3, 0.2, 3.0  # outer and inner wall thickness, storey height


def house() -> Building:
    """Two storeys, 10 x 6 m: downstairs a kitchen and a living room either side of an inner
    wall with a door, upstairs a loft; windows in the outer walls, a front door."""
    storeys = [Storey("Ground", 0.0, H), Storey("Upper", H, H)]
    walls = []
    for k in range(2):
        window = (Opening(1.0, 1.2, 1.4, 0.9, "window"),)
        front_door = (Opening(6.0, 1.0, 2.1, 0.0, "door"),) if k == 0 else ()
        walls += [
            Wall(f"S{k}", (-T / 2, 0.0), (10 + T / 2, 0.0), T, H, k, window + front_door),
            Wall(f"E{k}", (10.0, T / 2), (10.0, 6 - T / 2), T, H, k, window),
            Wall(f"N{k}", (10 + T / 2, 6.0), (-T / 2, 6.0), T, H, k, (Opening(2.0, 1.5, 1.2, 1.0, "window"),)),
            Wall(f"W{k}", (0.0, 6 - T / 2), (0.0, T / 2), T, H, k),
        ]
    walls.append(Wall("I0", (5.0, T / 2), (5.0, 6 - T / 2), t, H, 0, (Opening(2.0, 0.9, 2.1, 0.0, "door"),)))
    a, b = T / 2, 6 - T / 2
    spaces = [Space("Kitchen", ((a, a), (5 - t / 2, a), (5 - t / 2, b), (a, b)), 0),
              Space("Living", ((5 + t / 2, a), (10 - a, a), (10 - a, b), (5 + t / 2, b)), 0),
              Space("Loft", ((a, a), (10 - a, a), (10 - a, b), (a, b)), 1)]
    return Building("House", storeys, walls, spaces)


def expected_faces(building: Building):
    """{(wall name, side): (normal, offset, region in the face frame)} for both side faces."""
    out = {}
    for wall in building.walls:
        start, end = np.asarray(wall.start), np.asarray(wall.end)
        length = np.linalg.norm(end - start)
        x = (end - start) / length
        left = np.array([-x[1], x[0], 0.0])
        z0 = building.storeys[wall.storey].elevation
        for side in (1, -1):
            normal = side * left
            on_face = np.append(start, 0.0) + side * wall.thickness / 2 * left
            face = Face(normal, -float(normal @ on_face), None)

            def rect(along, width, bottom, height):
                corners = np.array([[along, bottom], [along + width, bottom], [along + width, bottom + height]])
                p = np.append(start, 0.0) + side * wall.thickness / 2 * left
                uv = face.to_2d(p + corners[:, :1] * np.append(x, 0.0) + corners[:, 1:] * [0, 0, 1])
                return shapely.box(*uv.min(axis=0), *uv.max(axis=0))

            region = rect(0.0, length, z0, wall.height)
            for o in wall.openings:
                region = region.difference(rect(o.along, o.width, z0 + o.sill, o.height))
            out[(wall.name, side)] = (face, region)
    return out


def edited_house(path, edit, **write_args):
    """The house written to `path`, then `edit(model)` applied to it; returns the edited model."""
    import ifcopenshell

    write_ifc(house(), path, **write_args)
    model = ifcopenshell.open(str(path))
    edit(model)
    model.write(str(path))
    return model


def add_opening(model, wall, T_W_opening, context, **box):
    """An IfcOpeningElement voiding `wall`, placed at `T_W_opening`: a box (`length` along its
    x, `height` up, across its y from `offset` to `offset + thickness`)."""
    import ifcopenshell.api.feature
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root

    opening = ifcopenshell.api.root.create_entity(model, ifc_class="IfcOpeningElement", name="opening")
    ifcopenshell.api.geometry.edit_object_placement(model, product=opening, matrix=T_W_opening)
    representation = ifcopenshell.api.geometry.add_wall_representation(model, context=context, **box)
    ifcopenshell.api.geometry.assign_representation(model, product=opening, representation=representation)
    ifcopenshell.api.feature.add_feature(model, feature=opening, element=wall)


def wall_named(model, name):
    return next(w for w in model.by_type("IfcWall") if w.Name == name)


def body_of(element):
    return next(r for r in element.Representation.Representations if r.RepresentationIdentifier == "Body")


@pytest.fixture(scope="module", params=[("IFC4", "m"), ("IFC4", "mm"), ("IFC2X3", "m"), ("IFC2X3", "mm")],
                ids=lambda p: f"{p[0]}-{p[1]}")
def written(request, tmp_path_factory):
    schema, unit = request.param
    path = tmp_path_factory.mktemp("house") / f"house_{schema}_{unit}.ifc"
    write_ifc(house(), path, schema=schema, length_unit=unit)
    return path


@pytest.fixture(scope="module")
def imported(written):
    return import_ifc(written, BimImportConfig())[0]


def test_written_models_are_valid_ifc(written):
    import ifcopenshell
    import ifcopenshell.validate

    logger = ifcopenshell.validate.json_logger()
    ifcopenshell.validate.validate(ifcopenshell.open(str(written)), logger, express_rules=False)
    assert logger.statements == []


def test_every_face_is_re_extracted_within_1mm_and_001deg(imported):
    building = house()
    expected = expected_faces(building)
    found = {}
    for section in imported.faces:
        n = np.asarray(section.normal)
        matches = [key for key, (face, _) in expected.items()
                   if key[0] == section.wall_name and np.degrees(np.arccos(np.clip(n @ face.normal, -1, 1))) < 0.01]
        assert len(matches) == 1, f"{section.id}: normal {n} matches {matches}"
        face, region = expected[matches[0]]
        assert abs(section.offset - face.offset) < 1e-3
        polygon = shapely.Polygon(face.to_2d(np.array(section.polygon)), [face.to_2d(np.array(h)) for h in section.holes])
        found.setdefault(matches[0], []).append(polygon)
    assert set(found) == set(expected), "every side face of every wall, nothing else"
    for key, polygons in found.items():
        union = shapely.union_all(polygons)
        region = expected[key][1]
        assert union.hausdorff_distance(region) < 1e-3, key
        assert abs(union.area - region.area) < 1e-3 * region.length, key
        assert abs(sum(p.area for p in polygons) - region.area) < 1e-3 * region.length, f"{key}: sections overlap"


def test_every_section_knows_its_room(imported):
    """A section belongs to the room it faces, it covers that room's whole stretch of the
    face, and a face with no room in front (outside) has no room."""
    building = house()
    for section in imported.faces:
        wall = next(w for w in building.walls if w.name == section.wall_name)
        n = np.asarray(section.normal)
        rooms = []
        for space in building.spaces:
            if space.storey != wall.storey:
                continue
            footprint = np.asarray(space.footprint)
            for a, b in zip(footprint, np.roll(footprint, -1, axis=0)):
                stretch = edge_on_wall_face(a, b, wall)
                if stretch is not None and np.dot(np.append(stretch[0], 0.0), n) + section.offset == pytest.approx(0, abs=1e-6):
                    rooms.append((space.name, stretch))
        face = Face(n, section.offset, None)
        polygon = shapely.Polygon(face.to_2d(np.array(section.polygon)))
        mine = [(name, stretch) for name, stretch in rooms if section.space and name == section.space.name]
        if not rooms:
            assert section.space is None and section.split == "none", section.id
            continue
        assert len(mine) == 1, f"{section.id} ({section.space}) is not in front of any of {[r[0] for r in rooms]}"
        assert section.split == "space_boundary"
        u = face.to_2d(np.column_stack([np.array(mine[0][1]), [0.0, 0.0]]))[:, 0]
        assert polygon.bounds[0] <= u.min() + 1e-6 and polygon.bounds[2] >= u.max() - 1e-6
    names = {(s.wall_name, s.space.name if s.space else None) for s in imported.faces}
    assert {("S0", "Kitchen"), ("S0", "Living"), ("S0", None), ("I0", "Kitchen"), ("I0", "Living"),
            ("S1", "Loft")} <= names


def test_storeys_and_elevations(imported):
    for section in imported.faces:
        storey = section.wall_name[-1]
        assert (section.storey, section.elevation) == (("Ground", 0.0) if storey == "0" else ("Upper", pytest.approx(H)))


def write_no_walls(path):
    write_ifc(Building("Empty", [Storey("Ground", 0.0, H)]), path)


@pytest.mark.parametrize("case", ["text", "truncated", "no_walls", "missing"])
def test_bad_input_is_one_line_error(case, tmp_path):
    model = tmp_path / "model.ifc"
    if case == "text":
        model.write_text("this is not an IFC file\n")
    elif case == "truncated":
        write_ifc(house(), model)
        data = model.read_bytes()
        model.write_bytes(data[: len(data) // 2])
    elif case == "no_walls":
        write_no_walls(model)
    with pytest.raises(InputError):
        import_ifc(model if case != "missing" else tmp_path / "absent.ifc", BimImportConfig())
    result = CliRunner().invoke(app, ["bim", str(model), "-o", str(tmp_path / "planes.json")])
    assert result.exit_code != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), result.stderr
    assert "Traceback" not in result.output
    assert not (tmp_path / "planes.json").exists()


def test_cli_writes_a_valid_plane_map(tmp_path):
    model = tmp_path / "house.ifc"
    write_ifc(house(), model, schema="IFC2X3", length_unit="mm")
    result = CliRunner().invoke(app, ["bim", str(model), "-o", str(tmp_path / "planes.json")])
    assert result.exit_code == 0, result.output
    plane_map = load_plane_map(tmp_path / "planes.json")
    assert len(plane_map.faces) == 20
    assert json.loads((tmp_path / "planes.json").read_text())["format"] == "bimgraph.planemap"


def test_georeferenced_model_keeps_building_coordinates(tmp_path):
    """A site placed millions of metres from the project origin (as georeferenced Revit
    exports are): B is the building's frame, faces come out as without the offset, and
    T_W_B says where B is."""
    import ifcopenshell
    import ifcopenshell.api.geometry

    path = tmp_path / "geo.ifc"
    write_ifc(house(), path, schema="IFC4", length_unit="mm")
    model = ifcopenshell.open(str(path))
    offset = np.array([512345.678, 5432109.876, 250.0])
    T_W_site = np.eye(4)
    T_W_site[:3, 3] = offset
    ifcopenshell.api.geometry.edit_object_placement(model, product=model.by_type("IfcSite")[0], matrix=T_W_site,
                                                    should_transform_children=True)
    model.write(str(path))
    plane_map, _ = import_ifc(path, BimImportConfig())
    assert np.allclose(plane_map.T_W_B[:3], offset, atol=1e-6)
    expected = expected_faces(house())
    for section in plane_map.faces:
        face = next(f for (name, _), (f, _) in expected.items()
                    if name == section.wall_name and np.dot(f.normal, section.normal) > 0.9999)
        assert abs(section.offset - face.offset) < 1e-3
        assert np.abs(np.asarray(section.polygon) @ face.normal + face.offset).max() < 1e-3


def test_model_without_rooms_is_split_at_wall_junctions(tmp_path):
    building = house()
    building.spaces = []
    path = tmp_path / "no_rooms.ifc"
    write_ifc(building, path)
    plane_map, _ = import_ifc(path, BimImportConfig())
    split = {}
    for section in plane_map.faces:
        assert section.space is None
        split.setdefault((section.wall_name, tuple(np.round(section.normal, 6))), []).append(section)
    # The ground floor's south wall meets the inner wall (axis x = 5) on its inside only.
    inside = sorted(split[("S0", (0.0, 1.0, 0.0))], key=lambda s: s.centre[0])
    assert [s.split for s in inside] == ["junction", "junction"]
    assert max(p[0] for p in inside[0].polygon) == pytest.approx(5.0, abs=1e-6)
    assert min(p[0] for p in inside[1].polygon) == pytest.approx(5.0, abs=1e-6)
    assert [s.split for s in split[("S0", (0.0, -1.0, 0.0))]] == ["none"]
    assert [s.split for s in split[("S1", (0.0, 1.0, 0.0))]] == ["none"]
    assert len(plane_map.faces) == 2 * len(building.walls) + 2


def test_wall_without_geometry_is_warned_about_and_skipped(tmp_path):
    path = tmp_path / "broken.ifc"

    def no_height(model):  # an extrusion of no height has no geometry
        body_of(wall_named(model, "E0")).Items[0].Depth = 0.0

    wall = wall_named(edited_house(path, no_height), "E0")
    messages = []
    plane_map, _ = import_ifc(path, BimImportConfig(), log=messages.append)
    assert len(messages) == 1 and wall.GlobalId in messages[0] and "skipped" in messages[0]
    assert "E0" not in {f.wall_name for f in plane_map.faces}
    assert len(plane_map.faces) == 18  # the other 8 walls, the south and north ones split in two rooms
    result = CliRunner().invoke(app, ["bim", str(path), "-o", str(tmp_path / "planes.json")])
    assert result.exit_code == 0 and "skipped" in result.stderr


def test_triangles_wound_either_way_are_oriented_outward():
    """Tessellated walls (surface models) come with triangles wound at random."""
    from bimgraph.bim.faces import orient_outward

    V = np.array([[x, y, z] for x in (0.0, 4.0) for y in (0.0, 0.3) for z in (0.0, 3.0)])
    # A box as 12 triangles, each wound outward (checked by the volume below).
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    T = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])

    def volume_of(V, T):
        return np.einsum("ij,ij->", V[T[:, 0]], np.cross(V[T[:, 1]], V[T[:, 2]])) / 6

    assert volume_of(V, T) == pytest.approx(3.6)
    rng = np.random.default_rng(0)
    for _ in range(20):
        mixed = T.copy()
        flip = rng.random(len(T)) < 0.5
        mixed[flip] = mixed[flip, ::-1]
        fixed = orient_outward(V, mixed)
        assert volume_of(V, fixed) == pytest.approx(3.6)
        assert np.array_equal(np.sort(fixed, axis=1), np.sort(T, axis=1))
    # Two separate boxes, one of them inside out: each part is oriented on its own.
    two = np.vstack([T, T[:, ::-1] + 8])
    V2 = np.vstack([V, V + [10.0, 0.0, 0.0]])
    assert volume_of(V2, orient_outward(V2, two)) == pytest.approx(7.2)


def test_internal_layer_faces_are_not_faces(tmp_path):
    """A wall built as two layers (two extrusions touching inside the wall) has the faces of
    the one-piece wall: the interface between the layers faces both ways and is no face."""
    import ifcopenshell.api.geometry

    path = tmp_path / "layers.ifc"

    def two_layers(model):
        body = body_of(wall_named(model, "W0"))
        layers = [ifcopenshell.api.geometry.add_wall_representation(
            model, context=body.ContextOfItems, length=6 - T, height=H, thickness=thickness, offset=offset)
            for thickness, offset in ((0.1, -T / 2), (T - 0.1, -T / 2 + 0.1))]
        body.Items = [layer.Items[0] for layer in layers]

    edited_house(path, two_layers, length_unit="mm")
    plane_map, _ = import_ifc(path, BimImportConfig())
    faces = [f for f in plane_map.faces if f.wall_name == "W0"]
    assert sorted(f.offset for f in faces) == pytest.approx([-T / 2, -T / 2])  # x = -0.15 and x = 0.15
    assert sum(f.area for f in faces) == pytest.approx(2 * (6 - T) * H)


def test_components_agree_with_scipy():
    """faces._components is a fast path for small meshes; it must partition as scipy does,
    long chains (which fall back to scipy) included."""
    import scipy.sparse
    import scipy.sparse.csgraph

    from bimgraph.bim.faces import _components

    rng = np.random.default_rng(0)
    graphs = [(n, rng.integers(0, n, size=(rng.integers(0, 2 * n), 2))) for n in rng.integers(1, 60, size=300)]
    graphs.append((500, np.stack([np.arange(499), np.arange(1, 500)], axis=1)))  # one long chain
    for n, edges in graphs:
        i, j = edges[:, 0], edges[:, 1]
        count, labels = _components(n, i, j)
        expected_count, expected = scipy.sparse.csgraph.connected_components(
            scipy.sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)), directed=False)
        assert count == expected_count
        # Same partition up to numbering: the sets of nodes per label are the same sets.
        def partition(labels):
            return {frozenset(np.flatnonzero(labels == label)) for label in np.unique(labels)}
        assert partition(np.asarray(labels)) == partition(expected)


def test_odd_but_valid_placements_and_a_degenerate_opening(tmp_path):
    """IFC allows a RefDirection not perpendicular to its Axis (its projection is the x axis),
    an element without ObjectPlacement (the world frame), and an opening's extrusion may be
    broken: the house comes out the same, the opening warned about."""
    import ifcopenshell

    path = tmp_path / "odd.ifc"
    write_ifc(house(), path)
    reference, _ = import_ifc(path, BimImportConfig())
    model = ifcopenshell.open(str(path))
    building = model.by_type("IfcBuilding")[0]
    building.ObjectPlacement.RelativePlacement.RefDirection = model.createIfcDirection((1.0, 0.0, 0.3))
    model.by_type("IfcBuildingStorey")[0].ObjectPlacement = None  # (the ground storey sits at the origin)
    opening = next(o for o in model.by_type("IfcOpeningElement") if o.VoidsElements[0].RelatingBuildingElement.Name == "I0")
    next(r for r in opening.Representation.Representations).Items[0].ExtrudedDirection = model.createIfcDirection((0.0, 0.0, 0.0))
    model.write(str(path))
    messages = []
    plane_map, _ = import_ifc(path, BimImportConfig(), log=messages.append)
    assert plane_map.T_W_B is None or np.allclose(plane_map.T_W_B[3:], [0, 0, 0, 1], atol=1e-9)
    assert len(plane_map.faces) == len(reference.faces)
    assert len(messages) == 1 and opening.GlobalId in messages[0]
    by_id = {f.id: f for f in reference.faces}
    for f in plane_map.faces:
        assert np.allclose(f.plane, by_id[f.id].plane, atol=1e-9)
        # the inner wall's door is not cut without its geometry: its faces keep the area
        assert f.area >= by_id[f.id].area - 1e-9


@pytest.mark.parametrize("target", ["folder", "under_a_file", "device"])
def test_an_output_that_cannot_be_written_is_one_line(tmp_path, target):
    model = tmp_path / "house.ifc"
    write_ifc(house(), model)
    (tmp_path / "a_file").write_text("")
    os.mkfifo(tmp_path / "fifo")  # (a special file: not /dev/null, which a broken writer would replace)
    out = {"folder": tmp_path, "under_a_file": tmp_path / "a_file" / "planes.json", "device": tmp_path / "fifo"}[target]
    result = CliRunner().invoke(app, ["bim", str(model), "-o", str(out)])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert len(result.stderr.strip().splitlines()) == 1 and str(out) in result.stderr
    assert not list(tmp_path.glob("*.tmp")) and (tmp_path / "a_file").read_text() == ""


# Wall E0's box in its own frame (x along it, y across, z up), as quads wound outward: its two
# ends and two sides, without top or bottom, so that it is an open surface.
BOX = [[x, y, z] for x in (0.0, 6 - T) for y in (-T / 2, T / 2) for z in (0.0, H)]
BOX_SIDES_AND_ENDS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6)]


def open_surface(model, kind, quads):
    """An item of representation `kind` made of the `quads` of BOX."""
    if kind in ("triangulated", "triangulated_unflagged"):
        triangles = [[i + 1 for i in t] for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
        closed = False if kind == "triangulated" else None
        return model.createIfcTriangulatedFaceSet(model.createIfcCartesianPointList3D(BOX), None, closed, triangles)
    if kind == "polygonal":
        return model.createIfcPolygonalFaceSet(model.createIfcCartesianPointList3D(BOX), False,
                                               [model.createIfcIndexedPolygonalFace([i + 1 for i in q]) for q in quads])
    points = [model.createIfcCartesianPoint(p) for p in BOX]
    faces = [model.createIfcFace([model.createIfcFaceOuterBound(model.createIfcPolyLoop([points[i] for i in q]), True)])
             for q in quads]
    if kind == "surface_model":
        return model.createIfcShellBasedSurfaceModel([model.createIfcOpenShell(faces)])
    return model.createIfcFacetedBrep(model.createIfcClosedShell(faces))  # a "closed" shell that is not


@pytest.mark.parametrize("winding", ["inward", "mixed"])
@pytest.mark.parametrize("kind", ["triangulated", "triangulated_unflagged", "polygonal", "surface_model", "faceted_brep"])
def test_open_tessellated_wall_faces_out_whatever_its_winding(tmp_path, kind, winding):
    """A wall given as an open surface (a face set not Closed, a surface model, a brep whose
    shell lacks faces), its triangles wound inward or each face either way: it encloses no
    volume to be oriented by, yet its faces point out of the wall as the extrusion's do."""
    write_ifc(house(), tmp_path / "reference.ifc")
    reference, _ = import_ifc(tmp_path / "reference.ifc", BimImportConfig())
    quads = [q[::-1] if winding == "inward" or k % 2 == 0 else q for k, q in enumerate(BOX_SIDES_AND_ENDS)]

    def tessellated(model):
        body_of(wall_named(model, "E0")).Items = [open_surface(model, kind, quads)]

    edited_house(tmp_path / "open.ifc", tessellated)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "open.ifc", BimImportConfig(), log=messages.append)
    assert messages == []

    def faces_of_E0(plane_map):
        return sorted((f.normal, round(f.offset, 6), round(f.area, 6)) for f in plane_map.faces if f.wall_name == "E0")

    # E0 runs along x = 10: its outer face is x = 10.15 (normal +x), its inner one x = 9.85
    assert [(n, d) for n, d, _ in faces_of_E0(plane_map)] == [((-1.0, 0.0, 0.0), 9.85), ((1.0, 0.0, 0.0), -10.15)]
    assert faces_of_E0(plane_map) == faces_of_E0(reference)


def test_open_surfaces_face_away_from_their_material():
    """orient_outward on a round wall's two sides alone (a ring: no top, bottom or ends), wound
    inward or at random: the outer side faces away from the centre, the inner one towards it
    (the material lies between them, not within the inner side)."""
    from bimgraph.bim.faces import orient_outward, triangle_normals

    n = 48
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    V = np.array([[r * np.cos(a), r * np.sin(a), z] for r in (2.0, 2.3) for z in (0.0, 3.0) for a in angles])
    k = np.arange(n)
    triangles = []
    for side, sign in ((0, -1), (1, 1)):  # inner: wound facing the centre, outer: away from it
        bottom, top = 2 * side * n + k, (2 * side + 1) * n + k
        quads = np.column_stack([bottom, np.roll(bottom, -1), np.roll(top, -1), top])
        quads = quads if sign > 0 else quads[:, ::-1]
        triangles += [quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]
    outward = np.vstack(triangles)
    rng = np.random.default_rng(0)
    for wound in (outward[:, ::-1], np.where(rng.random((len(outward), 1)) < 0.5, outward[:, ::-1], outward)):
        fixed = orient_outward(V, wound)
        normals, _ = triangle_normals(V, fixed)
        centres = V[fixed].mean(axis=1)
        radial = np.einsum("ij,ij->i", normals[:, :2], centres[:, :2] / np.linalg.norm(centres[:, :2], axis=1)[:, None])
        outer = np.linalg.norm(centres[:, :2], axis=1) > 2.15
        assert (radial[outer] > 0.99).all() and (radial[~outer] < -0.99).all()


@pytest.mark.parametrize("shape", ["sliver", "leaning"])
def test_wall_without_side_face_is_warned_about_and_skipped(tmp_path, shape):
    """A wall whose geometry gives no side face (a 1 x 1 cm sliver; a wall leaning 10 degrees,
    whose sides are not vertical) is warned about like one whose geometry fails."""
    import ifcopenshell.api.geometry

    def faceless(model):
        body = body_of(wall_named(model, "E0"))
        size = {"sliver": dict(length=0.01, thickness=0.01, offset=-0.005),
                "leaning": dict(length=6 - T, thickness=T, offset=-T / 2, x_angle=np.radians(10.0))}[shape]
        body.Items = ifcopenshell.api.geometry.add_wall_representation(
            model, context=body.ContextOfItems, height=H, **size).Items

    wall = wall_named(edited_house(tmp_path / "faceless.ifc", faceless), "E0")
    messages = []
    plane_map, _ = import_ifc(tmp_path / "faceless.ifc", BimImportConfig(), log=messages.append)
    assert len(messages) == 1 and wall.GlobalId in messages[0] and "(E0)" in messages[0]
    assert "no side face" in messages[0] and "skipped" in messages[0]
    assert "E0" not in {f.wall_name for f in plane_map.faces}
    assert len(plane_map.faces) == 18  # the other 8 walls, as when E0's geometry fails


def test_slab_without_faces_is_warned_about_and_skipped(tmp_path):
    """With include_slabs, a slab whose geometry fails (an extrusion of no depth) or that has
    no horizontal face (a roof sloped 30 degrees) is warned about and skipped like a wall; a
    flat one gives its top and bottom."""
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial

    from bimgraph.geometry import make_pose

    guids = {}
    a = np.radians(30.0)
    tilted = make_pose(np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]]), [0.0, 0.0, H])

    def slabs(model):
        context = body_of(wall_named(model, "E0")).ContextOfItems
        for name, T_W_slab in (("flat", make_pose(np.eye(3), [0.0, 0.0, H])), ("broken", np.eye(4)), ("sloped", tilted)):
            slab = ifcopenshell.api.root.create_entity(model, ifc_class="IfcSlab", name=name)
            ifcopenshell.api.spatial.assign_container(model, relating_structure=model.by_type("IfcBuildingStorey")[1],
                                                      products=[slab])
            ifcopenshell.api.geometry.edit_object_placement(model, product=slab, matrix=T_W_slab)
            representation = ifcopenshell.api.geometry.add_slab_representation(
                model, context=context, depth=0.2, polyline=[(0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)])
            if name == "broken":
                representation.Items[0].Depth = 0.0
            ifcopenshell.api.geometry.assign_representation(model, product=slab, representation=representation)
            guids[name] = slab.GlobalId

    edited_house(tmp_path / "slabs.ifc", slabs)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "slabs.ifc", BimImportConfig(include_slabs=True), log=messages.append)
    assert sorted(f.kind for f in plane_map.faces if f.kind != "wall") == ["slab_bottom", "slab_top"]
    assert {f.wall_name for f in plane_map.faces if f.kind != "wall"} == {"flat"}
    assert len(messages) == 2
    assert guids["broken"] in messages[0] and "(broken)" in messages[0] and "no geometry, skipped" in messages[0]
    assert guids["sloped"] in messages[1] and "(sloped)" in messages[1] and "no horizontal face" in messages[1]


@pytest.mark.parametrize("variant", ["mapped", "main_context", "no_identifier", "niche"])
def test_other_ways_to_write_walls(tmp_path, variant):
    """Walls as authoring tools also write them come out as the plain ones: a body and an axis
    only as IfcMappedItems, a body in the main model context, a body without identifier. An
    opening that does not cut through (a niche 20 cm deep into the 30 cm wall W0 from inside)
    is a hole in the face it opens only."""
    import ifcopenshell.util.placement

    from bimgraph.geometry import make_pose

    def mapped(model, representation):
        origin = model.createIfcAxis2Placement3D(model.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
        shared = model.createIfcShapeRepresentation(representation.ContextOfItems, representation.RepresentationIdentifier,
                                                    representation.RepresentationType, list(representation.Items))
        target = model.createIfcCartesianTransformationOperator3D(None, None, origin.Location, None, None)
        representation.Items = [model.createIfcMappedItem(model.createIfcRepresentationMap(origin, shared), target)]
        representation.RepresentationType = "MappedRepresentation"

    def edit(model):
        wall = wall_named(model, "W0")
        body = body_of(wall)
        if variant == "mapped":
            for representation in wall.Representation.Representations:
                mapped(model, representation)
        elif variant == "main_context":
            body.ContextOfItems = body.ContextOfItems.ParentContext
        elif variant == "no_identifier":
            body.RepresentationIdentifier = None
        else:
            T_W_wall = ifcopenshell.util.placement.get_local_placement(wall.ObjectPlacement)
            add_opening(model, wall, T_W_wall @ make_pose(np.eye(3), [2.0, 0.0, 1.0]), body.ContextOfItems,
                        length=1.0, height=1.0, thickness=0.21, offset=T / 2 - 0.2)

    write_ifc(house(), tmp_path / "reference.ifc")
    reference, _ = import_ifc(tmp_path / "reference.ifc", BimImportConfig())
    edited_house(tmp_path / "variant.ifc", edit)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "variant.ifc", BimImportConfig(), log=messages.append)
    assert messages == [] and len(plane_map.faces) == len(reference.faces)

    def key(face):  # GlobalIds are new in each file written
        return face.wall_name, face.id.split("/")[1]

    expected = {key(f): f for f in reference.faces}
    for face in plane_map.faces:
        plan = expected[key(face)]
        assert np.allclose(face.plane, plan.plane, atol=1e-9)
        niche = variant == "niche" and face.wall_name == "W0" and face.normal[0] > 0.5  # W0's inner face, x = 0.15
        assert face.area == pytest.approx(plan.area - (1.0 if niche else 0.0), abs=1e-6)
        assert len(face.holes) == len(plan.holes) + niche


def one_wall_model(path, profile, axis, schema="IFC4", length_unit="m"):
    """A model of one storey holding one wall "C0" (placed at the origin of B), as authoring
    tools write walls the house does not have: `profile(f, point, m)` and `axis(f, point, m)`
    make the curves of its body's profile (extruded H up) and of its axis in file `f`, with
    `point(x, y)` making a point and `m(x)` a length, both given in metres. Returns the model
    (unwritten), the wall and the representation contexts by identifier."""
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial

    s = 1000.0 if length_unit == "mm" else 1.0
    write_ifc(Building("One", [Storey("Ground", 0.0, H)], [], []), path, schema=schema, length_unit=length_unit)
    f = ifcopenshell.open(str(path))
    contexts = {c.ContextIdentifier: c for c in f.by_type("IfcGeometricRepresentationSubContext")}

    def m(x):
        return float(x * s)

    def point(x, y):
        return f.createIfcCartesianPoint((m(x), m(y)))

    solid = f.createIfcExtrudedAreaSolid(f.createIfcArbitraryClosedProfileDef("AREA", None, profile(f, point, m)),
                                         f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None),
                                         f.createIfcDirection((0.0, 0.0, 1.0)), H * s)
    wall = ifcopenshell.api.root.create_entity(f, ifc_class="IfcWall", name="C0")
    ifcopenshell.api.spatial.assign_container(f, relating_structure=f.by_type("IfcBuildingStorey")[0], products=[wall])
    ifcopenshell.api.geometry.edit_object_placement(f, product=wall, matrix=np.eye(4))
    for identifier, kind, item in (("Body", "SweptSolid", solid), ("Axis", "Curve2D", axis(f, point, m))):
        ifcopenshell.api.geometry.assign_representation(
            f, product=wall, representation=f.createIfcShapeRepresentation(contexts[identifier], identifier, kind, [item]))
    return f, wall, contexts


def test_bent_wall_has_no_end_faces(tmp_path):
    """An L-shaped wall (its axis a polyline of two segments at right angles): each leg's end
    faces along the other leg's axis, yet it is no side face; the four sides are."""
    def profile(f, point, m):
        corners = [(0, -T / 2), (4 + T / 2, -T / 2), (4 + T / 2, 3), (4 - T / 2, 3), (4 - T / 2, T / 2), (0, T / 2)]
        return f.createIfcPolyline([point(x, y) for x, y in corners + corners[:1]])

    def axis(f, point, m):
        return f.createIfcPolyline([point(0, 0), point(4, 0), point(4, 3)])

    one_wall_model(tmp_path / "bent.ifc", profile, axis)[0].write(str(tmp_path / "bent.ifc"))
    plane_map, _ = import_ifc(tmp_path / "bent.ifc", BimImportConfig())
    expected = [((-1.0, 0.0, 0.0), 4 - T / 2, (3 - T / 2) * H), ((0.0, -1.0, 0.0), -T / 2, (4 + T / 2) * H),
                ((0.0, 1.0, 0.0), -T / 2, (4 - T / 2) * H), ((1.0, 0.0, 0.0), -4 - T / 2, (3 + T / 2) * H)]
    found = sorted((tuple(np.round(f.normal, 9) + 0.0), f.offset, f.area) for f in plane_map.faces)
    assert [n for n, _, _ in found] == [n for n, _, _ in expected]
    assert np.allclose([(d, a) for _, d, a in found], [(d, a) for _, d, a in expected])


R_C = 5.0  # radius of the curved wall's axis


def write_curved_wall(path, profile: str, schema="IFC4", length_unit="m", opening=False):
    """A model of one wall along a quarter circle, as authoring tools write curved walls: its
    axis an IfcTrimmedCurve of an IfcCircle of radius R_C about the origin from angle 0 to 90
    degrees, its body an extruded arc-shaped profile T thick, `profile` "composite" (an
    IfcCompositeCurve of trimmed circles and polylines, as Revit writes it) or "indexed" (an
    IfcIndexedPolyCurve with IfcArcIndex segments, as ArchiCAD does); with `opening`, a
    window 1 m wide and 1.2 m high through it at 45 degrees."""
    from bimgraph.geometry import make_pose

    def arc(f, point, m, radius):  # angles in radians, the file's plane angle unit
        circle = f.createIfcCircle(f.createIfcAxis2Placement2D(point(0, 0), None), m(radius))
        return f.createIfcTrimmedCurve(circle, [f.createIfcParameterValue(0.0)], [f.createIfcParameterValue(np.pi / 2)],
                                       True, "PARAMETER")

    outer, inner = R_C + T / 2, R_C - T / 2

    def arc_profile(f, point, m):
        if profile == "composite":
            segments = [(arc(f, point, m, outer), True), (f.createIfcPolyline([point(0, outer), point(0, inner)]), True),
                        (arc(f, point, m, inner), False), (f.createIfcPolyline([point(inner, 0), point(outer, 0)]), True)]
            return f.createIfcCompositeCurve([f.createIfcCompositeCurveSegment("CONTINUOUS", sense, c)
                                              for c, sense in segments], False)
        c = np.cos(np.pi / 4)
        corners = [(outer, 0), (outer * c, outer * c), (0, outer), (0, inner), (inner * c, inner * c), (inner, 0)]
        return f.createIfcIndexedPolyCurve(
            f.createIfcCartesianPointList2D([(m(x), m(y)) for x, y in corners]),
            [f.create_entity("IfcArcIndex", (1, 2, 3)), f.create_entity("IfcLineIndex", (3, 4)),
             f.create_entity("IfcArcIndex", (4, 5, 6)), f.create_entity("IfcLineIndex", (6, 1))], False)

    f, wall, contexts = one_wall_model(path, arc_profile, lambda f, point, m: arc(f, point, m, R_C), schema, length_unit)
    if opening:
        # A box 0.6 m deep centred on the wall at 45 degrees: x along the wall, y toward the centre.
        a = np.pi / 4
        along, inward = np.array([-np.sin(a), np.cos(a), 0.0]), -np.array([np.cos(a), np.sin(a), 0.0])
        T_W_opening = make_pose(np.column_stack([along, inward, [0.0, 0.0, 1.0]]),
                                R_C * np.array([np.cos(a), np.sin(a), 0.0]) - 0.5 * along + [0.0, 0.0, 0.9])
        add_opening(f, wall, T_W_opening, contexts["Body"], length=1.0, height=1.2, thickness=0.6, offset=-0.3)
    f.write(str(path))


@pytest.mark.parametrize("profile, schema, unit", [("composite", "IFC4", "m"), ("composite", "IFC2X3", "mm"),
                                                   ("indexed", "IFC4", "m")])
def test_curved_wall_is_planar_facets_within_the_tolerance(tmp_path, profile, schema, unit):
    """A curved wall's sides become planar facets, none farther than curved_face_tol_m (1 cm,
    plus the kernel's 1 mm tessellation) from the true arc, covering it end to end, facing out
    of the wall; its ends are no side faces; a window through it is cut out of the facets."""
    cfg = BimImportConfig()
    tol = 0.01 + 0.001  # curved_face_tol_m's default
    write_curved_wall(tmp_path / "curved.ifc", profile, schema, unit)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "curved.ifc", cfg, log=messages.append)
    assert messages == []
    sides = {1.0: [f for f in plane_map.faces if np.hypot(*f.centre[:2]) > R_C + T / 2 - 2 * tol],
             -1.0: [f for f in plane_map.faces if np.hypot(*f.centre[:2]) < R_C - T / 2 + 2 * tol]}
    assert len(sides[1.0]) + len(sides[-1.0]) == len(plane_map.faces)  # the ends are no side faces
    for radius, side in ((R_C + T / 2, 1.0), (R_C - T / 2, -1.0)):
        facets = sides[side]
        # as few as the tolerance allows: a chord deviates 1 cm from an arc of 2 acos(1 - tol / r)
        fewest = np.ceil((np.pi / 2) / (2 * np.arccos(1 - 0.01 / radius)))
        assert fewest <= len(facets) <= 2 * fewest
        spans = []
        for face in facets:
            polygon = np.asarray(face.polygon)
            assert abs(face.normal[2]) < 1e-9 and np.abs(polygon @ face.normal + face.offset).max() < 1e-6
            angles = np.arctan2(polygon[:, 1], polygon[:, 0])
            spans.append((angles.min(), angles.max()))
            arc = np.linspace(angles.min(), angles.max(), 50)
            distance = radius * (np.cos(arc) * face.normal[0] + np.sin(arc) * face.normal[1]) + face.offset
            assert np.abs(distance).max() <= tol
            middle = np.mean(spans[-1])  # out of the wall: away from the centre outside, toward it inside
            assert side * (np.cos(middle) * face.normal[0] + np.sin(middle) * face.normal[1]) > 0.99
        spans.sort()
        assert spans[0][0] == pytest.approx(0.0, abs=1e-5) and spans[-1][1] == pytest.approx(np.pi / 2, abs=1e-5)
        assert all(abs(a[1] - b[0]) < 1e-5 for a, b in zip(spans, spans[1:]))  # no gap, no overlap
        assert sum(f.area for f in facets) == pytest.approx(radius * np.pi / 2 * H, rel=2e-3)

    write_curved_wall(tmp_path / "window.ifc", profile, schema, unit, opening=True)
    windowed, _ = import_ifc(tmp_path / "window.ifc", cfg)
    for side in (1.0, -1.0):
        def area(plane_map):
            return sum(f.area for f in plane_map.faces if side * (np.hypot(*f.centre[:2]) - R_C) > 0)
        assert area(plane_map) - area(windowed) == pytest.approx(1.0 * 1.2, rel=0.02)
