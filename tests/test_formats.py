"""The plane map and sequence formats: valid files load, bad ones name the bad field."""

import json

import numpy as np
import pytest

from bimgraph.bim.planemap import BimFace, load_plane_map, polygon_area_centre, save_plane_map
from bimgraph.errors import FormatError, InputError
from bimgraph.sequence.format import iter_keyframes, load_sequence

HAND_MAP = {
    "format": "bimgraph.planemap",
    "version": 1,
    "faces": [
        {
            "id": "north",
            "wall_guid": "W1",
            "normal": [0, -1, 0],
            "offset": 5.0,
            "polygon": [[0, 5, 0], [4, 5, 0], [4, 5, 3], [0, 5, 3]],
        }
    ],
}


def test_hand_written_map_gets_area_and_centre(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(json.dumps(HAND_MAP))
    pm = load_plane_map(path)
    face = pm.faces[0]
    assert face.area == pytest.approx(12.0)
    assert np.allclose(face.centre, [2, 5, 1.5])
    save_plane_map(pm, tmp_path / "again.json")
    assert load_plane_map(tmp_path / "again.json") == pm


def test_polygon_with_hole():
    square = [[0, 0, 0], [2, 0, 0], [2, 0, 2], [0, 0, 2]]
    hole = [[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]]
    area, centre = polygon_area_centre(square, [hole], [0, 1, 0])
    assert area == pytest.approx(3.0)
    # Moments: (4 * (1, 1) - 1 * (0.5, 0.5)) / 3
    assert np.allclose(centre, [3.5 / 3, 0, 3.5 / 3])


def face_with_hole() -> BimFace:
    return BimFace(**{**HAND_MAP["faces"][0], "holes": [[[1, 5, 1], [2, 5, 1], [2, 5, 2], [1, 5, 2]]]})


def test_face_moved_to_another_plane():
    """A wall built off plan: the face moved along its normal keeps its shape and holes; tilted
    about its centre, it keeps its centre."""
    face = face_with_hole()
    moved = face.moved_to([0, -1, 0, 5.07])
    assert face.moved_to([0, -2, 0, 10.14]) == moved  # (n, d) taken up to scale
    assert moved.area == pytest.approx(face.area)
    assert np.allclose(moved.centre, np.asarray(face.centre) + [0, 0.07, 0])
    assert np.allclose(np.asarray(moved.holes[0]) - face.holes[0], [0, 0.07, 0])
    tilt = np.radians(2.0)
    n = np.array([0.0, -np.cos(tilt), np.sin(tilt)])
    tilted = face.moved_to([*n, -n @ np.asarray(face.centre)])
    assert np.allclose(np.asarray(tilted.polygon) @ n - n @ np.asarray(face.centre), 0.0)
    assert tilted.area == pytest.approx(face.area * np.cos(tilt))  # projected: the height foreshortened
    assert np.allclose(tilted.centre, face.centre)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda f: f.update(normal=[0, -2, 0]), "faces[0].normal"),
        (lambda f: f.update(polygon=[[0, 5, 0], [4, 5, 0]]), "faces[0].polygon"),
        (lambda f: f.update(offset=4.0), "off the plane"),
        (lambda f: f.pop("wall_guid"), "faces[0].wall_guid"),
        (lambda f: f.update(offset=float("nan")), "faces[0].offset: Input should be a finite number"),
        (lambda f: f.update(holes=[[[1, 5, 1], [2, 5, 1]]]), "faces[0].holes[0]: List should have at least 3 items"),
        # corners in a line: no area, whatever area the file gives it
        (lambda f: f.update(polygon=[[0, 5, 0], [1, 5, 0], [2, 5, 0]], area=1.0), "faces[0]: polygon has zero area: its corners lie on a line"),
        (lambda f: f.update(polygon=[[0, 5, 0], [1, 5, 0], [2, 5, 0]], area=1.0, centre=[1, 5, 0]),
         "faces[0]: polygon has zero area"),
        (lambda f: f.update(id=""), "faces[0].id: String should have at least 1 character"),
        (lambda f: f.update(centre=[100, 5, 100]), "faces[0]: centre .* is not on the face"),
        (lambda f: f.update(kind="slab_top"), "faces[0]: a slab_top face must be horizontal"),
        # (a floor written as a wall loaded, and was matched as one)
        (lambda f: f.update(normal=[0, 0, 1], offset=0.0, polygon=[[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]]),
         "faces[0]: a wall face must be within 30 degrees of vertical"),
        (lambda data: data.update(T_W_B=[0, 0, 0, 0, 0, 0, 5]), "T_W_B: quaternion has norm 5.0000"),
        # shapes that would load as another area than the file says, then break a run's geometry
        (lambda f: f.update(polygon=[[0, 5, 0], [4, 5, 3], [4, 5, 0], [0, 5, 3]]),
         "faces[0] ('north'): its polygon and holes are not one shape (Self-intersection"),
        # (given area and centre, its outline's areas cancel: it was "zero area" alone)
        (lambda f: f.update(polygon=[[0, 5, 0], [4, 5, 3], [4, 5, 0], [0, 5, 3]], area=6.0, centre=[2, 5, 1.5]),
         "faces[0]: polygon has zero area: its outline crosses itself (a bow tie)"),
        (lambda f: f.update(holes=[[[5, 5, 1], [6, 5, 1], [6, 5, 2], [5, 5, 2]]]),
         "faces[0] ('north'): its polygon and holes are not one shape (Hole lies outside shell"),
        (lambda f: f.update(holes=[[[3, 5, 1], [5, 5, 1], [5, 5, 2], [3, 5, 2]]]), "faces[0] ('north'): .* not one shape"),
        (lambda f: f.update(area=13.0), "faces[0] ('north'): area 13 m2 is not its polygon's less its holes, 12 m2"),
    ],
)
def test_bad_map_names_the_field(tmp_path, change, message):
    data = json.loads(json.dumps(HAND_MAP))
    change(data if "T_W_B" in message else data["faces"][0])
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data))
    pattern = message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(").replace(")", r"\)")  # (".*" stays)
    with pytest.raises(FormatError, match=pattern):
        load_plane_map(path)


