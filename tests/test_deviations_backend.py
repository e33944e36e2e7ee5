"""The deviation step on the real backend: the online iSAM2 graph of the backend's synthetic
rooms, with one face of the plan moved, read through `observed_planes_isam2` and written by
`write_deviation_outputs`; and the offline backend's robust alignment
(`offline.gnc`), which keeps the moved face out of the alignment.

Online, the robust kernel alone cannot do that for a moved wall that the walk sees first:
the alignment follows it, and the sound walls seen later are outvoted one by one; the online
judgement takes that case (tests/test_online_judgement.py), and an online run's report is
measured after the offline rounds. The online graph tests here move a wall the walk meets once
others have placed it."""

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimgraph.backend.graph import PLANE_S, E, L, X, BatchSolver, bim_keys, joint_covariance
from bimgraph.backend.marginals import JointMarginals
from bimgraph.backend.offline import OfflineEstimator
from bimgraph.backend.online import Backend, observations_of
from bimgraph.backend.pipeline import run as run_pipeline
from bimgraph.backend.reduced import reduced
from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import PlaneMap, save_plane_map
from bimgraph.config import BackendConfig, Config, DeviationConfig
from bimgraph.deviations.bcf import BCF_FILE, read_bcf_topics
from bimgraph.deviations.graph import observed_planes_isam2
from bimgraph.deviations.outputs import write_deviation_outputs
from bimgraph.deviations.report import CSV_FILE, JSON_FILE, load_deviations, read_csv_rows
from bimgraph.evaluation.metrics import ate, extrinsic_error
from bimgraph.geometry import pose_to_tum
from bimgraph.sequence.format import Camera, InitialAlignment, Sequence, SequenceMeta, save_sequence

# Issue 8's deviation scenario (docs/experiments.md): 20 % of the faces moved 5-10 cm, no tilts,
# 30 % of the walls missing, and clutter, boards and partitions making 28-35 % of the planes
DEVIATIONS_AT_30_PERCENT_CLUTTER = {"offset_fraction": 0.2, "offset_min_m": 0.05, "offset_max_m": 0.10,
                                    "tilt_fraction": 0.0, "missing_wall_fraction": 0.3,
                                    "clutter_per_m2": 0.06, "boards_per_m2": 0.01, "partitions": 1}

MOVED = {"r00E": 0.08}  # the wall was built 8 cm into the room; the walk starts facing it
MOVED_LATE = {"r10E": 0.08}  # the same in the second room, first seen at keyframe 80 of 160


def moved_plan(plane_map: PlaneMap, moved: dict[str, float] = MOVED) -> PlaneMap:
    """The plan, with the faces in `moved` drawn where they were not built: the world (as
    observed) lies moved[face] along the normal from it."""
    faces = []
    for f in plane_map.faces:
        shift = -moved.get(f.id, 0.0) * np.asarray(f.normal)
        faces.append(f.model_copy(update={"offset": f.offset - float(shift @ f.normal),
                                          "polygon": [tuple(np.asarray(p) + shift) for p in f.polygon],
                                          "centre": tuple(np.asarray(f.centre) + shift)}))
    return PlaneMap(faces=faces)


@pytest.fixture(scope="module")
def run():
    scene = make_scene(160, rooms=(2, 1), seed=0, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map, MOVED_LATE)
    backend = Backend(plan, BackendConfig(), scene.initial)
    results = [backend.process(kf) for kf in scene.keyframes]
    return plan, backend, results


def test_every_landmark_is_read_from_the_graph(run):
    plan, backend, _ = run
    planes, _ = observed_planes_isam2(backend.graph, backend.landmarks.items)
    assert len(planes) == len(backend.landmarks.items)
    with_factor = {p.landmark for p in planes if p.bim_factor is not None}
    assert with_factor == set(backend.graph.bim_index)
    for p in planes:
        assert p.cov.shape == (15, 15)
        assert np.linalg.eigvalsh(p.cov).min() > -1e-12
        if p.bim_factor is not None:
            A, e_w = p.bim_factor
            assert A.shape == (3, 15) and e_w.shape == (3,)


