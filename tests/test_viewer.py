"""The Rerun viewer: recordings are read back with the `rerun` tool and checked entity by
entity (paths and row counts), on the real online and offline backends."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("RERUN_ANALYTICS", "0")

from bimgraph.backend.online import Backend  # noqa: E402
from bimgraph.backend.offline import run_offline  # noqa: E402
from bimgraph.backend.synthetic import make_scene  # noqa: E402
from bimgraph.bim.planemap import BimFace  # noqa: E402
from bimgraph.config import BackendConfig, ViewerConfig  # noqa: E402
from bimgraph.sequence.format import Camera  # noqa: E402
from bimgraph.viewer import blueprint as bp  # noqa: E402
from bimgraph.geometry import rotation_angle_deg  # noqa: E402
from bimgraph.viewer.drawing import angles_deg, project  # noqa: E402
from bimgraph.viewer.follow import RerunListener, mark_deviations  # noqa: E402
from bimgraph.viewer.meshes import face_mesh  # noqa: E402
from bimgraph.viewer.recording import open_recording  # noqa: E402
from bimgraph.viewer.rerun_viewer import RerunViewer, face_entity  # noqa: E402
from bimgraph.viewer.rrd import component_counts, row_counts, verify  # noqa: E402

N_KEYFRAMES = 80
CAMERA = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)


def triangle_areas(vertices, triangles):
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return np.cross(b - a, c - a)


@pytest.mark.parametrize("normal, offset, polygon, holes", [
    # wall x = 2 facing -x, with a door cut at floor level (touching the outline) and a window
    ((-1.0, 0.0, 0.0), 2.0, [(2, 0, 0), (2, 4, 0), (2, 4, 3), (2, 0, 3)],
     [[(2, 1, 0), (2, 2, 0), (2, 2, 2), (2, 1, 2)], [(2, 3, 1), (2, 3.5, 1), (2, 3.5, 2), (2, 3, 2)]]),
    # oblique wall, no holes
    ((0.6, 0.8, 0.0), -1.0, [(1.0 / 0.6, 0, 0), (0, 1.25, 0), (0, 1.25, 2.5), (1.0 / 0.6, 0, 2.5)], []),
])
def test_face_mesh_covers_polygon_minus_holes_on_the_plane(normal, offset, polygon, holes):
    face = BimFace(id="f", wall_guid="g", normal=normal, offset=offset, polygon=polygon, holes=holes)
    vertices, triangles = face_mesh(face.polygon, face.holes, face.plane)
    cross = triangle_areas(vertices, triangles)
    assert np.linalg.norm(cross, axis=1).sum() / 2 == pytest.approx(face.area, rel=1e-9)
    assert np.abs(vertices @ np.asarray(normal) + offset).max() < 1e-9
    # wound counter-clockwise seen from the room, so the side facing the room is the front
    assert np.all(cross @ np.asarray(normal) > 0)


def test_vectorised_angles_match_the_metric_definition():
    from scipy.spatial.transform import Rotation

    R_a = Rotation.random(50, random_state=1).as_matrix()
    R_b = Rotation.random(50, random_state=2).as_matrix()
    expected = [rotation_angle_deg(a.T @ b) for a, b in zip(R_a, R_b)]
    np.testing.assert_allclose(angles_deg(R_a, R_b), expected, atol=1e-6)


def test_projection_is_the_pinhole_model():
    points_C = np.array([[0.5, -0.2, 2.0], [0.0, 0.0, 1.0]])
    pixels = (CAMERA.K @ points_C.T).T
    np.testing.assert_allclose(project(points_C, CAMERA), pixels[:, :2] / pixels[:, 2:], atol=1e-9)


@pytest.fixture(scope="module")
def scene():
    return make_scene(n_keyframes=N_KEYFRAMES, rooms=(1, 2), seed=3)


def record_online(scene, path, config=None):
    viewer = RerunViewer(open_recording(path), scene.plane_map, scene.initial.T_B_S, camera=CAMERA,
                         T_B_C_truth=(np.array([kf.stamp for kf in scene.keyframes]), np.asarray(scene.T_B_C)), T_B_S_truth=scene.T_B_S, config=config)
    listener = RerunListener(viewer)
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial, listener=listener)
    results = [backend.process(kf) for kf in scene.keyframes]
    return viewer, results


@pytest.fixture(scope="module")
def online_rrd(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("viewer") / "online.rrd"
    # Flushing as often as it may: many small chunks, the worst case for reading back.
    viewer, results = record_online(scene, path, ViewerConfig(flush_seconds=0.0, flush_budget=1.0))
    faces = [f.id for f in scene.plane_map.faces]
    mark_deviations(viewer, {faces[0]: "deviating", faces[1]: "within_tolerance"})
    viewer.trajectory([r.T_B_C for r in results])
    viewer.close()
    return path, results


def test_recording_verifies_and_holds_one_mesh_per_face(online_rrd, scene):
    path, _ = online_rrd
    verify(path)
    counts = row_counts(path)
    meshes = {e for e, c in counts.items() if "Mesh3D:vertex_positions" in c}
    assert meshes == {"/" + face_entity(f.id) for f in scene.plane_map.faces}
    assert all(counts[e]["Mesh3D:vertex_positions"] == 1 for e in meshes)
    assert counts["/" + bp.LABELS]["Points3D:labels"] == 1


def test_trajectories_are_logged_one_segment_per_keyframe(online_rrd):
    path, _ = online_rrd
    counts = row_counts(path)
    instances = component_counts(path)
    for trail in (bp.RAW, bp.CORRECTED, bp.TRUTH):
        # one row and one segment a keyframe: linear, never the whole line again
        assert counts["/" + trail]["LineStrips3D:strips"] == N_KEYFRAMES - 1, trail
        assert instances["/" + trail]["LineStrips3D:strips"].instances == N_KEYFRAMES - 1, trail
    assert instances["/" + bp.FINAL]["LineStrips3D:strips"].instances == 1
    assert counts["/" + bp.FINAL]["LineStrips3D:strips"] == 1
    assert counts["/" + bp.CAMERA]["Transform3D:translation"] == N_KEYFRAMES
    assert counts["/" + bp.SLAM]["Transform3D:translation"] == N_KEYFRAMES
    assert counts["/" + bp.IMAGE]["Pinhole:image_from_camera"] == 1
    assert counts["/" + bp.PLANES]["LineStrips3D:strips"] == N_KEYFRAMES
    assert counts["/" + bp.ASSOCIATIONS]["LineStrips3D:strips"] == N_KEYFRAMES


def test_planes_and_association_lines_match_the_inputs(online_rrd, scene):
    path, results = online_rrd
    instances = component_counts(path)
    # one closed outline per detected polygon
    polygons = sum(p.polygon is not None for kf in scene.keyframes for p in kf.planes)
    assert polygons > 0
    assert instances["/" + bp.PLANES]["LineStrips3D:strips"].instances == polygons
    assert instances["/" + bp.PLANES]["LineStrips3D:colors"].instances == polygons
    # and projected into the camera's image
    assert instances["/" + bp.PLANES_2D]["LineStrips2D:strips"].rows == N_KEYFRAMES
    assert instances["/" + bp.PLANES_2D]["LineStrips2D:strips"].instances == polygons
    # one line per observation associated with a face, in the keyframe that saw it
    matched = sum(a.face is not None for r in results for a in r.associations)
    assert instances["/" + bp.ASSOCIATIONS]["LineStrips3D:strips"].instances == matched


def test_time_series_cover_every_keyframe(online_rrd):
    path, _ = online_rrd
    counts = row_counts(path)
    for name in ("latency_ms/backend", "associations/matched_landmarks", "extrinsic_deg/change", "extrinsic_cm/sigma",
                 "position_error_cm/corrected", "position_error_cm/raw", "extrinsic_deg/error", "extrinsic_cm/error"):
        assert counts[f"/{bp.METRICS}/{name}"]["Scalars:scalars"] == N_KEYFRAMES, name
    # the extrinsic's one-sigma is one series per axis
    assert component_counts(path)[f"/{bp.METRICS}/extrinsic_cm/sigma"]["Scalars:scalars"].instances == 3 * N_KEYFRAMES


def albedo_rows(path, entity: str) -> list[tuple[int, tuple]]:
    """(keyframe, RGBA) of each colour the recording gives the face mesh at `entity`."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    rows = []
    for chunk in reader.store(store=reader.recordings()[0]).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if "Mesh3D:albedo_factor" not in batch.schema.names:
            continue
        for k, colours in zip(batch.column("keyframe").to_pylist(), batch.column("Mesh3D:albedo_factor").to_pylist()):
            if colours:
                rows.append((k, tuple((int(colours[0]) >> shift) & 255 for shift in (24, 16, 8, 0))))  # (packed 0xRRGGBBAA)
    return sorted(rows, key=lambda row: row[0])  # (stable: changes at one keyframe stay in order)