def test_a_door_at_floor_level_may_be_a_hole_touching_the_outline(tmp_path):
    """As a user writes a door by hand: a hole whose bottom edge lies on the polygon's."""
    data = json.loads(json.dumps(HAND_MAP))
    data["faces"][0]["holes"] = [[[1, 5, 0], [2, 5, 0], [2, 5, 2], [1, 5, 2]]]
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data))
    assert load_plane_map(path).faces[0].area == pytest.approx(10.0)


def test_a_wall_may_lean_less_than_the_import_allows(tmp_path):
    """Up to 30 degrees out of vertical, as the IFC import's bound for a leaning wall's side."""
    lean = np.radians(29.0)
    n = [0.0, -np.cos(lean), np.sin(lean)]
    polygon = [[0, 0, 0], [4, 0, 0], [4, np.sin(lean), np.cos(lean)], [0, np.sin(lean), np.cos(lean)]]
    data = json.loads(json.dumps(HAND_MAP))
    data["faces"][0].update(normal=n, offset=0.0, polygon=polygon)
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data))
    assert load_plane_map(path).faces[0].area == pytest.approx(4.0)


def test_a_repeated_closing_point_is_dropped(tmp_path):
    """Hand-written maps come from closed polylines copied out of drawings: the last point
    repeating the first is no corner (it loaded as a fifth one)."""
    data = json.loads(json.dumps(HAND_MAP))
    face = data["faces"][0]
    face["polygon"].append(face["polygon"][0])
    face["holes"] = [[[1, 5, 1], [2, 5, 1], [2, 5, 2], [1, 5, 2], [1, 5, 1]]]
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data))
    loaded = load_plane_map(path).faces[0]
    assert loaded.polygon == [tuple(map(float, p)) for p in HAND_MAP["faces"][0]["polygon"]]
    assert len(loaded.holes[0]) == 4 and loaded.area == pytest.approx(11.0)


def test_a_byte_order_mark_is_read_past(tmp_path):
    """Windows editors write one; it was "Unexpected UTF-8 BOM (decode using utf-8-sig)"."""
    path = tmp_path / "map.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(HAND_MAP).encode())
    assert load_plane_map(path).faces[0].id == "north"
    _write_sequence(tmp_path / "seq", [KF, dict(KF, index=1, stamp=0.1)])
    for name in ("sequence.json", "keyframes.jsonl"):
        file = tmp_path / "seq" / name
        file.write_bytes(b"\xef\xbb\xbf" + file.read_bytes())
    assert len(load_sequence(tmp_path / "seq").keyframes) == 2


def test_not_json(tmp_path):
    path = tmp_path / "map.json"
    path.write_text("{ nope")
    with pytest.raises(FormatError, match="line 1"):
        load_plane_map(path)
    with pytest.raises(InputError):
        load_plane_map(tmp_path / "missing.json")


