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
    import ifcopenshell

    path = tmp_path / "broken.ifc"
    write_ifc(house(), path)
    model = ifcopenshell.open(str(path))
    wall = next(w for w in model.by_type("IfcWall") if w.Name == "E0")
    body = next(r for r in wall.Representation.Representations if r.RepresentationIdentifier == "Body")
    body.Items[0].Depth = 0.0  # an extrusion of no height has no geometry
    model.write(str(path))
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
    import ifcopenshell
    import ifcopenshell.api.geometry

    path = tmp_path / "layers.ifc"
    write_ifc(house(), path, length_unit="mm")
    model = ifcopenshell.open(str(path))
    wall = next(w for w in model.by_type("IfcWall") if w.Name == "W0")
    body = next(r for r in wall.Representation.Representations if r.RepresentationIdentifier == "Body")
    context = body.ContextOfItems
    layers = [ifcopenshell.api.geometry.add_wall_representation(
        model, context=context, length=6 - T, height=H, thickness=thickness, offset=offset)
        for thickness, offset in ((0.1, -T / 2), (T - 0.1, -T / 2 + 0.1))]
    body.Items = [layer.Items[0] for layer in layers]
    model.write(str(path))
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
