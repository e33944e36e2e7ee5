"""`bimgraph run`: the files it writes, incrementally online, and its one-line errors."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli_errors import assert_one_line_error

from bimgraph.backend.online import Backend
from bimgraph.backend import pipeline
from bimgraph.backend.pipeline import initial_alignment, load_model, run as run_pipeline
from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import save_plane_map
from bimgraph.cli import app
from bimgraph.config import BackendConfig, Config
from bimgraph.evaluation.metrics import ate
from bimgraph.errors import InputError
from bimgraph.evaluation.runs import load_estimate, run_summary
from bimgraph.geometry import pose_from_tum, pose_to_tum
from bimgraph.sequence.format import InitialAlignment, Sequence, SequenceMeta, load_sequence, save_sequence
from bimgraph.sequence.tum import read_tum

N = 60


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    scene = make_scene(N, rooms=(2, 1), seed=7)
    root = tmp_path_factory.mktemp("seq")
    meta = SequenceMeta(name="synthetic", model="planes.json", sensor="planes",
                        initial_alignment=InitialAlignment(T_B_S=tuple(pose_to_tum(scene.initial.T_B_S))))
    save_sequence(Sequence(root=root, meta=meta, keyframes=scene.keyframes))
    save_plane_map(scene.plane_map, root / "planes.json")
    return scene, root


def run(*args):
    return CliRunner().invoke(app, ["run", *map(str, args)])


def interrupt_at(monkeypatch, k: int) -> None:
    """The online run stops at keyframe k as at Ctrl-C."""
    process = Backend.process

    def interrupted(self, kf):
        if kf.index == k:
            raise KeyboardInterrupt
        return process(self, kf)

    monkeypatch.setattr(Backend, "process", interrupted)


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_run_writes_every_output(world, tmp_path, mode):
    scene, root = world
    result = run(root, "-o", tmp_path, "--mode", mode)
    assert result.exit_code == 0, result.output
    stamps, T_B_C = read_tum(tmp_path / "trajectory_bim.tum")
    assert len(stamps) == N
    np.testing.assert_allclose(stamps, [kf.stamp for kf in scene.keyframes], atol=1e-6)
    assert ate(T_B_C, scene.T_B_C) < ate([scene.initial.T_B_S @ kf.pose for kf in scene.keyframes], scene.T_B_C) / 2
    assert len(read_tum(tmp_path / "trajectory_slam.tum")[0]) == N
    extrinsic = json.loads((tmp_path / "extrinsic.json").read_text())
    assert np.array(extrinsic["covariance"]).shape == (6, 6)
    assert extrinsic["unobservable"] == [{"kind": "translation", "axis_B": [0.0, 0.0, 1.0]}]
    # the sigmas along B's axes too, as the terminal prints them (the file had only S's)
    R_B_S = pose_from_tum(extrinsic["T_B_S"])[:3, :3]
    cov_trans_B = R_B_S @ np.array(extrinsic["covariance"])[3:, 3:] @ R_B_S.T
    np.testing.assert_allclose(extrinsic["sigma_trans_B_m"], np.sqrt(np.diag(cov_trans_B)))
    associations = json.loads((tmp_path / "associations.json").read_text())["associations"]
    faces = {f.id for f in scene.plane_map.faces}
    assert associations and all(a["face"] in faces and a["keyframes"] for a in associations)
    # the world is built as planned: every match is kept whole by the alignment
    assert {a["alignment"] for a in associations} == {"kept"}
    landmarks = json.loads((tmp_path / "landmarks.json").read_text())["landmarks"]
    assert len(landmarks) >= len({a["landmark"] for a in associations})
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["finished"] and summary["mode"] == mode and summary["keyframes"] == N
    assert summary["off_plan_landmarks"] == 0
    # this world's front-end drifts as a random walk: no rate stands out
    assert summary["frontend_drift"]["rotation_deg_per_m"] == [0.0, 0.0, 0.0]
    assert summary["frontend_drift"]["translation_percent"] == [0.0, 0.0, 0.0]
    # the plane-to-BIM tolerance as the robust alignment left it (online: its online judgement)
    assert 0 < summary["bim_tolerance"]["normal_deg"] <= 1.0 and 0 < summary["bim_tolerance"]["offset_m"] <= 0.01
    # the terminal gets the run in a few lines, from those files
    printed = " ".join(result.output.split())
    for line in ("T_B_S sigma", "translation along [0.0, 0.0, 1.0]", f"keyframes │ {N}",
                 f"{summary['matched_landmarks']} matched to {summary['matched_faces']} BIM faces",
                 f"{sum(1 for f in json.loads((tmp_path / 'deviations.json').read_text())['faces'] if f['status'] == 'within_tolerance')} within tolerance"):
        assert line in printed, (line, result.output)


def test_the_step_after_the_last_keyframe_is_announced(world, tmp_path):
    """An online run measures the walls after its last keyframe, for as long as offline rounds
    take: the caller hears of it (the CLI's progress bar says so) before it starts."""
    _, root = world
    heard = []

    def stage(what):
        heard.append((what, (tmp_path / "deviations.json").exists()))

    run_pipeline(root, tmp_path, mode="online", progress=lambda done, total: heard.append(done), stage=stage)
    assert heard == [*range(1, N + 1), ("measuring the walls", False)]
    assert (tmp_path / "deviations.json").exists()


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_a_run_stopped_while_measuring_the_walls_is_not_finished(world, tmp_path, monkeypatch, mode):
    """Stopped in the deviation step, after everything else (Ctrl-C while the report is being
    written, here), a run has every other output written and says it did not finish; it leaves
    no report, not even part of one."""
    _, root = world

    def interrupted(out_dir, *args, **kwargs):
        (tmp_path / "deviations.json").write_text("{")  # as if stopped while writing it
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "write_deviation_outputs", interrupted)
    result = run(root, "-o", tmp_path, "--mode", mode)
    assert result.exit_code == 130
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["finished"] is False and summary["keyframes"] == N
    assert len(read_tum(tmp_path / "trajectory_bim.tum")[0]) == N
    json.loads((tmp_path / "extrinsic.json").read_text())
    assert not any((tmp_path / name).exists() for name in ("deviations.json", "deviations.csv", "deviations.bcf"))
    monkeypatch.undo()
    assert run(root, "-o", tmp_path, "--mode", mode).exit_code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["finished"] is True and summary["timings_s"]["total_s"] > summary["timings_s"]["deviation_report_s"] > 0
    assert (tmp_path / "deviations.json").exists()


