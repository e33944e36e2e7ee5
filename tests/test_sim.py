"""The simulator checked against its own ground truth: observations lie on the as-built
surfaces they came from, perturbed faces are where the record says, the camera stays in free
space, the same seed gives the same bytes, and the front-end drifts at the configured rates."""

import filecmp
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from cli_errors import assert_one_line_error

from bimgraph.config import Config, FrontEndConfig
from bimgraph.geometry import inverse, normal_angle_deg, plane_to_frame, point_plane_distance
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth
from bimgraph.sequence.tum import read_tum, write_tum
from bimgraph.sim.frontend import simulate_frontend
from bimgraph.sim.render import DepthRenderer
from bimgraph.sim.simulate import SimOptions, simulate
from bimgraph.sim.world import Element, triangulate


def _run(path, **kwargs):
    opts = SimOptions(output=path, **kwargs)
    return simulate(opts, Config())


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    root = tmp_path_factory.mktemp("office")
    summary = _run(root, scenario="office", keyframes=200, seed=7)
    return root, summary


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    summary = _run(root, scenario="site", keyframes=100, seed=3)
    return root, summary


def _elements(gt) -> list[Element]:
    return [Element(e["name"], e["kind"], e["face_id"], np.array(e["plane"]), np.array(e["polygon"]),
                    [np.array(h) for h in e["holes"]]) for e in gt.as_built["elements"]]


def test_tum_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    from bimgraph.geometry import exp_se3

    poses = [exp_se3(rng.normal(size=6)) for _ in range(5)]
    write_tum(tmp_path / "t.tum", np.arange(5) * 0.1, poses)
    stamps, back = read_tum(tmp_path / "t.tum")
    assert np.allclose(stamps, np.arange(5) * 0.1)
    assert np.allclose(back, poses, atol=1e-8)


def test_sequence_and_ground_truth_load_and_align(office):
    root, summary = office
    seq = load_sequence(root)
    gt = load_groundtruth(root)
    assert len(seq.keyframes) == 200 == len(gt.stamps)
    assert seq.model_path() == root / "model.ifc" and seq.model_path().is_file()
    assert [len(kf.planes) for kf in seq.keyframes] == [len(o) for o in gt.observations]
    assert summary["planes"] > 2 * len(seq.keyframes)
    # Both wall faces and non-wall surfaces (floor, clutter) are observed.
    faces = [p["face_id"] for obs in gt.observations for p in obs]
    assert sum(f is not None for f in faces) > 0.4 * len(faces)
    assert sum(f is None for f in faces) > 0
    # Every observed face is among the keyframe's visible faces.
    for obs, vis in zip(gt.observations, gt.visible):
        assert {p["face_id"] for p in obs} - {None} <= set(vis["faces"])
    # The manual alignment is off by the configured amounts.
    ia = gt.extrinsic["initial_alignment"]
    assert 1.0 <= abs(ia["yaw_error_deg"]) <= 2.0
    assert 0.1 <= np.linalg.norm(ia["translation_error_m"]) <= 0.2