def test_the_read_out_joint_marginals_are_the_graphs_at_its_estimate(run):
    """Read all at once, each landmark's joint marginal with its anchor and the extrinsic is
    gtsam's for the whole graph at the current estimate (iSAM2's own marginals are those of
    where it last relinearised each variable: here up to 30 % apart, through the robust
    kernels' weights)."""
    _, backend, _ = run
    planes = {p.landmark: p for p in observed_planes_isam2(backend.graph, backend.landmarks.items)[0]}
    marginals = gtsam.Marginals(backend.graph.batch(), backend.graph.estimate())
    for lm in backend.landmarks.items[::3]:
        keys = [E, X(lm.anchor), L(lm.id)]
        np.testing.assert_allclose(planes[lm.id].cov, joint_covariance(marginals, keys), rtol=1e-7, atol=1e-14)


def test_outputs_are_written_and_consistent_with_the_truth(run, tmp_path):
    plan, backend, results = run
    planes, _ = observed_planes_isam2(backend.graph, backend.landmarks.items)
    camera = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    cfg = DeviationConfig()
    data = write_deviation_outputs(tmp_path, plan, planes, results[-1].T_B_S, [r.T_B_C for r in results], camera, cfg)
    assert load_deviations(tmp_path / JSON_FILE) == data
    assert len(read_csv_rows(tmp_path / CSV_FILE)) == len(data.faces) + len(data.unplanned)
    assert len(read_bcf_topics(tmp_path / BCF_FILE)) == sum(f.status == "deviating" for f in data.faces)

    measured = [f for f in data.faces if f.offset_m is not None]
    assert {f.face_id for f in measured} >= {"r00E", "r00W", "r10E", "r10W"}
    for f in measured:
        truth = MOVED_LATE.get(f.face_id, 0.0)
        # The graph's sigma is honest: every face within 4 sigma of the truth.
        assert abs(f.offset_m - truth) < 4 * f.offset_sigma_m + 0.005, f
    assert [f.face_id for f in measured if f.status == "deviating"] == ["r10E"]


@pytest.fixture(scope="module")
def offline_runs():
    """The offline backend on rooms where the moved wall is seen early enough for the robust
    kernel alone to follow it (scene seed 1), without and with graduated non-convexity."""
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map)
    runs = {}
    for gnc in (False, True):
        cfg = BackendConfig()
        cfg.offline.gnc = gnc
        est = OfflineEstimator(plan, cfg, scene.initial)
        runs[gnc] = est, est.run(scene.keyframes)
    return scene, plan, runs


def test_offline_gnc_keeps_the_moved_wall_out_of_the_alignment(offline_runs):
    scene, plan, runs = offline_runs
    est, res = runs[True]
    assert {face: verdict for (_, face), verdict in est.judge.verdicts.items() if verdict != "kept"} == {"r00E": "direction"}
    assert {lm.face: lm.alignment for lm in res.landmarks if lm.face == "r00E"} == {"r00E": "direction"}
    # the moved wall keeps its face (to be measured) and every face observed keeps its match
    assert {lm.face for lm in res.landmarks if lm.face} == {lm.face for lm in runs[False][1].landmarks if lm.face}
    # the kernel alone follows the moved wall; GNC's alignment is the consistent walls'
    assert ate(runs[False][1].T_B_C, np.asarray(scene.T_B_C)) > 0.04
    assert ate(res.T_B_C, np.asarray(scene.T_B_C)) < 0.015
    assert extrinsic_error(res.T_B_S, scene.T_B_S)[1] < 1.5