def test_crash_mid_run_leaves_valid_outputs(world, tmp_path, monkeypatch):
    """An online run stopped at keyframe 40 (Ctrl-C here) leaves what it wrote up to there
    readable, and no deviation report."""
    _, root = world
    interrupt_at(monkeypatch, 40)
    out = tmp_path / "out"
    result = run(root, "-o", out)
    assert result.exit_code == 130
    assert len(read_tum(out / "trajectory_bim.tum")[0]) == 40
    assert len(read_tum(out / "trajectory_slam.tum")[0]) == 40
    summary = json.loads((out / "summary.json").read_text())
    assert summary["finished"] is False and summary["keyframes"] == 40
    json.loads((out / "associations.json").read_text())
    extrinsic = json.loads((out / "extrinsic.json").read_text())
    assert extrinsic["keyframe"] == 39 and np.isfinite(extrinsic["covariance"]).all()
    assert not any((out / name).exists() for name in ("deviations.json", "deviations.csv", "deviations.bcf"))


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_a_malformed_line_is_one_line_and_keeps_an_earlier_run(world, tmp_path, mode):
    """A malformed keyframe is a one-line error naming its line and field, found before
    anything is written: the earlier run in the output folder stays as it was."""
    _, root = world
    out = tmp_path / "out"
    assert run(root, "-o", out, "--mode", mode).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    broken = tmp_path / "seq"
    broken.mkdir()
    for name in ("sequence.json", "planes.json"):
        (broken / name).write_text((root / name).read_text())
    lines = (root / "keyframes.jsonl").read_text().splitlines()
    lines[40] = lines[40].replace('"T_S_C": [', '"T_S_C": [9, ')
    (broken / "keyframes.jsonl").write_text("\n".join(lines) + "\n")
    result = run(broken, "-o", out, "--mode", mode)
    assert result.exit_code == 3
    message = result.output.strip()
    assert "\n" not in message and "line 41" in message and "T_S_C" in message
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_run_into_an_earlier_runs_folder_leaves_nothing_of_it_standing(world, tmp_path, monkeypatch):
    """The files an earlier run wrote at its end (its deviation report) and `bimgraph eval`'s
    metrics of it go when a new run starts there: stopped midway, the new run would otherwise
    have the earlier run's report beside its own files."""
    _, root = world
    out = tmp_path / "out"
    assert run(root, "-o", out).exit_code == 0
    (out / "metrics.json").write_text("{}")
    interrupt_at(monkeypatch, 20)
    assert run(root, "-o", out).exit_code == 130
    assert json.loads((out / "summary.json").read_text())["keyframes"] == 20
    assert not any((out / name).exists() for name in ("deviations.json", "deviations.csv", "deviations.bcf", "metrics.json"))