def test_observations_lie_on_their_as_built_surfaces(office):
    root, _ = office
    seq, gt = load_sequence(root), load_groundtruth(root)
    by_name = {e["name"]: e for e in gt.as_built["elements"]}
    chi2_normal, chi2_offset, detections = [], [], 0
    cfg = Config().sim.observe
    for kf, truth, T_B_C in zip(seq.keyframes, gt.observations, gt.T_B_C):
        for obs, t in zip(kf.planes, truth):
            detections += 1
            plane_B = plane_to_frame(obs.plane, inverse(T_B_C))  # C -> B
            element = by_name[t["element"]]
            true_B = np.array(element["plane"])
            sigma_n, sigma_d = np.sqrt(obs.cov[0][0]), np.sqrt(obs.cov[2][2])
            chi2_normal.append((np.radians(normal_angle_deg(plane_B[:3], true_B[:3])) / sigma_n) ** 2)
            chi2_offset.append(((obs.d - t["plane_C"][3]) / sigma_d) ** 2)
            assert obs.d > 0 and obs.area >= cfg.min_area_m2
            # The extent lies on the detected plane, and on the true surface within the noise.
            ring_C = np.array(obs.polygon)
            assert np.abs(point_plane_distance(ring_C, obs.plane)).max() < 1e-6
            ring_B = ring_C @ T_B_C[:3, :3].T + T_B_C[:3, 3]
            bound = 5 * sigma_d + 5 * sigma_n * np.linalg.norm(ring_C, axis=1)
            assert np.all(np.abs(point_plane_distance(ring_B, true_B)) < bound)
            assert obs.centre[2] <= cfg.max_range_m + 0.3  # the range limit is on z-depth
    assert detections > 500
    # Normal error: chi-square with 2 degrees of freedom; offset: with 1.
    assert np.mean(chi2_normal) == pytest.approx(2.0, rel=0.15)
    assert np.mean(chi2_offset) == pytest.approx(1.0, rel=0.15)
    # Noise grows with distance: farther planes have larger offset sigmas.
    sig = [(np.linalg.norm(p.centre), np.sqrt(p.cov[2][2])) for kf in seq.keyframes for p in kf.planes]
    r, s = np.array(sig).T
    assert np.corrcoef(r, s)[0, 1] > 0.5
    assert cfg.noise.offset_sigma_m <= np.median(s) <= 4 * cfg.noise.offset_sigma_m


@pytest.mark.parametrize("fixture", ["office", "site"])
def test_perturbed_faces_are_where_ground_truth_says(fixture, request):
    root, _ = request.getfixturevalue(fixture)
    gt = load_groundtruth(root)
    by_face = {e["face_id"]: e for e in gt.as_built["elements"] if e["kind"] == "wall"}
    faces = gt.as_built["faces"]
    moved = [f for f in faces if f["offset_m"] != 0 and f["built"]]
    tilted = [f for f in faces if f["tilt_deg"] != 0 and f["built"]]
    assert moved and tilted
    if fixture == "site":
        assert any(not f["built"] for f in faces)
    for f in faces:
        if not f["built"]:
            assert f["face_id"] not in by_face
            continue
        planned, built = np.array(f["plane_planned"]), np.array(f["plane_as_built"])
        element = by_face[f["face_id"]]
        assert np.allclose(element["plane"], built, atol=1e-8)
        # Its outline lies on the recorded plane.
        assert np.abs(point_plane_distance(np.array(element["polygon"]), built)).max() < 1e-5
        # Tilted by the recorded angle about the recorded axis, moved by the recorded offset.
        assert normal_angle_deg(planned[:3], built[:3]) == pytest.approx(abs(f["tilt_deg"]), abs=1e-4)
        pivot = np.array(f["pivot"])
        assert point_plane_distance(pivot, planned) == pytest.approx(f["offset_m"], abs=1e-6)
        assert abs(point_plane_distance(pivot, built)) < 1e-6
        if f["offset_m"]:
            assert 0.01 <= abs(f["offset_m"]) <= 0.10


def test_camera_never_leaves_free_space(site):
    root, _ = site
    gt = load_groundtruth(root)
    elements = _elements(gt)
    mesh = triangulate(elements)
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    origin = mesh.vertices.mean(axis=0)
    scene.add_triangles(o3d.core.Tensor((mesh.vertices - origin).astype(np.float32)),
                        o3d.core.Tensor(mesh.triangles.astype(np.uint32)))

    def cast(origins, dirs):
        rays = np.concatenate([origins - origin, dirs], axis=1).astype(np.float32)
        return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()

    p = gt.T_B_C[:, :3, 3]
    # No segment between consecutive keyframes crosses any surface.
    assert np.all(cast(p[:-1], p[1:] - p[:-1]) > 1.0)
    # Every camera keeps its distance to walls and clutter (horizontal rays all round).
    clearance = Config().sim.trajectory.clearance_m
    for a in np.linspace(0, 2 * np.pi, 24, endpoint=False):
        d = np.tile([np.cos(a), np.sin(a), 0.0], (len(p), 1))
        assert cast(p, d).min() > clearance - 2 * Config().sim.trajectory.grid_m
    # Inside the storey: a floor below, a ceiling above, within the configured heights.
    floor_z = gt.as_built["storey"]["floor_z"]
    assert np.all((p[:, 2] - floor_z >= 1.2 - 1e-9) & (p[:, 2] - floor_z <= 1.7 + 1e-9))
    up = cast(p, np.tile([0.0, 0.0, 1.0], (len(p), 1)))
    down = cast(p, np.tile([0.0, 0.0, -1.0], (len(p), 1)))
    assert np.all(np.isfinite(up)) and np.allclose(down, p[:, 2] - floor_z, atol=1e-4)
    # Keyframes every ~0.3 m or ~10 degrees.
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert steps.max() < 0.4


