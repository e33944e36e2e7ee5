"""Damaged and unusual IFC files: the import warns and skips what it cannot read, and a file it
cannot read at all is one line. The generated house (tests/ifc_house.py) is edited as text, as
a broken exporter or a hand edit would leave it."""

import re

import numpy as np
import pytest
from cli_errors import assert_one_line_error
from ifc_house import house, wall_named
from typer.testing import CliRunner

from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_open import unbalanced_statement
from bimgraph.bim.ifc_write import write_ifc
from bimgraph.cli import app
from bimgraph.config import BimImportConfig
from bimgraph.errors import FormatError


@pytest.fixture(scope="module")
def house_text(tmp_path_factory):
    path = tmp_path_factory.mktemp("house") / "house.ifc"
    write_ifc(house(), path)
    return path.read_text()


def entity(text: str, ifc_type: str, name: str | None = None) -> str:
    """The line of the first entity of `ifc_type` (with that Name, if given)."""
    pattern = rf"^#\d+={ifc_type}\('[^']*',[^,]*,'{re.escape(name)}'.*$" if name else rf"^#\d+={ifc_type}\(.*$"
    return re.search(pattern, text, re.MULTILINE).group(0)


def line_of(text: str, ref: str) -> str:
    return re.search(rf"^{ref}=.*$", text, re.MULTILINE).group(0)


def imported(path):
    warnings = []
    plane_map, _ = import_ifc(path, BimImportConfig(), warnings.append)
    return plane_map, warnings


def walls_of(plane_map) -> set[str]:
    return {face.wall_name for face in plane_map.faces}


def test_the_house_as_written(house_text, tmp_path):
    """(No warning: in particular, no body the schema reader failed on and left to the kernel.)"""
    (tmp_path / "m.ifc").write_text(house_text)
    plane_map, warnings = imported(tmp_path / "m.ifc")
    assert warnings == [] and len(walls_of(plane_map)) == 9


def test_a_syntax_error_is_warned_about_not_lost_in_silence(house_text, tmp_path):
    """Past a syntax error the parser may fold the entities after it into one: what it lost
    is not lost in silence."""
    wall = entity(house_text, "IFCWALL", "E0")
    body = line_of(house_text, wall.split(",")[6])
    (tmp_path / "m.ifc").write_text(house_text.replace(body, body.replace("(", "((", 1)))
    _, warnings = imported(tmp_path / "m.ifc")
    assert warnings and all(w.startswith("warning: m.ifc: ") for w in warnings[:5])


def test_a_file_the_parser_refuses_names_the_line(house_text, tmp_path):
    """The parser's own message says "check logs"; the log says what and where, in bytes."""
    point = entity(house_text, "IFCCARTESIANPOINT")
    text = house_text.replace(point, "#abc=" + point.split("=", 1)[1], 1)
    (tmp_path / "m.ifc").write_text(text)
    result = CliRunner().invoke(app, ["bim", str(tmp_path / "m.ifc"), "-o", str(tmp_path / "planes.json")])
    line = text[:text.index("#abc=")].count("\n") + 1
    assert_one_line_error(result, 3, f"token abc on line {line} invalid instance name")


def test_a_file_damaged_beyond_its_walls_says_so_in_its_one_line(house_text, tmp_path):
    (tmp_path / "m.ifc").write_text(house_text.replace("IFCWALL(", "IFCWALX("))
    result = CliRunner().invoke(app, ["bim", str(tmp_path / "m.ifc"), "-o", str(tmp_path / "planes.json")])
    assert_one_line_error(result, 3, "no walls", "the file is damaged", "IFCWALX")