def test_face_colours_follow_the_backend(online_rrd, scene):
    """Each face starts unobserved; a face turns associated at the first keyframe whose
    result matches a plane to it, and no other face ever does; the face marked deviating
    ends so; a row is a change of colour."""
    path, results = online_rrd
    first_match = {}
    for r in results:
        for a in r.associations:
            if a.face is not None:
                first_match.setdefault(a.face, r.index)
    assert len(first_match) >= 4  # the backend did associate: the test is not vacuous
    cfg = ViewerConfig()
    colour = {state: tuple(cfg.colour(state)) for state in ("unobserved", "observed", "associated", "deviating")}
    faces = [f.id for f in scene.plane_map.faces]
    for face in faces:
        rows = albedo_rows(path, "/" + face_entity(face))
        colours = [c for _, c in rows]
        assert colours[0] == colour["unobserved"], face
        assert all(a != b for a, b in zip(colours, colours[1:])), face
        associated = [k for k, c in rows if c == colour["associated"]]
        if face in first_match and face != faces[0]:
            assert associated and associated[0] == first_match[face], face
        elif face not in first_match:
            assert not associated, face
    assert albedo_rows(path, "/" + face_entity(faces[0]))[-1][1] == colour["deviating"]


def test_blueprint_has_3d_camera_and_time_series_views(online_rrd):
    path, _ = online_rrd
    names = {c for e, cols in row_counts(path, store="blueprint").items() for c in cols}
    assert "ViewBlueprint:class_identifier" in names
    views = [e for e, cols in row_counts(path, store="blueprint").items() if "ViewBlueprint:class_identifier" in cols]
    assert len(views) == 2 + len(bp.SERIES)  # 3-D, camera, the time series
    overrides = [e for e in row_counts(path, store="blueprint") if "/overrides/" in e]
    assert {o.split("/overrides/")[1].removesuffix("/visualizers") for o in overrides} == set(bp.TRAILS)