def test_same_seed_same_bytes(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for root, seed in [(a, 5), (b, 5), (c, 6)]:
        _run(root, scenario="office", keyframes=30, seed=seed)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) >= 8
    match, mismatch, errors = filecmp.cmpfiles(a, b, [str(f) for f in files], shallow=False)
    assert not mismatch and not errors
    assert (a / "keyframes.jsonl").read_bytes() != (c / "keyframes.jsonl").read_bytes()


def test_offsets_change_nothing_but_the_walls(tmp_path):
    """The same site with and without moved faces: the same missing walls, clutter and walk
    (what issue 8's "same scenario without deviations" compares against)."""
    runs = {}
    for name, fraction in (("moved", 0.4), ("level", 0.0)):
        cfg = Config()
        cfg.sim.as_built_site = cfg.sim.as_built_site.model_copy(update={"offset_fraction": fraction})
        simulate(SimOptions(output=tmp_path / name, scenario="site", keyframes=30, seed=2), cfg)
        runs[name] = load_groundtruth(tmp_path / name)
    moved, level = runs["moved"], runs["level"]
    np.testing.assert_array_equal(moved.T_B_C, level.T_B_C)
    faces_m, faces_l = moved.as_built["faces"], level.as_built["faces"]
    assert [f["built"] for f in faces_m] == [f["built"] for f in faces_l]
    assert [f["tilt_deg"] for f in faces_m] == [f["tilt_deg"] for f in faces_l]
    assert sum(f["offset_m"] != 0 for f in faces_m) > 0 == sum(f["offset_m"] != 0 for f in faces_l)
    clutter = [[e["name"], e["plane"]] for e in moved.as_built["elements"] if e["kind"] != "wall"]
    assert clutter == [[e["name"], e["plane"]] for e in level.as_built["elements"] if e["kind"] != "wall"]


@pytest.mark.parametrize("gravity_aligned", [True, False])
def test_drift_matches_configured_rates(office, gravity_aligned):
    root, _ = office
    T_B_C = load_groundtruth(root).T_B_C
    rng = np.random.default_rng(1)
    quiet = dict(random_walk_m=0.0, random_walk_deg=0.0, noise_m=0.0, noise_deg=0.0, gravity_aligned=gravity_aligned)
    only_translation = simulate_frontend(T_B_C, FrontEndConfig(translation_drift=0.02, yaw_drift_deg_per_m=0.0, **quiet), rng)
    assert only_translation.drift["final_drift_percent"] == pytest.approx(2.0, rel=0.2)
    only_yaw = simulate_frontend(T_B_C, FrontEndConfig(translation_drift=0.0, yaw_drift_deg_per_m=0.3, **quiet), rng)
    assert only_yaw.drift["yaw_drift_deg_per_m"] == pytest.approx(0.3, rel=0.2)
    only_scale = simulate_frontend(T_B_C, FrontEndConfig(translation_drift=0.0, yaw_drift_deg_per_m=0.0, scale_error=0.02,
                                                         **quiet), rng)
    steps = [np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) for T in (only_scale.T_S_C, T_B_C)]
    np.testing.assert_allclose(steps[0], 1.02 * steps[1], atol=1e-12)
    # With the default random walk and noise on top, the heading rate still holds.
    default = simulate_frontend(T_B_C, FrontEndConfig(gravity_aligned=gravity_aligned), rng)
    assert default.drift["yaw_drift_deg_per_m"] == pytest.approx(FrontEndConfig().yaw_drift_deg_per_m, rel=0.2)
    # S is the first camera: the first estimated pose is T_S_C0 = T_S_B T_B_C0.
    assert np.allclose(default.T_S_C[0], inverse(default.T_B_S) @ T_B_C[0], atol=1e-9)
    if gravity_aligned:
        assert np.allclose(default.T_B_S[:3, 2], [0, 0, 1])
    else:  # S is the first camera's own frame
        assert np.allclose(default.T_B_S, T_B_C[0], atol=1e-9)


