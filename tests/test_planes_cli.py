"""`bimgraph planes` end to end: a TUM RGB-D folder with some bad frames, then the sequence."""

import json
import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli_errors import assert_one_line_error
from synthetic_sequence import write_sequence
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
    for kf_before, kf_after in zip(before.keyframes, after.keyframes):
        for a, b in zip(kf_before.planes, kf_after.planes):
            np.testing.assert_allclose(a.plane, b.plane, atol=1e-9)
            np.testing.assert_allclose(a.cov, b.cov, atol=1e-12)


def test_planes_again_from_the_trajectory_keeps_what_the_user_added(tmp_path):
    """The README's workflow: `planes -t`, then `model` and `initial_alignment` added to
    sequence.json by hand, then `planes -t` again (another trajectory, other settings): the
    second run replaced sequence.json and lost them."""
    make_tum_folder(tmp_path, count=2)
    args = ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--fx", "525", "--fy", "525", "--cx", "319.5", "--cy", "239.5"]
    assert runner.invoke(app, args).exit_code == 0
    meta = json.loads((tmp_path / "sequence.json").read_text())
    meta.update(model="planes.json", gravity_aligned=True,
                initial_alignment={"T_B_S": [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0], "sigma_rot_deg": 2.0, "sigma_trans_m": 0.2})
    (tmp_path / "sequence.json").write_text(json.dumps(meta))
    args[args.index("--fx") + 1] = "530"
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    kept = load_sequence(tmp_path).meta
    assert kept.model == "planes.json" and kept.gravity_aligned and kept.initial_alignment.T_B_S[:2] == (1.0, 2.0)
    assert kept.camera.fx == 530
    assert "keeps its initial_alignment" in again.stderr  # (which a trajectory in another frame S voids)
    # an earlier camera the checks now refuse does not block the run that replaces it
    meta = json.loads((tmp_path / "sequence.json").read_text())
    meta["camera"]["cx"] = -5.0
    (tmp_path / "sequence.json").write_text(json.dumps(meta))
    assert runner.invoke(app, args).exit_code == 0 and load_sequence(tmp_path).meta.camera.cx == 319.5


def test_planes_refuses_a_principal_point_outside_the_image_and_an_empty_trajectory(tmp_path):
    make_tum_folder(tmp_path, count=2)
    args = ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--fx", "525", "--fy", "525", "--cx", "-5", "--cy", "239.5"]
    assert_one_line_error(runner.invoke(app, args), 4, "the principal point (-5.0, 239.5) lies outside the 640x480 image")
    (tmp_path / "empty.txt").write_text("# no poses\n")
    args[3], args[args.index("--cx") + 1] = str(tmp_path / "empty.txt"), "319.5"
    assert_one_line_error(runner.invoke(app, args), 3, "empty.txt: no poses (an empty trajectory)")
    assert not (tmp_path / "sequence.json").exists()


def test_planes_errors(tmp_path):
    assert_one_line_error(runner.invoke(app, ["planes", str(tmp_path / "absent")]), 2, "absent: no such folder")
    (tmp_path / "sequence.json").write_text("{}")
    assert_one_line_error(runner.invoke(app, ["planes", str(tmp_path / "sequence.json")]), 2, "sequence.json: a file, not a folder")
    (tmp_path / "sequence.json").unlink()
    result = runner.invoke(app, ["planes", str(tmp_path)])
    assert result.exit_code == 2 and "for a TUM RGB-D folder give --trajectory" in result.output
    result = runner.invoke(app, ["planes", str(tmp_path), "--fx", "500"])
    assert result.exit_code == 4 and "all four of --fx --fy --cx --cy" in result.output
    make_tum_folder(tmp_path, count=1)
    result = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt")])
    assert result.exit_code == 2 and "no intrinsics" in result.output


def test_a_sequence_without_depth_images_is_refused_and_kept(tmp_path):
    """It rewrote keyframes.jsonl with every detection removed."""
    write_sequence(tmp_path, 8, rooms=(1, 1))  # plane detections only, as `bimgraph simulate --sensor planes` writes
    before = {name: (tmp_path / name).read_bytes() for name in ("keyframes.jsonl", "sequence.json")}
    assert b'"planes": [{' in before["keyframes.jsonl"]
    result = runner.invoke(app, ["planes", str(tmp_path)])
    assert_one_line_error(result, 2, "no keyframe has a depth image", "nothing written")
    assert {name: (tmp_path / name).read_bytes() for name in before} == before


