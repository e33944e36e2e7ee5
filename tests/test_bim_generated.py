"""A model with known geometry, written with ifcopenshell.api, re-extracted by the importer."""

import json
import os

import numpy as np
import pytest
import shapely
from cli_errors import assert_one_line_error
from ifc_house import H, body_of, edited_house, expected_faces, house, wall_named
from typer.testing import CliRunner

from bimgraph.bim.building import Building, Storey
from bimgraph.bim.faces import Face
from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_write import edge_on_wall_face, write_ifc
from bimgraph.bim.planemap import load_plane_map
from bimgraph.cli import app
from bimgraph.config import BimImportConfig
from bimgraph.errors import FormatError, InputError


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


def test_the_map_names_its_file_and_project(written, imported):
    """(BCF topics name both, so that BIM tools open them on the right model.)"""
    import ifcopenshell

    assert imported.source == written.name
    assert imported.ifc_project == ifcopenshell.open(str(written)).by_type("IfcProject")[0].GlobalId


def test_storeys_and_elevations(imported):
    for section in imported.faces:
        storey = section.wall_name[-1]
        assert (section.storey, section.elevation) == (("Ground", 0.0) if storey == "0" else ("Upper", pytest.approx(H)))


def write_no_walls(path):
    write_ifc(Building("Empty", [Storey("Ground", 0.0, H)]), path)


@pytest.mark.parametrize("case, exit_code, message", [("text", 3, "not an IFC file"), ("truncated", 3, "truncated"),
                                                      ("no_walls", 2, "no walls"), ("missing", 2, "no such file")])
def test_bad_input_is_one_line_error(case, exit_code, message, tmp_path):
    model = tmp_path / "model.ifc"
    if case == "text":
        model.write_text("this is not an IFC file\n")
    elif case == "truncated":
        write_ifc(house(), model)
        data = model.read_bytes()
        model.write_bytes(data[: len(data) // 2])
    elif case == "no_walls":
        write_no_walls(model)
    with pytest.raises(InputError if exit_code == 2 else FormatError):
        import_ifc(model if case != "missing" else tmp_path / "absent.ifc", BimImportConfig())
    result = CliRunner().invoke(app, ["bim", str(model), "-o", str(tmp_path / "planes.json")])
    assert_one_line_error(result, exit_code, message)
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
    assert_one_line_error(result, 2, str(out))
    assert not list(tmp_path.glob("*.tmp")) and (tmp_path / "a_file").read_text() == ""


def test_the_import_reports_its_progress(written):
    """Each stage counts up to its total, one step per wall or face (a building of a thousand
    walls imports for a minute)."""
    heard = []
    plane_map, _ = import_ifc(written, BimImportConfig(), progress=lambda *args: heard.append(args))
    stages = list(dict.fromkeys(what for what, _, _ in heard))
    assert stages == ["walls' side faces", "openings cut out", "faces split per room"]
    walls = len(house().walls)
    for what in stages:
        counts = [(done, total) for w, done, total in heard if w == what]
        total = counts[0][1]
        assert counts == [(done, total) for done in range(1, total + 1)]
    assert [t for w, _, t in heard if w == "walls' side faces"][0] == walls
    assert len(plane_map.faces) >= [t for w, _, t in heard if w == "faces split per room"][0]