def test_office_drift_recorded(office):
    root, summary = office
    meta = json.loads((root / "sequence.json").read_text())
    measured = meta["simulated"]["drift"]["measured"]
    assert measured == summary["drift"]
    assert measured["yaw_drift_deg_per_m"] == pytest.approx(FrontEndConfig().yaw_drift_deg_per_m, rel=0.2)


def test_rendered_depth_is_the_distance_to_the_as_built_face(tmp_path):
    root = tmp_path / "depth"
    _run(root, scenario="office", keyframes=4, seed=2, sensor="depth")
    seq, gt = load_sequence(root), load_groundtruth(root)
    assert seq.meta.sensor == "depth" and seq.keyframes[0].depth.startswith("depth/")
    listed = [line for line in (root / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(listed) == 4
    elements = _elements(gt)
    mesh = triangulate(elements)
    renderer = DepthRenderer(mesh.vertices, mesh.triangles, mesh.element)
    cam = seq.meta.camera
    rng = np.random.default_rng(0)
    checked = 0
    for kf, T_B_C in zip(seq.keyframes, gt.T_B_C):
        depth, ids = renderer.render(cam, T_B_C)
        labels = cv2.imread(str(root / "groundtruth" / "labels" / kf.depth.split("/")[1]), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(labels.astype(int) - 1, ids)
        noisy = cv2.imread(str(root / kf.depth), cv2.IMREAD_UNCHANGED) / cam.depth_scale
        for v, u in zip(rng.integers(0, cam.height, 200), rng.integers(0, cam.width, 200)):
            if ids[v, u] < 0:
                continue
            ray_B = T_B_C[:3, :3] @ np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
            plane = elements[ids[v, u]].plane
            z = -(plane[:3] @ T_B_C[:3, 3] + plane[3]) / (plane[:3] @ ray_B)
            assert depth[v, u] == pytest.approx(z, abs=2e-4)
            if noisy[v, u] > 0:
                noise = Config().depth_noise
                assert abs(noisy[v, u] - z) < 5 * (noise.sigma(z) + noise.systematic_sigma(z)) + 1e-3
            checked += 1
    assert checked > 500


@pytest.mark.parametrize("args, exit_code, message", [
    (["--sensor", "lidar"], 4, "--sensor"),
    (["--keyframes", "1"], 4, "--keyframes"),
    (["--scenario", "castle"], 4, "--scenario"),
    (["--scenario", "office", "--ifc", "x.ifc"], 4, "not both"),
    (["--ifc", "/nonexistent/model.ifc"], 2, "no such file"),
])
def test_invalid_options_give_one_line(tmp_path, args, exit_code, message):
    from typer.testing import CliRunner

    from bimgraph.cli import app

    result = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "seq"), *args])
    assert_one_line_error(result, exit_code, message)
    assert not (tmp_path / "seq").exists()


def test_ifc_without_walls_fails_in_one_line(tmp_path):
    import ifcopenshell.api.aggregate
    import ifcopenshell.api.project
    import ifcopenshell.api.root

    f = ifcopenshell.api.project.create_file(version="IFC4")
    project = ifcopenshell.api.root.create_entity(f, ifc_class="IfcProject", name="empty")
    storey = ifcopenshell.api.root.create_entity(f, ifc_class="IfcBuildingStorey", name="Level 0")
    ifcopenshell.api.aggregate.assign_object(f, relating_object=project, products=[storey])
    f.write(str(tmp_path / "empty.ifc"))
    proc = subprocess.run([sys.executable, "-m", "bimgraph.cli", "simulate", "-o", str(tmp_path / "seq"),
                           "--ifc", str(tmp_path / "empty.ifc")], capture_output=True, text=True)
    assert proc.returncode != 0
    assert proc.stderr.strip().startswith("error:") and len(proc.stderr.strip().splitlines()) == 1
    assert "wall" in proc.stderr