def test_a_keyframe_without_a_depth_image_keeps_its_planes(tmp_path):
    from bimgraph.sequence.format import PlaneObservation, save_sequence

    make_tum_folder(tmp_path, count=2)
    assert runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--fx", "525", "--fy", "525",
                               "--cx", "319.5", "--cy", "239.5"]).exit_code == 0
    seq = load_sequence(tmp_path)
    plane = PlaneObservation(n=(0.0, 0.0, -1.0), d=2.0)
    seq.keyframes[0] = seq.keyframes[0].model_copy(update={"depth": None, "planes": [plane]})
    save_sequence(seq)
    result = runner.invoke(app, ["planes", str(tmp_path)])
    assert result.exit_code == 0, result.output
    after = load_sequence(tmp_path)
    assert after.keyframes[0].planes == [plane] and after.keyframes[1].planes


def test_a_failure_mid_extraction_leaves_the_keyframes_file_as_it_was(tmp_path, monkeypatch):
    from bimgraph.planes.extractor import PlaneExtractor

    make_tum_folder(tmp_path, count=3)
    assert runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--fx", "525", "--fy", "525",
                               "--cx", "319.5", "--cy", "239.5"]).exit_code == 0
    before = (tmp_path / "keyframes.jsonl").read_bytes()
    extract, calls = PlaneExtractor.extract, []

    def failing(self, depth):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return extract(self, depth)

    monkeypatch.setattr(PlaneExtractor, "extract", failing)
    result = runner.invoke(app, ["planes", str(tmp_path)])
    assert result.exit_code == 130 and len(calls) == 2
    assert (tmp_path / "keyframes.jsonl").read_bytes() == before
    assert not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


def test_depth_images_that_give_no_plane_leave_the_keyframes_file_as_it_was(tmp_path):
    """Every frame skipped (the depth images moved away), or none with a plane: it said "0
    planes in N frames", exit 0, and wrote every keyframe without its planes."""
    make_tum_folder(tmp_path, count=3)
    pinhole = ["--fx", "525", "--fy", "525", "--cx", "319.5", "--cy", "239.5"]
    assert runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), *pinhole]).exit_code == 0
    before = (tmp_path / "keyframes.jsonl").read_bytes()
    (tmp_path / "depth").rename(tmp_path / "moved")
    assert_one_line_error(runner.invoke(app, ["planes", str(tmp_path)]), 2,
                          "no plane found in any of the 3 depth images (every one was skipped; the first: ",
                          "no such depth image); nothing written")
    (tmp_path / "moved").rename(tmp_path / "depth")
    (tmp_path / "few.yaml").write_text("planes:\n  min_area_m2: 1000000\n")
    assert_one_line_error(runner.invoke(app, ["planes", str(tmp_path), "-c", str(tmp_path / "few.yaml")]), 2,
                          "no plane found in any of the 3 depth images (check the intrinsics")
    assert (tmp_path / "keyframes.jsonl").read_bytes() == before


@pytest.mark.parametrize("order", ["repeated", "reversed"])
def test_a_depth_list_out_of_time_order_is_refused_naming_the_line(tmp_path, order):
    """It wrote keyframes that `run` then refused ("stamp 0.857143 does not follow 0.857143")."""
    make_tum_folder(tmp_path, count=3)
    lines = (tmp_path / "depth.txt").read_text().splitlines()
    header, images = lines[:2], lines[2:]
    images = images[:2] + images[1:] if order == "repeated" else images[::-1]
    (tmp_path / "depth.txt").write_text("\n".join(header + images) + "\n")
    result = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), "--fx", "525", "--fy", "525",
                                 "--cx", "319.5", "--cy", "239.5"])
    assert_one_line_error(result, 3, f"depth.txt: line {5 if order == 'repeated' else 4}: stamp ", "(list each image once, in time order)")
    assert not (tmp_path / "keyframes.jsonl").exists()


@pytest.mark.parametrize("options, message", [
    (["--fx", "-500", "--fy", "500", "--cx", "320", "--cy", "240"], "fx: Input should be greater than 0"),
    (["--fx", "nan", "--fy", "500", "--cx", "320", "--cy", "240"], "fx: Input should be a finite number"),
    # (fx 1e-9 px gave planes of 1e22 m2)
    (["--fx", "1e-9", "--fy", "1e-9", "--cx", "320", "--cy", "240"], "field of view of 180.0 degrees (at most 170)"),
    (["--fx", "500", "--fy", "500", "--cx", "320", "--cy", "240", "--max-dt", "-1"], "--max-dt must be at least 0"),
])
def test_bad_option_values_are_one_line_exit_4(tmp_path, options, message):
    make_tum_folder(tmp_path, count=1)
    result = runner.invoke(app, ["planes", str(tmp_path), "-t", str(tmp_path / "traj.txt"), *options])
    assert_one_line_error(result, 4, message)
    assert not (tmp_path / "keyframes.jsonl").exists()