def test_the_judgement_sees_the_whole_graph_through_its_marginal(offline_runs):
    """The robust alignment judges on the rest of the graph's Gaussian marginal on the
    extrinsic and the judged landmarks held in S (`bimgraph.backend.reduced`): at the point it
    was taken, the reduced graph with the plane-to-BIM factors has the whole graph's joint
    marginals of those, mapped to the planes in S by central differences, so the tolerance
    estimate and the studentized tests see the same; at the whole graph's optimum it is at its
    own; and its point, mapped back, is the whole graph's estimate."""
    scene, plan, runs = offline_runs
    est, _ = runs[True]
    observations = {kf.index: observations_of(kf, est.online.build) for kf in scene.keyframes}
    matched = [lm for lm in est.landmarks.current() if lm.face is not None]
    start = est.online.graph.estimate()
    whole = est._graph(scene.keyframes, observations, start)
    values = BatchSolver(50, 1e-9)(whole, start)
    judged = reduced(est._graph(scene.keyframes, observations, values, lambda lm: None), values, matched)
    small = judged.graph(est.judge.judged_factor)
    assert small.size() < whole.size() / 10

    keys = bim_keys(matched)
    rows = {key: 6 * (key in {E} | {X(lm.anchor) for lm in matched}) or 3 for key in keys}
    starts = dict(zip(keys, np.cumsum([0] + [rows[key] for key in keys])))
    keys_S = [E] + [PLANE_S(lm.id) for lm in matched]
    T = np.zeros((6 + 3 * len(matched), sum(rows.values())))  # whole tangent -> (E, planes in S) tangent
    T[:6, starts[E]:starts[E] + 6] = np.eye(6)
    h = 1e-6
    for i, lm in enumerate(matched):
        plane_S = judged.point.atOrientedPlane3(PLANE_S(lm.id))
        for key, dim in ((X(lm.anchor), 6), (L(lm.id), 3)):
            for k in range(dim):
                moved = [gtsam.Values(values), gtsam.Values(values)]
                for sign, v in zip((1, -1), moved):
                    v.update(key, (values.atPose3(key) if dim == 6 else values.atOrientedPlane3(key)).retract(sign * h * np.eye(dim)[k]))
                ends = [v.atOrientedPlane3(L(lm.id)).transform(v.atPose3(X(lm.anchor)).inverse()) for v in moved]
                T[6 + 3 * i:9 + 3 * i, starts[key] + k] += (plane_S.localCoordinates(ends[0]) - plane_S.localCoordinates(ends[1])) / (2 * h)
    expected = T @ JointMarginals(whole, values, keys)(keys) @ T.T
    np.testing.assert_allclose(JointMarginals(small, judged.point, keys_S)(keys_S), expected, rtol=1e-5, atol=1e-12)

    # its linear term: the rest pulls against the plane-to-BIM factors, which balance it at the
    # whole graph's optimum, so the reduced graph is at its own optimum there too
    # (the whole graph solved to 1e-9: its reduced graph moves E 3e-6; with the term's sign
    # flipped, 3e-3)
    solved = BatchSolver(20, 1e-12)(small, judged.point)
    assert np.linalg.norm(judged.point.atPose3(E).localCoordinates(solved.atPose3(E))) < 1e-5
    # and, as gtsam's marginal leaves it, the rest's error is zero at the rest's own minimum
    # (the solvers' relative tolerance reads the error's level)
    rest = judged.graph(lambda lm: None)
    assert abs(rest.error(BatchSolver(20, 1e-12)(rest, judged.point))) < 1e-9

    back = judged.anchored(judged.point)
    np.testing.assert_allclose(back.atPose3(E).matrix(), values.atPose3(E).matrix(), atol=1e-12)
    for lm in matched:
        np.testing.assert_allclose(back.atOrientedPlane3(L(lm.id)).planeCoefficients(),
                                   values.atOrientedPlane3(L(lm.id)).planeCoefficients(), atol=1e-12)


def test_offline_gnc_measures_the_moved_wall_against_the_others(offline_runs, tmp_path):
    _, plan, runs = offline_runs
    _, res = runs[True]
    camera = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    data = write_deviation_outputs(tmp_path, plan, res.observed_planes, res.T_B_S, res.T_B_C, camera, DeviationConfig())
    moved = next(f for f in data.faces if f.face_id == "r00E")
    assert moved.status == "deviating"
    assert abs(moved.offset_m - MOVED["r00E"]) < min(3 * moved.offset_sigma_m, 0.01)
    sound = [f for f in data.faces if f.offset_m is not None and f.face_id not in MOVED]
    assert len(sound) >= 6
    for f in sound:
        assert abs(f.offset_m) < min(4 * f.offset_sigma_m + 0.005, 0.015), f


