"""`bimgraph run --rrd` and `bimgraph view`, end to end on a sequence folder written from the
backend's synthetic scene (plane map JSON, ground truth), read back with rerun's reader."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from typer.testing import CliRunner

from cli_errors import assert_one_line_error
from conftest import load_script
from synthetic_sequence import write_sequence

os.environ.setdefault("RERUN_ANALYTICS", "0")

from bimgraph.cli import app  # noqa: E402
from bimgraph.config import ViewerConfig  # noqa: E402
from bimgraph.deviations.report import (  # noqa: E402
    JSON_FILE,
    DeviationsFile,
    ExplanationRecord,
    FaceRecord,
    ThicknessRecord,
    WidthRecord,
)
from bimgraph.files import write_json  # noqa: E402
from bimgraph.viewer import blueprint as bp  # noqa: E402
from bimgraph.viewer.rerun_viewer import face_entity  # noqa: E402
from bimgraph.viewer.rrd import component_counts, row_counts, verify  # noqa: E402

N_KEYFRAMES = 60


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer_cli") / "seq"
    return root, write_sequence(root, N_KEYFRAMES)


def scalars(path, entity):
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(path)).store().stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if "Scalars:scalars" in batch.schema.names:
                rows += list(zip(batch.column("keyframe").to_pylist(), batch.column("Scalars:scalars").to_pylist()))
    return np.array([v for _, v in sorted(rows)])


def albedo(path, entity):
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(path)).store().stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if "Mesh3D:albedo_factor" in batch.schema.names and "keyframe" in batch.schema.names:
                rows += list(zip(batch.column("keyframe").to_pylist(), batch.column("Mesh3D:albedo_factor").to_pylist()))
    return [v[0] for _, v in sorted(rows, key=lambda r: r[0])]


def rgba_u32(colour):
    r, g, b, a = colour
    return (r << 24) | (g << 16) | (b << 8) | a


@pytest.fixture(scope="module")
def online_run(seq_dir):
    root, _ = seq_dir
    out = root.parent / "out"
    result = CliRunner().invoke(app, ["run", str(root), "-o", str(out), "--rrd", str(out / "run.rrd")])
    assert result.exit_code == 0, result.output
    return out


def test_run_rrd_holds_the_whole_run(online_run, seq_dir):
    _, scene = seq_dir
    path = online_run / "run.rrd"
    verify(path)
    counts = row_counts(path)
    assert sum("Mesh3D:vertex_positions" in c for c in counts.values()) == len(scene.plane_map.faces)
    for trail in (bp.RAW, bp.CORRECTED, bp.TRUTH):
        assert counts["/" + trail]["LineStrips3D:strips"] == N_KEYFRAMES - 1
    for name in ("latency_ms/backend", "position_error_cm/corrected", "extrinsic_cm/error", "extrinsic_cm/sigma"):
        assert counts[f"/{bp.METRICS}/{name}"]["Scalars:scalars"] == N_KEYFRAMES, name
    # the viewer follows the real run: its error series say the correction worked
    corrected, raw = scalars(path, f"/{bp.METRICS}/position_error_cm/corrected"), scalars(path, f"/{bp.METRICS}/position_error_cm/raw")
    assert corrected[-1] < raw[-1]
    # the extrinsic's sigmas along B's axes, as extrinsic.json's sigma_trans_B_m (they were along S's)
    sigma_cm = scalars(path, f"/{bp.METRICS}/extrinsic_cm/sigma")[-1]
    np.testing.assert_allclose(sigma_cm, 100 * np.array(json.loads((online_run / "extrinsic.json").read_text())["sigma_trans_B_m"]),
                               rtol=1e-5)


def test_view_replays_the_outputs(online_run, seq_dir):
    root, scene = seq_dir
    faces = [f.id for f in scene.plane_map.faces]

    def face(i, status):
        return FaceRecord(face_id=faces[i], wall_guid="w", status=status, offset_m=0.05, offset_sigma_m=0.01, tilt_deg=0.1,
                          tilt_sigma_deg=0.1)

    write_json(online_run / JSON_FILE, DeviationsFile(
        tolerance_m=0.02, tilt_tolerance_deg=0.5, k_sigma=2.0, unplanned=[],
        faces=[face(1, "deviating"), face(2, "within_tolerance"), face(3, "not_enough_evidence")],
        contested=[ExplanationRecord(probability=0.6, deviating=[face(3, "deviating")]),
                   ExplanationRecord(probability=0.4, deviating=[face(1, "deviating")])],
        widths=[WidthRecord(space_guid="room", faces=(faces[1], faces[2]), planned_m=4.0, built_m=3.94, sigma_m=0.004,
                            n_keyframes=9, status="deviating")],
        thicknesses=[ThicknessRecord(wall_guid="w", faces=(faces[1], faces[3]), planned_m=0.2, built_m=0.26, sigma_m=0.005,
                                     n_keyframes=9, status="deviating"),
                     ThicknessRecord(wall_guid="w", faces=(faces[2], faces[3]), planned_m=0.2, built_m=0.2, sigma_m=0.005,
                                     n_keyframes=9, status="within_tolerance")],
    ).model_dump(mode="json"))
    result = CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root), "--rrd", str(online_run / "view.rrd")])
    assert result.exit_code == 0, result.output
    run, view = online_run / "run.rrd", online_run / "view.rrd"
    verify(view)
    counts = row_counts(view)
    for trail in (bp.RAW, bp.CORRECTED, bp.TRUTH):
        assert counts["/" + trail]["LineStrips3D:strips"] == N_KEYFRAMES - 1
    # the extrinsic recovered from the two trajectory files is the one the run logged live
    for name in ("extrinsic_cm/change", "extrinsic_deg/change", "position_error_cm/corrected"):
        entity = f"/{bp.METRICS}/{name}"
        np.testing.assert_allclose(scalars(view, entity), scalars(run, entity), atol=1e-4, err_msg=name)
    colours = ViewerConfig()
    assert albedo(view, "/" + face_entity(faces[1]))[-1] == rgba_u32(colours.colour_deviating)
    assert albedo(view, "/" + face_entity(faces[2]))[-1] != rgba_u32(colours.colour_deviating)
    # a face of a contest, deviating or not by which alignment holds; a deviating face stays so
    assert albedo(view, "/" + face_entity(faces[3]))[-1] == rgba_u32(colours.colour_contested)
    assert counts["/" + bp.WIDTHS]["LineStrips3D:strips"] == 1  # the room width, across the room
    # the wall thicknesses, through their walls, at once; the one off plan labelled
    thicknesses = component_counts(view)["/" + bp.THICKNESSES]
    assert thicknesses["LineStrips3D:strips"].instances == 2 and thicknesses["LineStrips3D:labels"].instances == 2
    (online_run / JSON_FILE).unlink()


def test_a_view_that_fails_keeps_an_earlier_recording(online_run, tmp_path):
    """Every file is read before the recording is written: a broken deviation report, found
    after the keyframes were logged, had replaced an earlier recording with part of one."""
    rrd = tmp_path / "x.rrd"
    assert CliRunner().invoke(app, ["view", str(online_run), "--rrd", str(rrd)]).exit_code == 0
    before = rrd.read_bytes()
    (online_run / JSON_FILE).write_text("{")
    try:
        assert_one_line_error(CliRunner().invoke(app, ["view", str(online_run), "--rrd", str(rrd)]), 3, JSON_FILE)
    finally:
        (online_run / JSON_FILE).unlink()
    assert rrd.read_bytes() == before


def test_a_recording_never_replaces_a_file_that_is_none(online_run, seq_dir, tmp_path):
    """`--rrd` on a run's own input or output by a slip of the shell: refused, the file as it
    was (it was replaced, and the run then failed on the recording it read as its sequence)."""
    root, _ = seq_dir
    out = tmp_path / "out"
    for target in (root / "keyframes.jsonl", root / "sequence.json"):
        before = target.read_bytes()
        result = CliRunner().invoke(app, ["run", str(root), "-o", str(out), "--rrd", str(target)])
        assert_one_line_error(result, 2, f"{target}: exists and is not a Rerun recording")
        assert target.read_bytes() == before
    target = online_run / "summary.json"
    before = target.read_bytes()
    result = CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root), "--rrd", str(target)])
    assert_one_line_error(result, 2, "is not a Rerun recording")
    assert target.read_bytes() == before


def test_a_view_stopped_half_way_keeps_an_earlier_recording(online_run, seq_dir, tmp_path, monkeypatch):
    """(Ctrl-C during `view --rrd` left a complete recording cut short.)"""
    from bimgraph.viewer.rerun_viewer import RerunViewer

    root, _ = seq_dir
    rrd = tmp_path / "x.rrd"
    assert CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root), "--rrd", str(rrd)]).exit_code == 0
    before = rrd.read_bytes()
    keyframe = RerunViewer.keyframe

    def stopping(self, index, *args, **kwargs):
        if index == N_KEYFRAMES // 2:
            raise KeyboardInterrupt
        keyframe(self, index, *args, **kwargs)

    monkeypatch.setattr(RerunViewer, "keyframe", stopping)
    result = CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root), "--rrd", str(rrd)])
    assert result.exit_code == 130, result.output
    assert rrd.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.rrd"]


def test_a_run_refused_after_the_recording_opened_keeps_an_earlier_one(seq_dir, tmp_path):
    """The sequence is read whole after the recording is opened: a bad line there replaced an
    earlier recording with an empty one."""
    import shutil

    root = tmp_path / "seq"
    shutil.copytree(seq_dir[0], root)
    rrd = tmp_path / "run.rrd"
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(tmp_path / "out"), "--rrd", str(rrd)]).exit_code == 0
    before = rrd.read_bytes()
    with open(root / "keyframes.jsonl", "a") as f:
        f.write("{\n")
    result = CliRunner().invoke(app, ["run", str(root), "-o", str(tmp_path / "out"), "--rrd", str(rrd)])
    assert_one_line_error(result, 3, "keyframes.jsonl")
    assert rrd.read_bytes() == before
    assert not (tmp_path / "run.rrd.part").exists()


def test_a_run_removes_the_recording_of_the_one_before_it(seq_dir, tmp_path):
    """The summary names the recording; a later run into the folder removes it with the rest
    (it stayed, the recording of another run beside this one's outputs), but not one outside."""
    root, _ = seq_dir
    out = tmp_path / "out"
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(out), "--rrd", str(out / "run.rrd")]).exit_code == 0
    assert json.loads((out / "summary.json").read_text())["recording"] == str((out / "run.rrd").resolve())
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(out), "--rrd", str(out / "run.rrd")]).exit_code == 0
    verify(out / "run.rrd")  # (its own recording, not removed as the earlier one)
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(out)]).exit_code == 0
    assert not (out / "run.rrd").exists()
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(out), "--rrd", str(tmp_path / "kept.rrd")]).exit_code == 0
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(out)]).exit_code == 0
    verify(tmp_path / "kept.rrd")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc, where no file can be made")