def test_a_parenthesis_too_many_is_found_by_its_line(house_text, tmp_path):
    """One "(" too many early on: the parser swallows the rest of the file and its first
    complaint is about ENDSEC at the end; the one line names the statement to fix."""
    point = entity(house_text, "IFCCARTESIANPOINT")
    text = house_text.replace(point, point.replace("(", "((", 1), 1)
    (tmp_path / "m.ifc").write_text(text)
    result = CliRunner().invoke(app, ["bim", str(tmp_path / "m.ifc"), "-o", str(tmp_path / "planes.json")])
    line = text[:text.index(point.replace("(", "((", 1))].count("\n") + 1
    assert_one_line_error(result, 3, "no walls", f"line {line}: its parentheses do not balance")


def test_the_unbalanced_statement_is_found_past_strings_and_comments(tmp_path):
    header = "ISO-10303-21;\nHEADER;\n/* an exporter's\n comment ( */\nFILE_NAME('a;(b''c');\nENDSEC;\nDATA;\n"
    (tmp_path / "m.ifc").write_text(header + "#1=IFCX('x)');\n#2=IFCX((1.,2.);\n#3=IFCY(());\nENDSEC;\n")
    assert unbalanced_statement(tmp_path / "m.ifc") == 9
    (tmp_path / "ok.ifc").write_text(header + "#1=IFCX('(',(1.,2.));\nENDSEC;\n")
    assert unbalanced_statement(tmp_path / "ok.ifc") is None


def test_two_entities_of_one_name_are_one_line(house_text, tmp_path):
    """(The geometry kernel would crash on such a file.)"""
    name = entity(house_text, "IFCWALL").split("=")[0]
    (tmp_path / "m.ifc").write_text(house_text.replace("DATA;\n", f"DATA;\n{name}=IFCCARTESIANPOINT((0.,0.,0.));\n", 1))
    with pytest.raises(FormatError, match="two entities with one name"):
        imported(tmp_path / "m.ifc")
    result = CliRunner().invoke(app, ["bim", str(tmp_path / "m.ifc"), "-o", str(tmp_path / "planes.json")])
    assert_one_line_error(result, 3, "m.ifc", "two entities")
    assert not (tmp_path / "planes.json").exists()


@pytest.mark.parametrize("damage", ["profile", "placement", "representation_type", "placement_cycle", "no_placement",
                                    "no_parent_placement"])
def test_a_wall_that_cannot_be_read_is_skipped_and_the_rest_goes_on(house_text, tmp_path, damage):
    """Whatever of a wall's geometry cannot be read, the wall is warned about and skipped and
    counted as unreadable. A reference to no entity the parser reads as unset: the wall stood
    at the origin, or storeys below its own, without a word (a review's edit of AC20-FZK-Haus)."""
    wall = entity(house_text, "IFCWALL", "E0")
    fields = wall.split(",")
    if damage == "profile":  # its extrusion's profile is an entity the file does not hold
        shape = line_of(house_text, fields[6])
        solids = [line_of(house_text, ref) for ref in re.findall(r"#\d+", shape.split("=", 1)[1])]
        items = [line_of(house_text, ref) for rep in solids for ref in re.findall(r"#\d+", rep.split("=", 1)[1])]
        solid = next(line for line in items if "IFCEXTRUDEDAREASOLID(" in line)
        text = house_text.replace(solid, re.sub(r"\(#\d+,", "(#88888,", solid, count=1))
    elif damage == "placement":  # its placement's axes are missing
        placement = line_of(house_text, fields[5])
        text = house_text.replace(placement, re.sub(r",#\d+\);$", ",#99993);", placement))
    elif damage == "representation_type":  # its representation is a point
        point = entity(house_text, "IFCCARTESIANPOINT").split("=")[0]
        text = house_text.replace(wall, ",".join(fields[:6] + [point] + fields[7:]))
    elif damage == "placement_cycle":  # placed relative to itself
        placement = line_of(house_text, fields[5])
        text = house_text.replace(placement, re.sub(r"\(#\d+,", f"({placement.split('=')[0]},", placement, count=1))
    elif damage == "no_placement":  # its placement is an entity the file does not hold
        text = house_text.replace(wall, ",".join(fields[:5] + ["#99994"] + fields[6:]))
    else:  # its placement's parent is an entity the file does not hold
        placement = line_of(house_text, fields[5])
        text = house_text.replace(placement, re.sub(r"\(#\d+,", "(#99995,", placement, count=1))
    (tmp_path / "m.ifc").write_text(text)
    warnings = []
    plane_map, report = import_ifc(tmp_path / "m.ifc", BimImportConfig(), warnings.append)
    assert "E0" not in walls_of(plane_map) and len(walls_of(plane_map)) == 8
    assert any("E0" in w and "skipped" in w for w in warnings), warnings
    counts = {item: int(n) for item, n in zip(report.columns[0]._cells, report.columns[1]._cells)
              if item.startswith("walls skipped")}
    assert counts["walls skipped (geometry unreadable)"] + counts["walls skipped (no geometry)"] == 1
    if damage in ("placement_cycle", "no_placement", "no_parent_placement"):
        assert counts["walls skipped (geometry unreadable)"] == 1  # (a cycle was counted as no geometry)
        why = "placed relative to itself" if damage == "placement_cycle" else "names an entity the file lacks"
        assert any("E0" in w and why in w for w in warnings), warnings