@pytest.mark.parametrize("refine, judge_every", [(True, 50), (False, 0), (False, 50)])
def test_an_online_run_writes_the_refined_report(tmp_path, refine, judge_every):
    """Online without the judgement (`isam2.judge_every` 0), the kernel follows the moved wall
    the walk sees first, and read at the online graph's own solution
    (`deviations.online_refine: false`) three sound faces come out 7-8 cm off at 6 sigma. By
    default an online run's report is measured where the offline rounds take its graph
    (`OfflineEstimator(causal=)`): the moved wall alone deviates, measured against the others;
    the online judgement (on by default) gets there in the online graph itself."""
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    meta = SequenceMeta(name="moved", model="planes.json", sensor="planes",
                        initial_alignment=InitialAlignment(T_B_S=tuple(pose_to_tum(scene.initial.T_B_S))))
    save_sequence(Sequence(root=tmp_path / "seq", meta=meta, keyframes=scene.keyframes))
    save_plane_map(moved_plan(scene.plane_map), tmp_path / "seq" / "planes.json")
    cfg = Config()
    cfg.deviations.online_refine = refine
    cfg.backend.isam2.judge_every = judge_every
    run_pipeline(tmp_path / "seq", tmp_path / "out", mode="online", config=cfg)
    faces = load_deviations(tmp_path / "out" / JSON_FILE).faces
    deviating = [f.face_id for f in faces if f.status == "deviating"]
    if refine or judge_every:
        assert deviating == ["r00E"], faces
        for f in faces:
            if f.offset_m is not None:
                assert abs(f.offset_m - MOVED.get(f.face_id, 0.0)) < min(4 * f.offset_sigma_m + 0.005, 0.015), f
    else:
        sound_off = [f for f in faces if f.face_id not in MOVED and f.status == "deviating"]
        assert len(sound_off) >= 3 and all(abs(f.offset_m) > 0.05 for f in sound_off), faces


def tilted_plan(plane_map: PlaneMap, face_id: str, deg: float) -> PlaneMap:
    """The plan with `face_id` turned by `deg` about the vertical through its centre: the
    wall (as observed) was built out of line by that angle."""
    R = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    faces = []
    for f in plane_map.faces:
        if f.id == face_id:
            c = np.asarray(f.centre)
            n = R @ np.asarray(f.normal)
            f = f.model_copy(update={"normal": tuple(n), "offset": float(-n @ c),
                                     "polygon": [tuple(c + R @ (np.asarray(p) - c)) for p in f.polygon]})
        faces.append(f)
    return PlaneMap(faces=faces)