@pytest.mark.parametrize("text, message", [
    ("[" * 100000 + "]" * 100000, "nested too deeply"),
    ('{"version": ' + "9" * 5000 + "}", "Exceeds the limit"),
])
def test_json_python_will_not_read_is_a_format_error(tmp_path, text, message):
    path = tmp_path / "map.json"
    path.write_text(text)
    with pytest.raises(FormatError, match=message):
        load_plane_map(path)


def _write_sequence(root, lines):
    root.mkdir()
    (root / "sequence.json").write_text(json.dumps({"format": "bimgraph.sequence", "version": 1}))
    (root / "keyframes.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))


KF = {"index": 0, "stamp": 0.0, "T_S_C": [0, 0, 0, 0, 0, 0, 1],
      "planes": [{"n": [0, 0, -1], "d": 2.0, "cov": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]]}]}


def test_sequence_loads(tmp_path):
    kf2 = dict(KF, index=1, stamp=0.1)
    _write_sequence(tmp_path / "seq", [KF, kf2])
    seq = load_sequence(tmp_path / "seq")
    assert len(seq.keyframes) == 2
    assert np.allclose(seq.keyframes[0].pose, np.eye(4))
    assert np.allclose(seq.keyframes[0].planes[0].plane, [0, 0, -1, 2])


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(KF, index=1, T_S_C=[0, 0, 0, 0, 0, 0, 2]), "line 2: T_S_C"),
        (dict(KF, index=1, planes=[{"n": [0, 0, -1]}]), r"line 2: planes\[0\].d"),
        # (a normal away from the camera, or a plane given in S, read "Input should be greater than 0")
        (dict(KF, index=1, stamp=0.1, planes=[{"n": [0, 0, 1], "d": -2.0}]),
         r"line 2: planes\[0\].d: -2: d is the camera's distance to the plane, > 0, with n toward the camera .with d < 0, flip n and d"),
        (dict(KF, index=0), "line 2: index"),
        (dict(KF, index=1, stamp=0.0), "line 2: stamp: 0.0 does not follow 0.0"),
        (dict(KF, index=1, stamp=0.1, planes=[dict(KF["planes"][0], polygon=[[0, 0, 2], [1, 0, 2]])]),
         r"line 2: planes\[0\].polygon: a polygon has at least 3 points"),
        (dict(KF, index=1, stamp=0.1, planes=[dict(KF["planes"][0], polygon=[[0, 0, 2], [1, 0, 2], [1, 1, 52]])]),
         r"line 2: planes\[0\]: polygon: a point lies 50.00 m off the plane"),
        (dict(KF, index=1, planes=[dict(KF["planes"][0], cov=[[1, 0, 0], [0, -1, 0], [0, 0, 1]])]), "positive definite"),
        # (a pose given to 1e-15 m made the graph singular, reported at another keyframe)
        (dict(KF, index=1, stamp=0.1, cov=(1e-30 * np.eye(6)).tolist()), r"line 2: cov: .*a sigma of 1e-15, below 1e-09"),
        # (nanoseconds came out of a run rounded by float64, and `--rrd` ended in a traceback)
        (dict(KF, index=1, stamp=1700000000123456789), "line 2: stamp: 1.7000000001234568e[+]18 is not in seconds .it looks like nanoseconds"),
        (dict(KF, index=1, stamp=1700000000123), "line 2: stamp: 1700000000123 is not in seconds .it looks like milliseconds"),
    ],
)
def test_bad_keyframe_names_line_and_field(tmp_path, bad, message):
    _write_sequence(tmp_path / "seq", [KF, bad])
    with pytest.raises(FormatError, match=message):
        list(iter_keyframes(tmp_path / "seq"))


def test_initial_alignment_needs_a_unit_quaternion(tmp_path):
    """A zero quaternion was accepted, and made every pose NaN."""
    _write_sequence(tmp_path / "seq", [KF])
    meta = {"format": "bimgraph.sequence", "version": 1, "initial_alignment": {"T_B_S": [0, 0, 0, 0, 0, 0, 0]}}
    (tmp_path / "seq" / "sequence.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError, match=r"sequence.json: initial_alignment.T_B_S: quaternion has norm 0.0000, must be unit$"):
        load_sequence(tmp_path / "seq")


def test_gravity_aligned_must_be_a_boolean(tmp_path):
    """"yes" ran as true: a flag that fixes two of the extrinsic's directions is no guess."""
    _write_sequence(tmp_path / "seq", [KF])
    meta = {"format": "bimgraph.sequence", "version": 1, "gravity_aligned": "yes"}
    (tmp_path / "seq" / "sequence.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError, match=r"sequence.json: gravity_aligned: Input should be a valid boolean$"):
        load_sequence(tmp_path / "seq")