def test_a_building_placed_relative_to_itself_is_one_line(house_text, tmp_path):
    building = entity(house_text, "IFCBUILDING")
    placement = line_of(house_text, building.split(",")[5])
    ref = placement.split("=")[0]
    (tmp_path / "m.ifc").write_text(house_text.replace(placement, re.sub(r"\((#\d+|\$),", f"({ref},", placement, count=1)))
    with pytest.raises(FormatError, match="the building's placement cannot be read"):
        imported(tmp_path / "m.ifc")


def test_a_byte_order_mark_is_read(house_text, tmp_path):
    (tmp_path / "plain.ifc").write_text(house_text)
    (tmp_path / "bom.ifc").write_text(house_text, encoding="utf-8-sig")
    plain, _ = imported(tmp_path / "plain.ifc")
    with_bom, warnings = imported(tmp_path / "bom.ifc")
    assert warnings == [] and [f.model_dump() for f in with_bom.faces] == [f.model_dump() for f in plain.faces]


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (1.0, 0.0044, 0.0),
                                  (1.0, 0.0, 0.1)])
def test_an_axis_without_ref_direction_is_read_as_the_geometry_kernel_reads_it(tmp_path, axis):
    """IFC wants Axis and RefDirection both or neither; given an Axis alone, the schema reader
    and ifcopenshell's kernel must agree (here a wall body turned so)."""
    import ifcopenshell
    import ifcopenshell.geom
    import ifcopenshell.util.shape

    path = tmp_path / "m.ifc"
    write_ifc(house(), path)
    model = ifcopenshell.open(str(path))
    wall = wall_named(model, "E0")
    solid = next(r for r in wall.Representation.Representations if r.RepresentationIdentifier == "Body").Items[0]
    solid.Position.Axis = model.createIfcDirection(axis)
    solid.Position.RefDirection = None
    model.write(str(path))
    plane_map, warnings = imported(path)
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    V = ifcopenshell.util.shape.get_vertices(ifcopenshell.geom.create_shape(settings, wall).geometry)
    faces = [f for f in plane_map.faces if f.wall_name == "E0"]
    assert faces and not warnings
    corners = np.vstack([np.asarray(f.polygon) for f in faces])
    # (B is the building's frame, the world's here: write_ifc places the building at the origin)
    np.testing.assert_allclose(corners.min(axis=0), V.min(axis=0), atol=1e-5)
    np.testing.assert_allclose(corners.max(axis=0), V.max(axis=0), atol=1e-5)