def test_offline_gnc_takes_a_wall_built_out_of_line_out_of_the_alignment(tmp_path):
    """A wall turned 2 deg from plan, against a 0.5 deg direction tolerance: not even its
    direction can be kept (verdict "out"), and the report measures its tilt."""
    scene = make_scene(160, rooms=(2, 1), seed=0, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = tilted_plan(scene.plane_map, "r00E", 2.0)
    cfg = BackendConfig()
    cfg.noise.bim_normal_deg = 0.5
    est = OfflineEstimator(plan, cfg, scene.initial)
    res = est.run(scene.keyframes)
    assert {face: verdict for (_, face), verdict in est.judge.verdicts.items() if verdict != "kept"} == {"r00E": "out"}
    assert ate(res.T_B_C, np.asarray(scene.T_B_C)) < 0.015
    camera = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    data = write_deviation_outputs(tmp_path, plan, res.observed_planes, res.T_B_S, res.T_B_C, camera, DeviationConfig())
    tilted = next(f for f in data.faces if f.face_id == "r00E")
    assert tilted.status == "deviating"
    assert abs(tilted.tilt_deg - 2.0) < 3 * tilted.tilt_sigma_deg


def test_offline_tightens_the_tolerance_to_what_the_walls_show(tmp_path):
    """The sound walls of the synthetic rooms are exactly as planned: the tolerance estimated
    from them is well inside the configured 1 cm, so the sound faces are measured well
    enough to say they are within tolerance (with the configured one, none is), and the moved
    wall is still found and measured."""
    scene = make_scene(160, rooms=(2, 1), seed=0, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map)
    camera = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    status = {}
    for estimate in (False, True):
        cfg = BackendConfig()
        cfg.offline.estimate_tolerance = estimate
        est = OfflineEstimator(plan, cfg, scene.initial)
        res = est.run(scene.keyframes)
        data = write_deviation_outputs(tmp_path / str(estimate), plan, res.observed_planes, res.T_B_S, res.T_B_C, camera,
                                       DeviationConfig())
        status[estimate] = {f.face_id: f.status for f in data.faces if f.offset_m is not None}
        if estimate:
            assert res.bim_tolerance == est.judge.tolerance
            assert est.judge.tolerance[1] < 0.006 and est.judge.tolerance[0] < np.radians(0.5)
            moved = next(f for f in data.faces if f.face_id == "r00E")
            assert abs(moved.offset_m - MOVED["r00E"]) < min(3 * moved.offset_sigma_m, 0.01)
            assert ate(res.T_B_C, np.asarray(scene.T_B_C)) < 0.01
    sound = set(status[True]) - set(MOVED)
    assert len(sound) >= 6
    # (all but one: r00N, measured tilted 0.39 deg at a sigma of 0.14, is not proven within
    # 0.5 deg, `deviations.conformance_k`)
    within = [f for f in sound if status[True][f] == "within_tolerance"]
    assert len(within) >= len(sound) - 1 and {status[True][f] for f in sound} <= {"within_tolerance", "not_enough_evidence"}
    assert {status[False][f] for f in sound} == {"not_enough_evidence"}
    assert status[True]["r00E"] == status[False]["r00E"] == "deviating"


def test_offline_judges_each_wall_against_the_others(monkeypatch):
    """A wall built 5 cm off, seen early: the poses that see it follow it, so its residual in
    the solved graph passes GNC's test and the alignment keeps it whole. Measured against the
    rest of the graph, with its own pull taken out (`offline.studentized`), it fails: its
    offset leaves the alignment, and the poses come back. (A chosen case: at 4 or 6 cm, or with
    scene seed 3, both judgements agree; with seed 2 the wall is demoted but the ATE is no
    lower. So is the tolerance: the estimate's 95 % upper bound and a 0.1 deg floor, as the
    case was chosen with; with the estimate itself the walls are trusted tighter, and GNC
    alone demotes the wall too.)"""
    monkeypatch.setitem(MOVED, "r00E", 0.05)
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map)
    verdicts, errors = {}, {}
    for studentized in (False, True):
        cfg = BackendConfig()
        cfg.noise.bim_offset_m = 0.015  # GNC keeps whole what lies within 5.1 cm (3.4 sigma)
        cfg.offline.tolerance_confidence, cfg.offline.tolerance_floor_deg = 0.95, 0.1
        cfg.offline.studentized = studentized
        est = OfflineEstimator(plan, cfg, scene.initial)
        res = est.run(scene.keyframes)
        verdicts[studentized] = {face: verdict for (_, face), verdict in est.judge.verdicts.items() if verdict != "kept"}
        errors[studentized] = ate(res.T_B_C, np.asarray(scene.T_B_C))
    assert verdicts == {False: {}, True: {"r00E": "direction"}}
    assert errors[True] < 0.9 * errors[False]