def test_shared_ifc_model(tmp_path, ifc_samples):
    """A user's model: referenced by path, walked over its floor slab, faces from its import."""
    from bimgraph.bim.ifc_import import import_ifc
    from bimgraph.deviations.visibility import expected_view_counts

    model = ifc_samples / "AC20-FZK-Haus.ifc"
    root = tmp_path / "fzk"
    _run(root, ifc=model, keyframes=60, seed=1)
    seq, gt = load_sequence(root), load_groundtruth(root)
    assert seq.model_path() == model.resolve()
    plane_map, _ = import_ifc(model, Config().bim)
    faces = {p["face_id"] for obs in gt.observations for p in obs} - {None}
    assert faces and faces <= set(plane_map.index)
    floor_z = gt.as_built["storey"]["floor_z"]
    assert np.all(gt.T_B_C[:, 2, 3] - floor_z >= 1.2 - 1e-9)
    # the ceiling under the slab above (its underside at 2.5 m), not at the walls' tops (2.7 m:
    # they run up through the slab)
    assert gt.as_built["storey"]["ceiling_z"] == pytest.approx(2.5)
    # Over the ground floor slab (0..12 x 0..10 m in this model), not outside.
    xy = gt.T_B_C[:, :2, 3]
    assert np.all((xy > -0.1) & (xy < [12.1, 10.1]))
    # Walls of the storey above are not in view through the ceiling (the model's map has no
    # slabs): before the report put floors at the storeys' elevations, two faces of the roof
    # storey were, at 9 and 10 of these 60 keyframes, and possibly not built
    cam = seq.meta.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    counts = expected_view_counts(plane_map, gt.T_B_C, K, cam.width, cam.height, Config().deviations)
    storeys = {face.id: face.storey for face in plane_map.faces}
    assert any(counts.values())
    assert all(storeys[face] == gt.as_built["storey"]["name"] for face, n in counts.items() if n)


def test_over_segmentation_splits_a_surface_in_two(office):
    from shapely.geometry import box

    from bimgraph.sim.observe import split_in_two

    pieces = split_in_two(box(0, 0, 4, 2))
    assert sorted(p.area for p in pieces) == pytest.approx([4.0, 4.0])
    assert pieces[0].intersection(pieces[1]).area == pytest.approx(0.0)
    gt = load_groundtruth(office[0])
    doubled = sum(len(obs) - len({p["element"] for p in obs}) for obs in gt.observations)
    total = sum(len(obs) for obs in gt.observations)
    assert 0 < doubled < 0.1 * total


def test_a_failed_simulation_leaves_no_folder_it_made(tmp_path, monkeypatch):
    """A truncated IFC left an empty output folder; a stop after the model was written, a folder
    with model.ifc alone. A folder that was there before keeps what it held."""
    from typer.testing import CliRunner

    from cli_errors import assert_one_line_error

    from bimgraph.cli import app
    from bimgraph.sim import observe

    half = tmp_path / "half.ifc"
    half.write_text("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('ViewDefinition [CoordinationView]'),'2;1');\n")
    result = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "new" / "seq"), "--ifc", str(half)])
    assert_one_line_error(result, 3, "half.ifc: truncated IFC file")
    assert not (tmp_path / "new").exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    result = CliRunner().invoke(app, ["simulate", "-o", str(kept), "--ifc", str(half)])
    assert result.exit_code == 3 and kept.is_dir() and not any(kept.iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.ifc", "kept"]  # (nothing written beside it either)

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(observe, "detect", stop)
    result = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "stopped"), "-n", "5"])
    assert result.exit_code == 130 and not (tmp_path / "stopped").exists()