def singular_at(monkeypatch, k: int) -> None:
    """gtsam finds the system singular at keyframe k (as far overconfident covariances made it)."""
    process = Backend.process

    def singular(self, kf):
        if kf.index == k:
            raise RuntimeError("\nIndeterminate linear system detected while working near variable\n"
                               f"8646911284551352350 (Symbol: x{k}).\n\nThrown when a linear system is ill-posed.")
        return process(self, kf)

    monkeypatch.setattr(Backend, "process", singular)


def test_a_run_that_stops_at_its_first_keyframe_leaves_nothing_of_an_earlier_one(world, tmp_path, monkeypatch):
    """Made singular at its first keyframe, a run into an earlier run's folder has written
    (almost) nothing: the earlier run's files must not stand beside it as if they were its own,
    and `view` and `eval` of what it left say so in one line."""
    _, root = world
    out = tmp_path / "out"
    assert run(root, "-o", out).exit_code == 0
    (out / "metrics.json").write_text("{}")
    singular_at(monkeypatch, 0)
    assert_one_line_error(run(root, "-o", out), 5, "singular at keyframe 0")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["finished"] is False and summary["keyframes"] == 0
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "trajectory_bim.tum", "trajectory_slam.tum"]
    assert_one_line_error(CliRunner().invoke(app, ["view", str(out), "--rrd", str(tmp_path / "x.rrd")]), 2, "no keyframe")
    with pytest.raises(InputError, match="no keyframe"):
        load_estimate(out)  # (what `eval` reads of a run)


def test_singular_graph_mid_run_is_one_line_and_keeps_the_outputs(world, tmp_path, monkeypatch):
    """gtsam finding the system singular (as far overconfident covariances made it) ends the
    run with exit code 5 and a line naming the keyframe; the outputs so far stay valid."""
    _, root = world
    singular_at(monkeypatch, 30)
    out = tmp_path / "out"
    result = run(root, "-o", out)
    assert result.exit_code == 5
    message = result.output.strip()
    assert "\n" not in message and "singular at keyframe 30" in message
    summary = json.loads((out / "summary.json").read_text())
    assert summary["finished"] is False and summary["keyframes"] == 30
    assert len(read_tum(out / "trajectory_bim.tum")[0]) == 30