@pytest.mark.parametrize("built_off_m", [0.0, 0.12])
def test_a_wall_the_rest_barely_checks_is_tested_left_out(built_off_m):
    """The judged graph by hand: the extrinsic at the identity, seven walls whose planes in S
    the rest of the graph knows to 2 mm, and r10E's to 2 cm only (a wall seen a few times
    from poses that little else holds), built `built_off_m` into the room. Kept, its factor
    pulls its plane onto the face: its redundancy is some 0.05^2 / 2^2, and the closed-form
    studentized test, which divides by it, does not apply (`tolerance.studentized` None).
    Left out, the rest puts it 12 cm off at 2 cm: its offset fails (6 sigma) and only its
    direction stays; built as planned, every wall passes."""
    from bimgraph.backend import tolerance
    from bimgraph.backend.associate_bim import FaceIndex
    from bimgraph.backend.graph import S_FRAME, FactorBuilder, plane_cov
    from bimgraph.backend.landmarks import KEPT, Landmark, LandmarkTable
    from bimgraph.backend.reduced import Reduced
    from bimgraph.backend.robust_alignment import RobustAlignment, _judged_keys
    from factors import plane_prior_factor

    cfg = BackendConfig()
    plan = make_scene(20, rooms=(2, 1), seed=0).plane_map
    faces = FaceIndex(plan, cfg.bim_association)
    rest, point, landmarks = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
    for pose, sigma in ((E, 0.2), (S_FRAME, 1e-8)):
        rest.add(gtsam.PriorFactorPose3(pose, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, sigma)))
        point.insert(pose, gtsam.Pose3())
    for j, face in enumerate(f for f in plan.faces if f.kind == "wall"):
        plane = np.r_[face.normal, face.offset - (built_off_m if face.id == "r10E" else 0.0)]
        sigma_m = 0.02 if face.id == "r10E" else 0.002
        rest.add(plane_prior_factor(plane, gtsam.noiseModel.Gaussian.Covariance(plane_cov(np.radians(0.05), sigma_m)), PLANE_S(j)))
        point.insert(PLANE_S(j), gtsam.OrientedPlane3(plane))
        landmarks[j] = Landmark(j, None, plane, np.eye(3), np.eye(4), face=face.id)
    judged = Reduced(rest, point, landmarks, {j: gtsam.Pose3() for j in landmarks})
    alignment = RobustAlignment(faces, FactorBuilder(cfg), LandmarkTable(), cfg.offline)
    alignment.tolerance = (np.radians(0.05), 0.002)
    alignment.verdicts = {(j, lm.face): KEPT for j, lm in landmarks.items()}
    solve = BatchSolver(20, 1e-9)
    graph = judged.graph(alignment.factors(alignment.verdicts))
    values = solve(graph, point)

    moved = next(j for j, lm in landmarks.items() if lm.face == "r10E")
    A, e = alignment._deviation_residual(landmarks[moved], "r10E", values)
    keys = _judged_keys(landmarks[moved])
    assert tolerance.studentized(A, e, JointMarginals(graph, values, keys)(keys)) is None
    worst = alignment._worst_studentized(graph, values, judged, solve)
    if built_off_m:
        assert worst == ((moved, "r10E"), "direction")
        assert np.sqrt(alignment._left_out_offset((moved, "r10E"), judged, values, solve)) == pytest.approx(6.0, abs=0.3)
    else:
        assert worst is None


@pytest.mark.parametrize("seed", [2, 4])
def test_offline_judgement_finds_the_sound_walls_among_walls_moved_alike(tmp_path, seed):
    """Issue 8's scenario at its 30 % of clutter. Seed 2: walls built 6-10 cm off the same way
    bend the walk into a consensus that fits the configured 1 deg tolerance as well as the
    sound walls do (within 0.2 units of TLS cost, even with the true associations); compared
    at that tolerance the moved walls won (extrinsic 9.4 cm off, ATE 9.5 cm, measured), compared
    each under the tolerance its own kept walls show the sound walls win. Seed 4: neither start
    finds the sound walls at the configured tolerance (4.5 cm, ATE 6.5 cm); GNC at a tighter
    one does (`offline.gnc_tolerance_steps`)."""
    from bimgraph.backend.pipeline import initial_alignment, load_model, model_path
    from bimgraph.sequence.format import load_sequence
    from bimgraph.sequence.groundtruth import load_groundtruth
    from bimgraph.sim.simulate import SimOptions, simulate

    cfg = Config()
    cfg.sim.as_built_site = cfg.sim.as_built_site.model_copy(update=DEVIATIONS_AT_30_PERCENT_CLUTTER)
    root = tmp_path / f"dev{seed}"
    simulate(SimOptions(output=root, scenario="site", keyframes=600, seed=seed), cfg)
    sequence, truth = load_sequence(root), load_groundtruth(root)
    res = OfflineEstimator(load_model(model_path(root, sequence.meta, None), cfg), cfg.backend,
                           initial_alignment(sequence.meta, cfg)).run(sequence.keyframes)
    assert extrinsic_error(res.T_B_S, truth.T_B_S)[1] < 1.5
    assert ate(res.T_B_C, truth.T_B_C) < 0.02


