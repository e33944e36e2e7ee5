"""`bimgraph planes` end to end: a TUM RGB-D folder with some bad frames, then the sequence."""

import cv2
import numpy as np
from typer.testing import CliRunner

from test_planes_tum import make_tum_folder

from bimgraph.cli import app
from bimgraph.geometry import inverse, normal_angle_deg, plane_to_frame
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.tum import write_tum
from bimgraph.sequence.tum_rgbd import read_image_list, write_image_list

runner = CliRunner()


def add_bad_frames(folder):
    """Append an all-zero frame, an 8-bit frame and a missing file to the TUM folder."""
    stamps, names = read_image_list(folder / "depth.txt")
    bad = {"depth/zero.png": np.zeros((480, 640), np.uint16), "depth/byte.png": np.full((480, 640), 9, np.uint8)}
    for name, image in bad.items():
        cv2.imwrite(str(folder / name), image)
    extra = [stamps[-1] + 0.5 * (i + 1) for i in range(3)]
    write_image_list(folder / "depth.txt", [*stamps, *extra], [*names, *bad, "depth/missing.png"], "depth")
    return extra


def test_planes_on_tum_folder(tmp_path):
    scene, stamps, poses = make_tum_folder(tmp_path)
    extra = add_bad_frames(tmp_path)
    # Ground-truth poses as the SLAM trajectory: S = B.
    write_tum(tmp_path / "traj.txt", [*stamps, *extra], [*poses, *[poses[0]] * 3])
    (tmp_path / "cam.yaml").write_text("width: 640\nheight: 480\nfx: 525\nfy: 525\ncx: 319.5\ncy: 239.5\n")
    result = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--intrinsics", str(tmp_path / "cam.yaml")])
    assert result.exit_code == 0, result.output
    assert "zero.png: no valid depth (all pixels are 0)" in result.output
    assert "byte.png: depth image is 8-bit uint8, must be 16-bit" in result.output
    assert "missing.png: no such depth image" in result.output
    seq = load_sequence(tmp_path)
    assert len(seq.keyframes) == 7
    assert all(kf.planes for kf in seq.keyframes[:4]) and not any(kf.planes for kf in seq.keyframes[4:])
    walls_B = np.array(list(scene.planes_B.values()))
    for kf in seq.keyframes[:4]:
        T_C_B = inverse(kf.pose)
        for obs in kf.planes:
            plane_B = plane_to_frame(obs.plane, T_C_B)
            err = [normal_angle_deg(plane_B[:3], w[:3]) + 100 * abs(plane_B[3] - w[3]) for w in walls_B]
            assert min(err) < 1.0  # degrees + centimetres: on a face of the room
            assert obs.cov is not None and obs.polygon and obs.inliers > 0 and obs.area > 0


def test_planes_on_sequence_with_pinhole_options(tmp_path):
    make_tum_folder(tmp_path, count=2)
    first = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"),
                                "--fx", "525", "--fy", "525", "--cx", "319.5", "--cy", "239.5"])
    assert first.exit_code == 0, first.output
    before = load_sequence(tmp_path)
    assert before.meta.camera.width == 640
    # The saved sequence knows its camera; running again gives the same planes.
    again = runner.invoke(app, ["planes", str(tmp_path)])
    assert again.exit_code == 0, again.output
    after = load_sequence(tmp_path)
    assert [len(kf.planes) for kf in after.keyframes] == [len(kf.planes) for kf in before.keyframes]


def test_planes_errors(tmp_path):
    result = runner.invoke(app, ["planes", str(tmp_path)])
    assert result.exit_code == 4 and "for a TUM RGB-D folder give --trajectory" in result.output
    result = runner.invoke(app, ["planes", str(tmp_path), "--fx", "500"])
    assert result.exit_code == 4 and "all four of --fx --fy --cx --cy" in result.output
    make_tum_folder(tmp_path, count=1)
    result = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt")])
    assert result.exit_code == 2 and "no intrinsics" in result.output