def test_online_run_writes_the_covariance_the_api_gives_at_that_keyframe(world, tmp_path):
    """`bimgraph run` skips the extrinsic's covariance per keyframe (nothing it writes reads
    it) and asks the graph for it where it writes: the same as the Python API's per keyframe."""
    _, root = world
    assert run(root, "-o", tmp_path).exit_code == 0
    written = json.loads((tmp_path / "extrinsic.json").read_text())
    sequence = load_sequence(root)
    backend = Backend(load_model(root / "planes.json", Config()), BackendConfig(), initial_alignment(sequence.meta, Config()))
    last = [backend.process(kf) for kf in sequence.keyframes][-1]
    assert written["keyframe"] == last.index
    np.testing.assert_allclose(written["covariance"], last.cov_T_B_S, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("field, value, message", [("normal", [0.0, 2.0, 0.0], "faces[2].normal: normal has norm 2.0000"),
                                                  ("offset", float("nan"), "faces[2].offset: Input should be a finite number")])
def test_malformed_plane_map_is_one_line(world, tmp_path, field, value, message):
    _, root = world
    bad = json.loads((root / "planes.json").read_text())
    bad["faces"][2][field] = value
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    result = run(root, "-o", tmp_path / "out", "--bim", tmp_path / "bad.json")
    assert_one_line_error(result, 3, f"bad.json: {message}")
    assert not (tmp_path / "out").exists()


def test_seed_alignment_and_bad_seed(world, tmp_path):
    scene, root = world
    # keyframe 0 sees some walls: seed every one of its wall planes with its true face
    seeds = [f"0:{i}:{scene.truth[(0, i)]}" for i in range(len(scene.keyframes[0].planes)) if scene.truth[(0, i)]]
    result = run(root, "-o", tmp_path / "out", "--mode", "offline", *sum((["--seed", s] for s in seeds), []))
    assert result.exit_code == 0, result.output
    result = run(root, "-o", tmp_path / "out2", "--seed", "0:99:r00S")
    # (found once the progress bar is up: rich ended it with a blank line before the error)
    assert_one_line_error(result, 4, "no plane 99 in keyframe 0 (it has")
    assert_one_line_error(run(root, "-o", tmp_path / "out2", "--seed", "999:0:r00S"), 4, "no keyframe 999 in the sequence")
    # one pair naming the wall opposite its plane: the run went on turned 180 deg, 13 m off
    i, face = next((i, scene.truth[(0, i)]) for i in range(len(scene.keyframes[0].planes)) if scene.truth[(0, i)])
    opposite = face[:-1] + {"N": "S", "S": "N", "E": "W", "W": "E"}[face[-1]]
    result = run(root, "-o", tmp_path / "out2", "--seed", f"0:{i}:{opposite}")
    assert_one_line_error(result, 4, "the --seed pairs turn T_B_S 178 deg from the initial alignment, 89 times its sigma_rot_deg (2)")


def test_a_run_without_an_alignment_says_so_and_why_nothing_matched(world, tmp_path):
    """A sequence of the user's own (`bimgraph planes -t` writes sequence.json without one):
    T_B_S starts at identity, 2 degrees and 20 cm, far from this scene's; the run warns before
    it starts and its summary asks after the alignment when no landmark matched a face. With
    seed pairs it does not warn."""
    scene, root = world
    seq = tmp_path / "seq"
    save_sequence(Sequence(root=seq, meta=SequenceMeta(name="own", model=str(root / "planes.json"), sensor="planes"),
                           keyframes=scene.keyframes))
    result = run(seq, "-o", tmp_path / "out", "--mode", "offline")
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"warning: {seq / 'sequence.json'} gives no initial_alignment and no --seed pair")
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["matched_landmarks"] == 0
    assert "is the initial alignment" in " ".join(result.output.split())
    seeds = [f"0:{i}:{scene.truth[(0, i)]}" for i in range(len(scene.keyframes[0].planes)) if scene.truth[(0, i)]]
    result = run(seq, "-o", tmp_path / "seeded", "--mode", "offline", *sum((["--seed", s] for s in seeds), []))
    assert result.exit_code == 0, result.output
    assert "warning" not in result.output and "is the initial alignment" not in " ".join(result.output.split())


def test_summary_lists_the_deviating_walls(world, tmp_path):
    """The printed summary names each wall the report finds deviating, with its offset."""
    _, root = world
    assert run(root, "-o", tmp_path).exit_code == 0
    path = tmp_path / "deviations.json"
    report = json.loads(path.read_text())
    face = next(f for f in report["faces"] if f["offset_m"] is not None)
    face.update(status="deviating", offset_m=0.073, offset_sigma_m=0.004)
    path.write_text(json.dumps(report))
    rows = dict((label, text) for label, text in run_summary(tmp_path) if label == "deviating")
    assert rows == {"deviating": f"{face['wall_name'] or face['wall_guid']} ({face['face_id']}): offset +7.3 ± 0.4 cm, "
                                 f"tilt {face['tilt_deg']:.2f} ± {face['tilt_sigma_deg']:.2f} deg"}


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_a_sequence_of_one_keyframe_runs(world, tmp_path, mode):
    """No step to measure the odometry's noise by (offline once crashed there)."""
    _, root = world
    one = tmp_path / "seq"
    one.mkdir()
    for name in ("sequence.json", "planes.json"):
        (one / name).write_text((root / name).read_text())
    (one / "keyframes.jsonl").write_text((root / "keyframes.jsonl").read_text().splitlines()[0] + "\n")
    result = run(one, "-o", tmp_path / "out", "--mode", mode)
    assert result.exit_code == 0, result.output
    assert len(read_tum(tmp_path / "out" / "trajectory_bim.tum")[0]) == 1