def test_offline_challenge_overturns_the_worse_consensus(monkeypatch):
    """The judgement is made to choose the complement of its own consensus (the moved wall
    kept whole, the walls that disagree with it held by their direction); once the rounds
    settle, the challenge on the whole graph finds its complement (the consistent walls)
    cheaper and takes it: the moved wall ends out of the alignment, and the poses with the
    sound walls."""
    from bimgraph.backend.landmarks import DIRECTION, KEPT
    from bimgraph.backend.robust_alignment import RobustAlignment

    real_decide, real_challenge = RobustAlignment.decide, OfflineEstimator._challenge
    challenges = []

    def decide(self, matches, reduced):
        real_decide(self, matches, reduced)
        self.verdicts = {m: DIRECTION if v == KEPT else KEPT for m, v in self.verdicts.items()}
        return BatchSolver(20, 1e-6)(reduced.graph(self.factors(self.verdicts)), reduced.point)

    def challenge(self, *args):
        challenges.append(dict(self.judge.verdicts))
        return real_challenge(self, *args)

    monkeypatch.setattr(RobustAlignment, "decide", decide)
    monkeypatch.setattr(OfflineEstimator, "_challenge", challenge)
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map)
    est = OfflineEstimator(plan, BackendConfig(), scene.initial)
    res = est.run(scene.keyframes)
    assert [{face for (_, face), v in verdicts.items() if v == KEPT} for verdicts in challenges][0] == {"r00E"}
    assert {face: v for (_, face), v in est.judge.verdicts.items() if v != KEPT} == {"r00E": "direction"}
    assert ate(res.T_B_C, np.asarray(scene.T_B_C)) < 0.015
    # the summary says so: which consensus won, by how much, and the faces judged otherwise
    assert res.alignment_challenge["complement_taken"] and res.alignment_challenge["margin"] > 0
    assert "r00E" in res.alignment_challenge["contested_faces"]


def test_likelihood_cost_is_the_tls_cost_at_the_configured_tolerance_and_rewards_a_tight_fit():
    """At the configured tolerance the candidates' likelihood cost is the TLS cost plus the
    same normalisation for every factor; at a tighter tolerance the walls that still fit cost
    less, and a wall that no longer fits costs what an off-plan wall costs (the same at any
    tolerance)."""
    from scipy.stats import chi2

    scene = make_scene(60, rooms=(2, 1), seed=7)
    est = OfflineEstimator(scene.plane_map, BackendConfig(), scene.initial)
    est.run(scene.keyframes)
    judge, matches = est.judge, est._matches()
    obs = {kf.index: observations_of(kf, est.online.build) for kf in scene.keyframes}
    start = est.online.graph.estimate()
    judged = reduced(est._graph(scene.keyframes, obs, start, lambda lm: None), start, [est.landmarks[j] for j, _ in matches])
    values, rest = judged.point, judged.graph(lambda lm: None).error(judged.point)
    configured = est.online.build.bim_tolerance()
    c2 = chi2.ppf(judge.cfg.gnc_probability, 3)

    def r2():
        return np.array([2.0 * judge.factor(judged.landmarks[j], 1.0).error(values) for j, _ in matches])

    log_det = 2 * np.log(configured[0]) + np.log(configured[1])
    judge.tolerance = configured
    tls = rest + 0.5 * np.minimum(r2(), c2).sum()
    assert judge._likelihood_cost(matches, judged, values) == pytest.approx(tls + len(matches) * log_det, rel=1e-9)
    judge.tolerance = (configured[0] / 4, configured[1] / 4)
    off_plan = 0.5 * c2 + log_det
    tight = 2 * np.log(configured[0] / 4) + np.log(configured[1] / 4)
    expected = rest + np.minimum(0.5 * r2() + tight, off_plan).sum()
    assert judge._likelihood_cost(matches, judged, values) == pytest.approx(expected, rel=1e-9)
    assert (0.5 * r2() + tight < off_plan).any()
