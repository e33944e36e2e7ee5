"""deviations.json / .csv round trips and the BCF file re-opened with the BCF library."""

import json
import zipfile

import numpy as np
import pytest
from bcf.v3.bcfxml import BcfXml
from scipy.spatial.transform import Rotation

from bimgraph.config import DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.bcf import read_bcf_topics, write_bcf
from bimgraph.deviations.report import CSV_FILE, JSON_FILE, load_deviations, read_csv_rows, write_deviations
from bimgraph.errors import FormatError
from bimgraph.geometry import inverse, make_pose, pose_to_tum
from deviation_scenes import T_S_B
from test_deviations import room_scene

CFG = DeviationConfig()


@pytest.fixture()
def written(tmp_path):
    plane_map, planes = room_scene()
    report = assess(plane_map, planes, T_S_B, CFG, expected_views={"north-face": 12})
    data = write_deviations(report, tmp_path)
    return plane_map, data, tmp_path


def test_json_round_trip(written):
    _, data, out = written
    loaded = load_deviations(out / JSON_FILE)
    assert loaded == data
    assert loaded.counts() == {"deviating": 2, "within_tolerance": 1, "possibly_not_built": 1, "unplanned": 1}
    south = next(f for f in loaded.faces if f.face_id == "south-face")
    assert south.offset_m == pytest.approx(0.06, abs=1e-3)
    assert south.wall_guid == "2O2Fr$t4X7Zf8NOew3FLOH"


def test_csv_holds_the_same_rows(written):
    plane_map, data, out = written
    rows = read_csv_rows(out / CSV_FILE)
    assert len(rows) == len(data.faces) + len(data.unplanned)
    planned = {f.id: f for f in plane_map.faces}
    for row, face in zip(rows, data.faces):
        assert row["face_id"] == face.face_id and row["status"] == face.status
        # where the offset is measured, for a reader with the report alone
        assert face.centre == planned[face.face_id].centre and face.area_m2 == planned[face.face_id].area
        assert [float(row[f"centre_{axis}"]) for axis in "xyz"] == list(face.centre)
        assert float(row["area_m2"]) == face.area_m2
        if face.offset_m is None:
            assert row["offset_m"] == "" and row["offset_sigma_m"] == ""
        else:
            assert float(row["offset_m"]) == face.offset_m  # exact: floats are written in full
            assert float(row["tilt_sigma_deg"]) == face.tilt_sigma_deg
        assert int(row["n_keyframes"]) == face.n_keyframes
    unplanned = rows[-1]
    assert unplanned["status"] == "unplanned" and unplanned["face_id"] == ""
    assert float(unplanned["area_m2"]) == data.unplanned[0].area_m2
    assert float(unplanned["centre_x"]) == pytest.approx(3.0)


def test_bad_json_names_the_field(tmp_path, written):
    _, data, out = written
    raw = json.loads((out / JSON_FILE).read_text())
    raw["faces"][0]["status"] = "wonky"
    (tmp_path / "bad.json").write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=r"faces\[0\]\.status"):
        load_deviations(tmp_path / "bad.json")


@pytest.mark.parametrize("edit, message", [
    # (the printout multiplied a null offset: a traceback)
    (lambda d: d["faces"][0].update(status="deviating", offset_m=None), r"faces\[0\]: .*a face deviating has its offset_m"),
    (lambda d: d.update(contested=[{"probability": 0.5, "deviating": [dict(d["faces"][0], status="within_tolerance")]}]),
     r"contested\[0\]: .*the faces of an explanation are deviating ones"),
])
def test_a_report_that_cannot_be_read_as_one_names_the_field(written, tmp_path, edit, message):
    _, _, out = written
    raw = json.loads((out / JSON_FILE).read_text())
    edit(raw)
    (tmp_path / "bad.json").write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=message):
        load_deviations(tmp_path / "bad.json")


# B 2.5 km and a turn of 30 degrees away from the IFC world frame, as in a georeferenced model
T_W_B = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [2500.0, -1200.0, 35.0])