@pytest.mark.parametrize("case, exit_code, fragments", [
    ("nan_pose", 3, ("line 6", "T_S_C")), ("negative_d", 3, ("line 6", "planes[0].d")),
    ("empty", 3, ("keyframes.jsonl", "no keyframes")), ("output_is_a_file", 2, ("out",)),
])
def test_bad_input_or_output_is_one_line(world, tmp_path, case, exit_code, fragments):
    """NaN (which would go singular, or into the outputs), a plane behind its camera, no
    keyframes, an output folder that is a file: one line, no traceback, nothing written."""
    _, root = world
    seq = tmp_path / "seq"
    seq.mkdir()
    for name in ("sequence.json", "planes.json"):
        (seq / name).write_text((root / name).read_text())
    lines = (root / "keyframes.jsonl").read_text().splitlines()
    if case == "nan_pose":
        data = json.loads(lines[5])
        data["T_S_C"][0] = float("nan")  # (json writes it NaN, as numpy-minded writers do)
        lines[5] = json.dumps(data)
    elif case == "negative_d":
        data = json.loads(lines[5])
        data["planes"][0]["d"] = -abs(data["planes"][0]["d"])
        lines[5] = json.dumps(data)
    elif case == "empty":
        lines = []
    (seq / "keyframes.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    if case == "output_is_a_file":
        out.write_text("")
    result = run(seq, "-o", out)
    assert_one_line_error(result, exit_code, *fragments)
    assert out.is_file() if case == "output_is_a_file" else not out.exists()


@pytest.mark.parametrize("depth", [False, True])
def test_a_sequence_without_plane_detections_is_one_line(world, tmp_path, depth):
    """Run anyway, it would place nothing and list every face in view as possibly not built; a
    depth sequence whose planes were not detected yet is told how to detect them."""
    _, root = world
    seq = tmp_path / "seq"
    seq.mkdir()
    for name in ("sequence.json", "planes.json"):
        (seq / name).write_text((root / name).read_text())
    lines = []
    for line in (root / "keyframes.jsonl").read_text().splitlines():
        data = {**json.loads(line), "planes": []}
        if depth:
            data["depth"] = f"depth/{data['index']}.png"
        lines.append(json.dumps(data))
    (seq / "keyframes.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    message = assert_one_line_error(run(seq, "-o", out), 2, "no keyframe has a plane detection")
    assert ("bimgraph planes" in message) == depth
    assert not out.exists()


def test_an_online_run_too_short_for_a_drift_fit_reports_none(world, tmp_path):
    """The drift is fitted every `isam2.drift_every` keyframes: a run that ended before the
    first fit reported a correction of +0.000 deg/m, as if measured (outside review)."""
    _, root = world
    (tmp_path / "c.yaml").write_text(f"backend:\n  isam2:\n    drift_every: {N + 1}\n")
    result = run(root, "-o", tmp_path / "out", "--config", tmp_path / "c.yaml")
    assert result.exit_code == 0, result.output
    assert "frontend_drift" not in json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "front-end drift" not in result.output


def test_the_printed_sigmas_are_along_B():
    """extrinsic.json's covariance is in the right tangent of T_B_S, whose axes are S's; the
    printout gives the sigmas along B's axes (a review read S's as B's: 1.5, 0.5 cm against
    1.24, 0.88 along B)."""
    from bimgraph.geometry import make_pose, sigmas_in_B

    T_B_S = make_pose(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [5.0, -3.0, 0.0])  # 90 deg yaw
    cov = np.diag([1e-6, 4e-6, 9e-6, 1e-4, 4e-4, 9e-4]).tolist()
    rot, pos = sigmas_in_B(T_B_S, cov)
    np.testing.assert_allclose(pos, [0.02, 0.01, 0.03])  # S's y along B's x
    np.testing.assert_allclose(rot, [0.002, 0.001, 0.003])
    cov[0][0] = None  # (an early online keyframe's has no figures)
    assert np.isnan(sigmas_in_B(T_B_S, cov)[0][1])


def test_a_keyframe_stopped_half_way_is_not_in_the_outputs(world, tmp_path):
    """Ctrl-C inside a keyframe, once its observations went to the landmarks (here: after the
    backend took it, before the writer did): the landmarks and associations written are those
    of the keyframes the trajectories hold. They had held the half-done keyframe's
    observations, and its new landmarks."""
    from bimgraph.backend.results import OnlineWriter
    from bimgraph.config import BackendConfig

    scene, _ = world
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial)
    writer = OnlineWriter(tmp_path, 1000)
    for kf in scene.keyframes:
        result = backend.process(kf)
        # (a keyframe that a matched landmark saw, or that made a landmark)
        if kf.index >= 10 and any((lm.face is not None or lm.anchor == kf.index) and (kf.index, 0) in lm.observations
                                  for lm in backend.landmarks.current()):
            stop = kf.index
            break
        writer.keyframe(result, backend)
    writer.snapshot(backend, finished=False)
    writer.close()
    assert len(read_tum(tmp_path / "trajectory_bim.tum")[0]) == stop
    landmarks = json.loads((tmp_path / "landmarks.json").read_text())["landmarks"]
    associations = json.loads((tmp_path / "associations.json").read_text())["associations"]
    assert max(lm["anchor"] for lm in landmarks) < stop
    assert max(k for a in associations for k in a["keyframes"]) < stop
    assert json.loads((tmp_path / "summary.json").read_text())["landmarks"] == len(landmarks)


def test_a_signal_between_the_trajectories_lines_stops_after_both(world, tmp_path, monkeypatch):
    """Ctrl-C or SIGTERM arriving while the writer puts a keyframe's lines into the two
    trajectories (here: just after the first) takes effect once the keyframe is written
    whole: the trajectories and the summary agree. It had stopped between them: the BIM
    trajectory one line longer than the SLAM one and than the summary's count (seen once in
    `test_sigterm_stops_a_run_as_ctrl_c_does`, 19 keyframes against 20 lines)."""
    import os
    import signal

    from bimgraph.backend.results import OnlineWriter, TumAppender
    from bimgraph.config import BackendConfig

    scene, _ = world
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial)
    writer = OnlineWriter(tmp_path, 1000)
    append = TumAppender.append

    def append_then_signal(self, stamp, T):
        append(self, stamp, T)
        if self is writer.bim and len(writer.latencies) == 7:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(TumAppender, "append", append_then_signal)
    with pytest.raises(KeyboardInterrupt):
        for kf in scene.keyframes:
            writer.keyframe(backend.process(kf), backend)
    writer.snapshot(backend, finished=False)
    writer.close()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["keyframes"] == 8
    assert len(read_tum(tmp_path / "trajectory_bim.tum")[0]) == len(read_tum(tmp_path / "trajectory_slam.tum")[0]) == 8