def test_a_recording_that_cannot_be_written_is_one_line(online_run):
    """(rerun's own error came as a traceback, with a warning of the data it dropped.)"""
    result = CliRunner().invoke(app, ["view", str(online_run), "--rrd", "/proc/bimgraph.rrd"])
    assert_one_line_error(result, 2, "/proc/bimgraph.rrd: cannot write the recording")


def test_view_finds_the_sequence_the_run_names(online_run):
    result = CliRunner().invoke(app, ["view", str(online_run), "--rrd", str(online_run / "x.rrd")])
    assert result.exit_code == 0, result.output
    verify(online_run / "x.rrd")
    # A summary that names no sequence: one line asking for --sequence.
    summary = json.loads((online_run / "summary.json").read_text())
    del summary["sequence"]
    (online_run / "summary.json").write_text(json.dumps(summary))
    result = CliRunner().invoke(app, ["view", str(online_run), "--rrd", str(online_run / "y.rrd")])
    assert_one_line_error(result, 2, "--sequence")


def test_plot_run_draws_the_run(online_run, seq_dir, tmp_path):
    import cv2

    from bimgraph.config import Config

    plot_run = load_script("plot_run")
    png = tmp_path / "run.png"
    plot_run.plot_run(online_run, seq_dir[0], png, Config())
    image = cv2.imread(str(png))
    assert image is not None and image.shape[0] > 500
    # the corrected trajectory's blue is drawn
    blue = np.array(Config().viewer.colour_corrected[:3][::-1])  # BGR
    assert (np.abs(image.astype(int) - blue).sum(axis=2) < 30).sum() > 100