def test_rooms_without_geometry_leave_the_split_to_the_junctions(tmp_path):
    """A model whose only IfcSpace has no solid and no boundary says nothing of rooms: its
    faces are split where walls meet them, as in a model without rooms."""
    import ifcopenshell
    import ifcopenshell.api.root

    path = tmp_path / "m.ifc"
    write_ifc(house(), path)
    model = ifcopenshell.open(str(path))
    for space in model.by_type("IfcSpace"):
        model.remove(space)
    without, _ = import_ifc_model(model, tmp_path / "none.ifc")
    ifcopenshell.api.root.create_entity(model, ifc_class="IfcSpace", name="empty")
    with_empty, _ = import_ifc_model(model, tmp_path / "empty.ifc")
    assert {f.split for f in without.faces} >= {"junction"}
    assert [(f.id, f.split) for f in with_empty.faces] == [(f.id, f.split) for f in without.faces]


def import_ifc_model(model, path):
    model.write(str(path))
    return imported(path)


def real_wall_lines(text: str) -> list[tuple[int, str, str, str]]:
    """(line number, statement, GlobalId, Name) of each IfcWallStandardCase of an ArchiCAD model."""
    pattern = re.compile(r"^#\d+= ?IFCWALLSTANDARDCASE\('([^']+)',[^,]*,'([^']*)'.*$", re.MULTILINE)
    return [(text[:m.start()].count("\n") + 1, m.group(0), m.group(1), m.group(2)) for m in pattern.finditer(text)]


def test_a_parenthesis_too_many_in_a_wall_names_its_line(ifc_samples, tmp_path):
    """The parser keeps the wall of that statement, its attributes lost, and swallows every
    wall after it: walls are found, no face comes out; that is the file's damage, said by its
    line, not a model without faces. (It said "no wall face", exit 2, named the husk wall by the
    entity the parser had put in its GlobalId, and passed on ifcopenshell's C++ type names.)"""
    text = (ifc_samples / "AC20-FZK-Haus.ifc").read_text()
    line, wall, _, _ = real_wall_lines(text)[0]
    (tmp_path / "m.ifc").write_text(text.replace(wall, wall.replace("(", "((", 1), 1))
    result = CliRunner().invoke(app, ["bim", str(tmp_path / "m.ifc"), "-o", str(tmp_path / "planes.json")])
    *warnings, error, _ = result.stderr.split("\n")
    assert result.exit_code == 3 and error.startswith("error: "), result.stderr
    assert "the file is damaged" in error and f"line {line}: its parentheses do not balance" in error, error
    assert all(w.startswith("warning: ") for w in warnings), warnings
    assert "IfcRelSpaceBoundary" not in result.stderr and "instance_reference" not in result.stderr, result.stderr


def test_two_walls_sharing_a_globalid_are_told_apart(ifc_samples, tmp_path):
    """GlobalIds are unique in IFC; a file where two walls share one (a copy-paste slip) is
    warned about, naming both, and their faces keep ids of their own (they came out merged
    under one wall, without a word)."""
    text = (ifc_samples / "AC20-FZK-Haus.ifc").read_text()
    (_, first, guid, first_name), (_, second, shared, second_name) = real_wall_lines(text)[:2]
    (tmp_path / "m.ifc").write_text(text.replace(first, first.replace(guid, shared), 1))
    plane_map, warnings = imported(tmp_path / "m.ifc")
    original, _ = imported(ifc_samples / "AC20-FZK-Haus.ifc")
    ids = [first.split("=")[0], second.split("=")[0]]
    assert any(shared in w and all(i in w for i in ids) and first_name in w and second_name in w for w in warnings), warnings
    faces = {name: [f for f in plane_map.faces if f.wall_name == name] for name in (first_name, second_name)}
    assert all(f.wall_guid == shared for fs in faces.values() for f in fs)
    prefixes = {name: {f.id.rpartition("/")[0] for f in fs} for name, fs in faces.items()}
    assert len(prefixes[first_name]) == len(prefixes[second_name]) == 1 and prefixes[first_name] != prefixes[second_name]
    assert len(plane_map.faces) == len(original.faces)
