"""Warnings about sequences the format accepts but the backend cannot use as their writer
likely meant (`bimgraph.sequence.checks`), and `bimgraph run` printing them."""

import numpy as np
from test_run import run, world  # noqa: F401 (a fixture)

from bimgraph.sequence.checks import sequence_warnings
from bimgraph.sequence.format import Keyframe, Sequence, load_sequence, save_sequence

STEP = np.diag([1e-6] * 3 + [1e-5] * 3)


def keyframes(covs, polygon=True):
    plane = {"n": (1.0, 0.0, 0.0), "d": 2.0}
    if polygon:
        plane["polygon"] = [(-2.0, 0.0, 0.0), (-2.0, 1.0, 0.0), (-2.0, 0.0, 1.0)]
    return [Keyframe(index=k, stamp=float(k), T_S_C=(float(k), 0, 0, 0, 0, 0, 1), cov=None if c is None else c.tolist(),
                     planes=[plane]) for k, c in enumerate(covs)]


def test_a_pose_covariance_growing_along_the_walk_is_told_from_a_step_covariance():
    growing = sequence_warnings(keyframes([STEP * (k + 1) for k in range(40)]))
    assert len(growing) == 1 and "grows along the walk (20x" in growing[0] and "step from the previous keyframe" in growing[0]
    assert sequence_warnings(keyframes([STEP] * 40)) == []
    assert sequence_warnings(keyframes([None] * 40)) == []
    # noisy but steady step covariances, as a real front-end's
    rng = np.random.default_rng(0)
    assert sequence_warnings(keyframes([STEP * rng.uniform(0.5, 5.0) for _ in range(40)])) == []


def test_planes_without_polygons_are_counted():
    (warning,) = sequence_warnings(keyframes([None] * 5, polygon=False))
    assert warning.startswith("5 of 5 plane detections have no polygon")
    # a floor's detections may lack one: not most
    assert sequence_warnings(keyframes([None] * 5, polygon=False) + keyframes([None] * 5)) == []


def test_keyframes_far_from_the_origin_of_s_are_told():
    """A walk 100 km from S's origin (coordinates of a map projection) failed with a traceback
    from the robust alignment's Cholesky, and at 10 km with "covariances far overconfident"."""
    far = [kf.model_copy(update={"T_S_C": (kf.T_S_C[0] + 1e5, 2e4, *kf.T_S_C[2:])}) for kf in keyframes([None] * 5)]
    (warning,) = sequence_warnings(far)
    assert warning.startswith("keyframes lie up to 102 km from the origin of S") and "subtract the first keyframe" in warning
    assert sequence_warnings(keyframes([None] * 5)) == []
    # a walk that jumps away names the keyframe where it does (a front-end's glitch)
    jump = keyframes([None] * 5)
    jump[3:] = [kf.model_copy(update={"T_S_C": (kf.T_S_C[0] + 1e6, *kf.T_S_C[1:])}) for kf in jump[3:]]
    (warning,) = sequence_warnings(jump)
    assert f"from keyframe {jump[3].index} on (stamp {jump[3].stamp})" in warning


