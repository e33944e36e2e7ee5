"""TUM RGB-D reading and writing: 16-bit depth PNGs, image lists, intrinsics, association."""

import json

import cv2
import numpy as np
import pytest

from depth_scenes import CAMERA, room, viewpoints

from bimgraph.errors import FormatError, InputError
from bimgraph.sequence.format import load_sequence, save_sequence
from bimgraph.sequence.tum import write_tum
from bimgraph.sequence.tum_rgbd import (
    load_camera, load_tum_rgbd, nearest, read_depth_png, read_image_list, write_depth_png, write_image_list,
)
from bimgraph.sim.render import DepthRenderer


def test_depth_png_round_trip(tmp_path):
    depth = np.array([[0.0, 1.23456, 13.107], [13.2, -1.0, np.nan]])
    write_depth_png(tmp_path / "d.png", depth)
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw[0, 1] == 6173  # 1.23456 m * 5000, rounded
    back = read_depth_png(tmp_path / "d.png")
    assert back[0, 1] == pytest.approx(1.2346)
    assert back[0, 2] == pytest.approx(13.107)
    # Beyond 65535 / 5000 m, negative and NaN: no return.
    assert back[1].tolist() == [0.0, 0.0, 0.0] and back[0, 0] == 0.0


@pytest.mark.parametrize("image, message", [
    (np.full((4, 4), 200, np.uint8), "8-bit uint8, must be 16-bit"),
    (np.full((4, 4, 3), 2000, np.uint16), "3 channels"),
])
def test_depth_png_wrong_kind(tmp_path, image, message):
    cv2.imwrite(str(tmp_path / "bad.png"), image)
    with pytest.raises(InputError, match=message):
        read_depth_png(tmp_path / "bad.png")


def test_unreadable_and_missing_depth(tmp_path):
    (tmp_path / "x.png").write_text("not a png")
    with pytest.raises(InputError, match="not a readable image"):
        read_depth_png(tmp_path / "x.png")
    with pytest.raises(InputError, match="no such depth image"):
        read_depth_png(tmp_path / "missing.png")


def test_image_list(tmp_path):
    write_image_list(tmp_path / "depth.txt", [1.5, 2.25], ["depth/1.png", "depth/2.png"], "depth")
    stamps, names = read_image_list(tmp_path / "depth.txt")
    assert stamps.tolist() == [1.5, 2.25] and names == ["depth/1.png", "depth/2.png"]
    (tmp_path / "bad.txt").write_text("# c\n1.0 a.png\nx b.png\n")
    with pytest.raises(FormatError, match="line 3: stamp 'x'"):
        read_image_list(tmp_path / "bad.txt")
    # float() takes "inf": it went into a keyframe, a ValidationError traceback
    (tmp_path / "bad.txt").write_text("1.0 a.png\ninf b.png\n")
    with pytest.raises(FormatError, match="line 2: stamp 'inf' is not a finite number"):
        read_image_list(tmp_path / "bad.txt")
    # nanoseconds went into a keyframe: a ValidationError traceback
    (tmp_path / "bad.txt").write_text("1.0 a.png\n1700000000000000000 b.png\n")
    with pytest.raises(FormatError, match="line 2: stamp 1.7e[+]18 is not in seconds .it looks like nanoseconds"):
        read_image_list(tmp_path / "bad.txt")


def test_nearest_association():
    stamps = np.array([3.0, 1.0, 2.0])
    assert nearest(np.array([0.99, 2.015, 2.5, 3.03]), stamps, 0.02).tolist() == [1, 2, -1, -1]
    assert nearest(np.array([1.0]), np.zeros(0), 0.02).tolist() == [-1]


def test_camera_files(tmp_path):
    (tmp_path / "cam.yaml").write_text("width: 640\nheight: 480\nfx: 525\nfy: 525\ncx: 319.5\ncy: 239.5\n")
    assert load_camera(tmp_path / "cam.yaml").fx == 525
    (tmp_path / "cam.json").write_text(json.dumps({"width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 0, "cy": 0, "depth_scale": 1000}))
    assert load_camera(tmp_path / "cam.json").depth_scale == 1000
    (tmp_path / "bad.yaml").write_text("width: 640\nfx: 525\n")
    with pytest.raises(FormatError, match="bad.yaml: height"):
        load_camera(tmp_path / "bad.yaml")


def make_tum_folder(folder, count=4, offset_s=0.004):
    """A TUM RGB-D folder of rendered room depth, and a trajectory whose stamps are a few ms off."""
    scene = room()
    renderer = DepthRenderer(*scene.arrays())
    poses = viewpoints(np.random.default_rng(11), count)
    stamps = 1000.0 + 0.5 * np.arange(count)
    names = [f"depth/{s:.6f}.png" for s in stamps]
    for name, T_B_C in zip(names, poses):
        write_depth_png(folder / name, renderer.render(CAMERA, T_B_C)[0])
    write_image_list(folder / "depth.txt", stamps, names, "depth")
    write_tum(folder / "traj.txt", stamps + offset_s, poses)
    return scene, stamps, poses


def test_load_tum_rgbd(tmp_path):
    scene, stamps, poses = make_tum_folder(tmp_path)
    write_tum(tmp_path / "short.txt", stamps[:2] + 0.004, poses[:2])
    seq = load_tum_rgbd(tmp_path, tmp_path / "short.txt", CAMERA)
    assert [kf.stamp for kf in seq.keyframes] == stamps[:2].tolist()
    assert np.allclose(seq.keyframes[1].pose, poses[1], atol=1e-8)
    assert seq.meta.camera == CAMERA and seq.meta.sensor == "depth"
    save_sequence(seq)
    again = load_sequence(tmp_path)
    assert read_depth_png(again.root / again.keyframes[0].depth).shape == (480, 640)
    # Saved elsewhere, the image paths stay valid.
    other = load_tum_rgbd(tmp_path, tmp_path / "traj.txt", CAMERA, root=tmp_path / "out")
    assert (other.root / other.keyframes[3].depth).resolve() == (tmp_path / f"depth/{stamps[3]:.6f}.png").resolve()
    with pytest.raises(InputError, match="no pose within 0.001 s"):
        load_tum_rgbd(tmp_path, tmp_path / "traj.txt", CAMERA, max_dt=0.001)


def test_binary_or_broken_text_files_are_one_line_format_errors(tmp_path):
    """A binary file given by mistake was a UnicodeDecodeError traceback; PyYAML's error five lines."""
    from bimgraph.sequence.tum import read_tum

    binary = b"\x7fELF\x02\x01\x01\x00\xf0\x9f\x00\x00"
    for name, read in [("traj.txt", read_tum), ("depth.txt", read_image_list), ("cam.yaml", load_camera)]:
        (tmp_path / name).write_bytes(binary)
        with pytest.raises(FormatError, match=f"{name}: not a text file$"):
            read(tmp_path / name)
    (tmp_path / "cam.yaml").write_text("width: 640\nfx: [525\nfy: 525\n")
    with pytest.raises(FormatError) as err:
        load_camera(tmp_path / "cam.yaml")
    assert str(err.value).endswith("cam.yaml: line 3: invalid YAML (expected ',' or ']', but got ':')")