def test_the_storey_to_walk_is_chosen_on_the_command_line(tmp_path, ifc_samples):
    """`--storey` (`sim.storey`): the named storey is walked; a storey with no walls is one
    line naming those that have some, and writes nothing."""
    from typer.testing import CliRunner

    from bimgraph.cli import app

    model = str(ifc_samples / "AC20-FZK-Haus.ifc")
    result = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "attic"), "--ifc", model, "--storey", "Dachgeschoss", "-n", "5"])
    assert result.exit_code == 0, result.output
    assert load_groundtruth(tmp_path / "attic").as_built["storey"]["name"] == "Dachgeschoss"
    result = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "none"), "--scenario", "office", "--storey", "Roof", "-n", "5"])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == ["error: no walls on storey 'Roof'; storeys with walls: Level 0"]
    assert not (tmp_path / "none").exists()


def test_simulate_says_each_step_before_the_keyframes(tmp_path):
    steps, done = [], []
    simulate(SimOptions(output=tmp_path / "seq", scenario="site", keyframes=5, seed=1), Config(),
             progress=lambda k, total: done.append((k, total)), stage=steps.append)
    firsts = list(dict.fromkeys(step.split(":")[0] for step in steps))
    assert firsts == ["importing the model", "building the storey as built", "planning the walk", "observing"]
    assert "importing the model: faces split per room 1/" in " ".join(steps)
    assert done == [(k, 5) for k in range(1, 6)]


def test_a_simulation_replaces_an_earlier_one_whole_and_nothing_else(tmp_path, monkeypatch):
    """Into the folder of an earlier simulation: its files go, a depth walk's images with them
    (they outlived a planes walk written over it), once the new one is complete (stopped, the
    earlier one stays as it was). A folder of other files, of a sequence not simulated, or of
    a simulated sequence and a run's outputs (which the new walk would leave stale), is
    refused: it was written over without a word."""
    from typer.testing import CliRunner

    from cli_errors import assert_one_line_error

    from bimgraph.cli import app
    from bimgraph.sim import observe

    seq = tmp_path / "seq"
    assert CliRunner().invoke(app, ["simulate", "-o", str(seq), "--sensor", "depth", "-n", "3", "--seed", "1"]).exit_code == 0
    (seq / "notes.txt").write_text("mine")
    before = {p: p.read_bytes() for p in seq.rglob("*") if p.is_file()}
    detect = observe.detect
    calls = []

    def stop(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return detect(*args, **kwargs)

    monkeypatch.setattr(observe, "detect", stop)
    assert CliRunner().invoke(app, ["simulate", "-o", str(seq), "-n", "5", "--seed", "2"]).exit_code == 130
    assert {p: p.read_bytes() for p in seq.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    monkeypatch.setattr(observe, "detect", detect)

    assert CliRunner().invoke(app, ["simulate", "-o", str(seq), "-n", "5", "--seed", "2"]).exit_code == 0
    assert sorted(p.name for p in seq.iterdir()) == ["groundtruth", "keyframes.jsonl", "model.ifc", "notes.txt", "sequence.json"]
    assert len(load_sequence(seq).keyframes) == 5
    (seq / "summary.json").write_text("{}")
    result = CliRunner().invoke(app, ["simulate", "-o", str(seq), "-n", "3"])
    assert_one_line_error(result, 2, "holds a run's outputs (summary.json)")
    assert len(load_sequence(seq).keyframes) == 5 and (seq / "summary.json").read_text() == "{}"
    (seq / "summary.json").unlink()

    others = tmp_path / "run"
    others.mkdir()
    (others / "summary.json").write_text("{}")
    result = CliRunner().invoke(app, ["simulate", "-o", str(others), "-n", "3"])
    assert_one_line_error(result, 2, "holds files but no sequence")
    assert [p.name for p in others.iterdir()] == ["summary.json"]
    meta = json.loads((seq / "sequence.json").read_text())
    del meta["simulated"]
    (seq / "sequence.json").write_text(json.dumps(meta))
    result = CliRunner().invoke(app, ["simulate", "-o", str(seq), "-n", "3"])
    assert_one_line_error(result, 2, "holds a sequence that was not simulated")
    assert len(load_sequence(seq).keyframes) == 5