def walk_looking_around(up_S=(0.0, 0.0, 1.0), camera_y_down=True, wxyz=False):
    """Keyframes of an OpenCV camera turning on the spot, level, in a z-up S; or as written
    with S y-up (`up_S` (0, 1, 0)), with OpenGL's camera axes, or with the quaternion w x y z."""
    from scipy.spatial.transform import Rotation

    from bimgraph.geometry import pose_to_tum

    up = np.asarray(up_S)
    R_S_Szup = Rotation.align_vectors([up], [[0.0, 0.0, 1.0]])[0].as_matrix()
    out = []
    for k, yaw in enumerate(np.linspace(0.0, 2 * np.pi, 40, endpoint=False)):
        forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        R = np.column_stack([np.cross(down, forward), down, forward])  # x right, y down, z forward
        if not camera_y_down:
            R = R @ np.diag([1.0, -1.0, -1.0])
        pose = pose_to_tum(np.block([[R_S_Szup @ R, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
        if wxyz:
            pose = np.r_[pose[:3], pose[6], pose[3:6]]
        out.append(Keyframe(index=k, stamp=float(k), T_S_C=tuple(pose), planes=[]))
    return out


def test_frame_conventions_gone_wrong_are_told_where_s_has_z_up():
    """An AR tracker's y-up world, OpenGL's camera axes, a quaternion written w x y z: each
    ran without a word, matched no wall, and the hint blamed the initial alignment."""
    from bimgraph.sequence.format import InitialAlignment, SequenceMeta

    gravity = SequenceMeta(gravity_aligned=True)
    assert sequence_warnings(walk_looking_around(), gravity) == []
    for wrong in (walk_looking_around(up_S=(0.0, 1.0, 0.0)), walk_looking_around(camera_y_down=False),
                  walk_looking_around(wxyz=True)):
        (warning,) = sequence_warnings(wrong, gravity)
        assert "gravity_aligned is true, yet in" in warning and "image's down axis (C's y) does not point down in S" in warning
        assert sequence_warnings(wrong, SequenceMeta()) == []  # (S's axes unknown: nothing to tell)
    tilted = gravity.model_copy(update={"initial_alignment": InitialAlignment(T_B_S=(0, 0, 0, 0.5, 0.5, 0.5, 0.5))})
    (warning,) = sequence_warnings(walk_looking_around(), tilted)
    assert warning.startswith("gravity_aligned is true, yet initial_alignment's T_B_S tilts S's z 90 deg from B's")
    turned = gravity.model_copy(update={"initial_alignment": InitialAlignment(T_B_S=(5, 0, 0, 0, 0, 0.6, 0.8))})
    assert sequence_warnings(walk_looking_around(), turned) == []


def test_a_step_covariance_no_front_end_has_is_told():
    """1e-12 a step was taken at its word: five sound walls judged off plan, 11 cm off."""
    (warning,) = sequence_warnings(keyframes([STEP * 1e-6] * 10))
    assert warning.startswith("the keyframes' cov gives a step's sigmas of 5.7e-05 deg and 0.0032 mm (median)")
    assert sequence_warnings(keyframes([STEP] * 10)) == []


def test_stamps_in_units_smaller_than_seconds_are_told():
    """Milliseconds from 1000 on (or nanoseconds since a phone's boot) pass as seconds."""
    slow = [kf.model_copy(update={"stamp": 1000.0 + 100.0 * kf.index}) for kf in keyframes([None] * 5)]
    (warning,) = sequence_warnings(slow)
    assert warning.startswith("keyframes lie 100 s apart (median): stamps are seconds; divide milliseconds by 1e3")


def test_planes_in_millimetres_are_told():
    """Distances in millimetres put every wall kilometres off: nothing matched, and the walls
    reported possibly not built, without a word on why."""
    in_mm = [kf.model_copy(update={"planes": [p.model_copy(update={"d": 1000.0 * p.d, "polygon": None}) for p in kf.planes]})
             for kf in keyframes([None] * 5)]
    assert any(w.startswith("the planes lie a median 2e+03 m from the camera: d is in metres") for w in sequence_warnings(in_mm))
    assert not any("median" in w and "camera" in w for w in sequence_warnings(keyframes([None] * 5)))


def test_a_plane_map_far_from_b_s_origin_is_told():
    """A hand-written map in site coordinates 3.6 km out made every run singular ("a variable
    no factor constrains"); one in millimetres reads alike."""
    from bimgraph.backend.synthetic import make_scene
    from bimgraph.bim.planemap import PlaneMap

    plane_map = make_scene(5, rooms=(1, 1), seed=0).plane_map
    assert plane_map.far_warning() is None
    t = np.array([3000.0, 2000.0, 0.0])
    moved = PlaneMap(faces=[f.model_copy(update={
        "polygon": [tuple(np.add(p, t)) for p in f.polygon], "holes": [[tuple(np.add(p, t)) for p in h] for h in f.holes],
        "offset": f.offset - float(np.dot(f.normal, t)), "centre": tuple(np.add(f.centre, t))}) for f in plane_map.faces])
    assert moved.far_warning().startswith("the plane map's faces lie up to 3.61 km from B's origin")


def test_the_run_prints_the_warning(world, tmp_path):
    _, root = world
    sequence = load_sequence(root)
    grown = [kf.model_copy(update={"cov": tuple(map(tuple, STEP * (k + 1)))}) for k, kf in enumerate(sequence.keyframes)]
    save_sequence(Sequence(root=tmp_path / "seq", meta=sequence.meta.model_copy(update={"model": str(root / "planes.json")}),
                           keyframes=grown))
    result = run(tmp_path / "seq", "-o", tmp_path / "out", "--mode", "offline")
    assert result.exit_code == 0, result.output
    assert "the keyframes' cov grows along the walk" in " ".join(result.output.split())