@pytest.fixture
def no_viewer(monkeypatch):
    """Spawning the Rerun viewer is recorded, never done (a test must not open a window, nor
    wait for one that cannot open)."""
    import sys

    import rerun

    spawned = []
    monkeypatch.setattr(rerun.RecordingStream, "spawn", lambda self, **kwargs: spawned.append(kwargs))
    monkeypatch.setattr(sys, "platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    return spawned


def test_without_a_display_the_viewer_is_refused_in_one_line(online_run, seq_dir, tmp_path, no_viewer):
    """It waited forever for a viewer that exits at once without a display."""
    root, _ = seq_dir
    result = CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root)])
    assert_one_line_error(result, 4, "no display", "--rrd FILE")
    # run --spawn refuses before it reads anything or writes its outputs
    result = CliRunner().invoke(app, ["run", str(root), "-o", str(tmp_path / "out"), "--spawn"])
    assert_one_line_error(result, 4, "no display", "--rrd FILE")
    assert not (tmp_path / "out").exists() and no_viewer == []


def test_without_the_viewer_executable_spawning_is_one_line(online_run, seq_dir, monkeypatch, no_viewer):
    root, _ = seq_dir
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setenv("PATH", "")
    result = CliRunner().invoke(app, ["view", str(online_run), "--sequence", str(root)])
    assert_one_line_error(result, 4, "no Rerun viewer (`rerun`) on PATH")
    assert no_viewer == []


def test_view_shows_the_model_the_run_used(seq_dir, tmp_path):
    """A run given `--bim` is shown on that map, not on the one the sequence names."""
    from test_eval_cli import renamed_map

    root, scene = seq_dir
    alt, run = renamed_map(root, tmp_path / "alt.json"), tmp_path / "run"
    assert CliRunner().invoke(app, ["run", str(root), "-o", str(run), "--bim", str(alt)]).exit_code == 0
    result = CliRunner().invoke(app, ["view", str(run), "--rrd", str(tmp_path / "x.rrd")])
    assert result.exit_code == 0, result.output
    entities = row_counts(tmp_path / "x.rrd")
    faces = [f.id for f in scene.plane_map.faces]
    assert all("/" + face_entity("alt-" + f) in entities for f in faces)
    assert not any("/" + face_entity(f) in entities for f in faces)