def test_offline_run_logs_every_keyframe(scene, tmp_path):
    path = tmp_path / "offline.rrd"
    viewer = RerunViewer(open_recording(path), scene.plane_map, scene.initial.T_B_S, camera=CAMERA)
    listener = RerunListener(viewer)
    results = run_offline(list(scene.keyframes), scene.plane_map, BackendConfig(), scene.initial,
                          listener=listener)
    viewer.close()
    verify(path)
    counts = row_counts(path)
    assert counts["/" + bp.CORRECTED]["LineStrips3D:strips"] == len(results.indices) - 1
    assert "/" + bp.TRUTH not in counts and f"/{bp.METRICS}/position_error_cm/corrected" not in counts
    assert f"/{bp.METRICS}/latency_ms/backend" not in counts  # offline has no per-keyframe latency


def test_depth_images_are_logged_in_the_camera_view(scene, tmp_path):
    import cv2

    (tmp_path / "depth").mkdir()
    keyframes = []
    for kf in scene.keyframes[:6]:
        if kf.index % 2 == 0:  # every other keyframe has a depth image
            name = f"depth/{kf.index}.png"
            cv2.imwrite(str(tmp_path / name), np.full((48, 64), 5000 + kf.index, dtype=np.uint16))
            kf = kf.model_copy(update={"depth": name})
        keyframes.append(kf)
    camera = Camera(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    path = tmp_path / "depth.rrd"
    viewer = RerunViewer(open_recording(path, camera=camera), scene.plane_map, scene.initial.T_B_S, camera=camera)
    listener = RerunListener(viewer, tmp_path)
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial, listener=listener)
    for kf in keyframes:
        backend.process(kf)
    viewer.close()
    counts = row_counts(path)
    assert counts["/" + bp.IMAGE]["DepthImage:buffer"] == 3
    assert counts["/" + bp.IMAGE]["Pinhole:image_from_camera"] == 1