@pytest.mark.parametrize("georeferenced", [False, True])
def test_bcf_reopens_and_names_existing_walls(written, tmp_path, georeferenced):
    """Every topic selects a deviating wall; its camera stands in the room, in front of the
    face, and looks at it, in the IFC world frame (B's pose in it applied where B is not it)."""
    plane_map, data, _ = written
    if georeferenced:
        plane_map = plane_map.model_copy(update={"T_W_B": tuple(pose_to_tum(T_W_B))})
    T_B_W = inverse(T_W_B) if georeferenced else np.eye(4)
    path = tmp_path / "deviations.bcf"
    n = write_bcf(data, plane_map, path, CFG)
    deviating = [f for f in data.faces if f.status == "deviating"]
    assert n == len(deviating) == 2

    topics = read_bcf_topics(path)
    assert len(topics) == n
    wall_guids = {f.wall_guid for f in plane_map.faces}
    assert sorted(g for _, guids in topics for g in guids) == sorted(f.wall_guid for f in deviating)
    assert all(len(guids) == 1 and guids[0] in wall_guids for _, guids in topics)

    with BcfXml.load(path) as bcf:
        for topic in bcf.topics.values():
            assert "cm" in topic.topic.description
            (vp,) = topic.viewpoints.values()
            camera = vp.visualization_info.perspective_camera
            # The camera stands in the room (in front of the face) and looks at the face.
            face = next(f for f in plane_map.faces if f.wall_guid == vp.get_selected_guids()[0])
            (p, d) = (np.array([v.x, v.y, v.z]) for v in (camera.camera_view_point, camera.camera_direction))
            pos_B, direction_B = T_B_W[:3, :3] @ p + T_B_W[:3, 3], T_B_W[:3, :3] @ d
            assert np.dot(face.normal, pos_B) + face.offset > 1.0
            assert np.dot(face.normal, direction_B) < -0.5


@pytest.mark.parametrize("version", [1, 2, 3])
def test_an_earlier_version_loads_without_the_later_fields(written, tmp_path, version):
    _, _, out = written
    raw = json.loads((out / JSON_FILE).read_text())
    raw["version"] = version
    for later in {1: ("contested", "widths", "thicknesses"), 2: ("thicknesses",), 3: ()}[version]:
        raw.pop(later)
    for face in raw["faces"]:
        del face["centre"], face["area_m2"]
    (tmp_path / "old.json").write_text(json.dumps(raw))
    old = load_deviations(tmp_path / "old.json")
    assert old.version == version and old.thicknesses == [] and len(old.faces) == 4


def test_bcf_names_its_model_and_lists_the_values_it_uses(written, tmp_path):
    """A BIM tool picks the model a topic is about by the markup's header (it had none), and
    BCF 3.0 takes topic types and statuses from extensions.xml (it was empty); creation dates
    are UTC, said so; the project keeps one id from report to report, so they merge."""
    plane_map, data, _ = written
    plane_map = plane_map.model_copy(update={"source": "site.ifc", "ifc_project": "3sQBBEGDXPPi$$JO2bKmW$"})
    ids = []
    for name in ("a.bcf", "b.bcf"):
        write_bcf(data, plane_map, tmp_path / name, CFG)
        with BcfXml.load(tmp_path / name) as bcf:
            ids.append(bcf.project_info.project.project_id)
            extensions = bcf.extensions
            for topic in bcf.topics.values():
                assert topic.topic.topic_type in extensions.topic_types.topic_type
                assert topic.topic.topic_status in extensions.topic_statuses.topic_status
                assert topic.topic.creation_author in extensions.users.user
                (file,) = topic.header.files.file
                assert (file.filename, file.ifc_project, file.is_external) == ("site.ifc", "3sQBBEGDXPPi$$JO2bKmW$", True)
                assert topic.topic.creation_date.offset == 0
    assert ids[0] == ids[1]
    with zipfile.ZipFile(tmp_path / "a.bcf") as z:
        extensions_xml = z.read("extensions.xml").decode()
    for listed in ("TopicTypes", "TopicStatuses", "Priorities", "TopicLabels", "Users", "SnippetTypes", "Stages"):
        assert f"<{listed}" in extensions_xml
    # a hand-written map names no model: no header
    write_bcf(data, plane_map.model_copy(update={"source": "", "ifc_project": ""}), tmp_path / "c.bcf", CFG)
    with BcfXml.load(tmp_path / "c.bcf") as bcf:
        assert all(topic.header is None for topic in bcf.topics.values())