def test_sigterm_stops_a_run_as_ctrl_c_does(world, tmp_path):
    """systemd, docker stop and ROS launch stop a process with SIGTERM: the run says so and
    leaves its outputs consistent, as after Ctrl-C (it had died at once, without a summary)."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    _, root = world
    out = tmp_path / "out"
    process = subprocess.Popen([str(Path(sys.executable).parent / "bimgraph"), "run", str(root), "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while not (out / "trajectory_bim.tum").is_file() or len(read_tum(out / "trajectory_bim.tum")[0]) < 5:
        assert process.poll() is None and time.time() < deadline, process.communicate()
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130 and "interrupted" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["finished"] is False and summary["keyframes"] == len(read_tum(out / "trajectory_bim.tum")[0])


def test_the_api_refuses_a_keyframe_that_does_not_follow_and_goes_on(world):
    """A keyframe repeated or out of order is an InputError before the graph is touched (gtsam
    had refused its key half-way, and every later keyframe after it); the backend goes on."""
    from bimgraph.backend.offline import run_offline
    from bimgraph.config import BackendConfig
    from bimgraph.errors import InputError

    scene, _ = world
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial)
    for kf in scene.keyframes[:20]:
        backend.process(kf)
    for bad in (scene.keyframes[19], scene.keyframes[5], scene.keyframes[20].model_copy(update={"stamp": scene.keyframes[19].stamp})):
        with pytest.raises(InputError, match="does not follow keyframe 19"):
            backend.process(bad)
    with pytest.raises(InputError, match="not finite"):
        backend.process(scene.keyframes[20].model_copy(update={"T_S_C": (float("nan"),) + tuple(scene.keyframes[20].T_S_C[1:])}))
    # (a plane set after validation, as a caller may)
    nan_plane = scene.keyframes[20].model_copy(deep=True)
    nan_plane.planes[0].d = float("nan")
    with pytest.raises(InputError, match="keyframe 20: plane 0 .* is not finite"):
        backend.process(nan_plane)
    assert backend.process(scene.keyframes[20]).index == 20
    with pytest.raises(InputError, match="no keyframes"):
        run_offline([], scene.plane_map, BackendConfig(), scene.initial)


def test_the_api_stops_where_the_graph_becomes_singular(world):
    """A step the front-end gives as certain to 3e-9 that the planes contradict by 0.5 m
    makes the linear system singular: gtsam's multi-line RuntimeError escaped the API, and
    every later keyframe failed with "key already exists". Now a SingularError names the
    keyframe, and the backend, which iSAM2 left holding it in part, refuses every later one
    with the same words."""
    from bimgraph.config import BackendConfig
    from bimgraph.errors import SingularError

    scene, _ = world
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial)
    for kf in scene.keyframes[:20]:
        backend.process(kf)
    kf = scene.keyframes[20]
    certain = kf.model_copy(update={"cov": tuple(tuple(1e-17 * (i == j) for j in range(6)) for i in range(6)),
                                    "T_S_C": (kf.T_S_C[0] + 0.5, *kf.T_S_C[1:])})
    with pytest.raises(SingularError, match="^keyframe 20: the graph's linear system became singular"):
        backend.process(certain)
    with pytest.raises(SingularError, match="^keyframe 21: this Backend stopped at keyframe 20"):
        backend.process(scene.keyframes[21])


def test_an_unfinished_runs_report_is_not_read(world, tmp_path):
    """A run killed while it wrote its deviation report left part of one, beside a summary
    that does not say it finished: `view` and the printout read no report then."""
    from bimgraph.viewer.session import deviation_report

    _, root = world
    out = tmp_path / "out"
    assert run(root, "-o", out, "--mode", "offline").exit_code == 0
    assert deviation_report(out) is not None
    summary = json.loads((out / "summary.json").read_text())
    (out / "summary.json").write_text(json.dumps({**summary, "finished": False}))
    assert deviation_report(out) is None
    (out / "landmarks.json.tmp").write_text("{")  # (a kill while it wrote one)
    assert run(root, "-o", out, "--mode", "offline").exit_code == 0
    assert not (out / "landmarks.json.tmp").exists()


def test_the_python_api_gives_the_deviation_report_a_run_writes(world, tmp_path):
    """`deviation_report` on offline `Results` is deviations.json's content (the README said
    the API returned what the files hold; the report was only made inside `bimgraph run`)."""
    from bimgraph.backend import run_offline
    from bimgraph.backend.pipeline import initial_alignment
    from bimgraph.config import Config
    from bimgraph.deviations.outputs import deviation_report
    from bimgraph.deviations.report import load_deviations, to_file
    from bimgraph.sequence.format import load_sequence

    scene, root = world
    assert run(root, "-o", tmp_path, "--mode", "offline").exit_code == 0
    cfg, seq = Config(), load_sequence(root)
    results = run_offline(seq.keyframes, scene.plane_map, cfg.backend, initial_alignment(seq.meta, cfg))
    report = deviation_report(scene.plane_map, results.observed_planes, results.T_B_S, results.T_B_C, seq.meta.camera,
                              cfg.deviations, results.rival_alignment)
    written = load_deviations(tmp_path / "deviations.json")
    assert written.faces and to_file(report).model_dump() == written.model_dump()


@pytest.mark.slow
def test_a_model_that_does_not_fit_the_walk_is_warned_about(tmp_path):
    """A run against the wrong model ends as any other (6 of 65 landmarks matched on the
    sixth review's); the large walls seen long, most of which a fitting model matches, say so."""
    seq = tmp_path / "seq"
    assert CliRunner().invoke(app, ["simulate", "-o", str(seq), "--scenario", "office", "-n", "80", "--seed", "4"]).exit_code == 0
    assert CliRunner().invoke(app, ["bim", str(seq / "model.ifc"), "-o", str(tmp_path / "planes.json")]).exit_code == 0
    plane_map = load_model(tmp_path / "planes.json", Config())
    moved = [face.model_copy(update={"polygon": [(x + 1.5, y + 1.5, z) for x, y, z in face.polygon],
                                     "holes": [[(x + 1.5, y + 1.5, z) for x, y, z in h] for h in face.holes],
                                     "offset": face.offset - 1.5 * (face.normal[0] + face.normal[1]), "area": None, "centre": None})
             for face in plane_map.faces]
    save_plane_map(plane_map.model_copy(update={"faces": moved}), tmp_path / "moved.json")
    for bim, warned in [(tmp_path / "planes.json", False), (tmp_path / "moved.json", True)]:
        result = run(seq, "-o", tmp_path / bim.stem, "--bim", bim)
        assert result.exit_code == 0, result.output
        assert ("large vertical planes seen in 10 keyframes or more matched a BIM face" in result.output) == warned
