"""The online judgement (`isam2.judge_every`): the robust alignment run on the graph so far, so
that a wall built off plan that the walk sees first cannot hold the online alignment."""

import numpy as np
import pytest

from bimgraph.backend.online import Backend
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig, DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.graph import observed_planes_isam2
from bimgraph.evaluation.metrics import extrinsic_error
from bimgraph.geometry import inverse
from test_deviations_backend import moved_plan


@pytest.mark.parametrize("judge_every", [0, 10])
def test_online_judgement_overrules_a_moved_wall_seen_first(judge_every):
    """The walk starts facing a wall built 8 cm off. With the robust kernel alone
    (`isam2.judge_every` 0) the online alignment follows it, and the sound walls across x seen
    after it are reported deviating; judged online (as offline, GNC over the graph so far, once
    a newly matched wall misfits), the alignment ends with the sound walls and only the moved
    wall deviates."""
    scene = make_scene(160, rooms=(2, 1), seed=0, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map)
    cfg = BackendConfig()
    cfg.isam2.judge_every = judge_every
    backend = Backend(plan, cfg, scene.initial)
    results = [backend.process(kf) for kf in scene.keyframes]
    planes, _ = observed_planes_isam2(backend.graph, backend.landmarks.items)
    data = assess(plan, planes, inverse(results[-1].T_B_S), DeviationConfig())
    deviating = sorted(f.face_id for f in data.faces if f.status == "deviating")
    if judge_every:
        assert deviating == ["r00E"]
        assert {lm.face: lm.alignment for lm in backend.landmarks.items if lm.face == "r00E"} == {"r00E": "direction"}
        assert extrinsic_error(results[-1].T_B_S, scene.T_B_S)[1] < 2.0
    else:
        assert {"r00W", "r10W", "r10E"} <= set(deviating)


@pytest.mark.parametrize("scale, studentized", [(1.0, None), (1.0, 0.9999), (0.2, 0.9999)])
def test_the_judgement_sees_the_walk_stiffer_than_the_noise_given(scale, studentized):
    """The front-end gives no covariance, so the odometry takes the configured default, ten
    times the walk's true noise per step (0.1 deg and 5 mm against 0.01 deg and 1 mm). The walk
    starts facing a wall built 6 cm off. Judged under the noise as given
    (`isam2.judge_odometry_scale` 1) without the studentized tests, the walk bends around that
    wall until it fits, the wall is kept and the extrinsic ends 5.8 cm off. The studentized
    test (`isam2.judge_studentized_probability`), which measures the wall against the rest
    with its own pull taken out, finds it off plan even so (0.8 cm); at the default 0.2 GNC
    already puts it out (0.4 cm)."""
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map, {"r00E": 0.06})
    cfg = BackendConfig()
    cfg.isam2.judge_every = 10
    cfg.isam2.judge_odometry_scale = scale
    cfg.isam2.judge_studentized_probability = studentized
    backend = Backend(plan, cfg, scene.initial)
    results = [backend.process(kf.model_copy(update={"cov": None})) for kf in scene.keyframes]
    verdicts = {lm.face: lm.alignment for lm in backend.landmarks.items if lm.face == "r00E"}
    error_cm = extrinsic_error(results[-1].T_B_S, scene.T_B_S)[1]
    if studentized is None:
        assert verdicts == {"r00E": "kept"} and error_cm > 4.0
    elif scale == 1.0:
        assert verdicts == {"r00E": "direction"} and error_cm < 1.0
    else:
        assert verdicts == {"r00E": "out"} and error_cm < 1.0
        # judged as offline, the tolerance tightened to what the kept walls show (0.05 deg, 5 mm)
        normal_rad, offset_m = backend.judge.tolerance
        assert np.degrees(normal_rad) < 0.5 * cfg.noise.bim_normal_deg and offset_m < cfg.noise.bim_offset_m


def test_the_stiff_graph_replaces_each_odometry_factor_and_leaves_the_graph_as_given():
    """The judgement's graph holds the same factors as the online graph without its
    plane-to-BIM ones, each odometry factor with its sigmas scaled by
    `judge_odometry_scale`; the online graph's own odometry keeps the noise as given."""
    scene = make_scene(60, rooms=(1, 1), seed=2)
    cfg = BackendConfig()
    cfg.isam2.judge_odometry_scale = 0.2
    backend = Backend(scene.plane_map, cfg, scene.initial)
    for kf in scene.keyframes:
        backend.process(kf)
    graph = backend.graph
    n_odometry = len(graph.odometry_index)
    assert n_odometry == len(scene.keyframes) - 1
    assert graph.without_bim(odometry=False).size() == graph.without_bim().size() - n_odometry
    stiff = backend.judge.stiff_rest(graph, backend.odometry, backend._keyframes)
    assert stiff.size() == graph.without_bim().size()

    def sigmas(factor):
        return np.sqrt(np.diag(np.linalg.inv(factor.noiseModel().information())))

    previous, kf = scene.keyframes[10], scene.keyframes[11]
    given = backend.odometry.factor(previous, kf)
    scaled = backend.odometry.scaled(0.2)
    np.testing.assert_allclose(sigmas(scaled.factor(previous, kf)), 0.2 * sigmas(given), rtol=1e-9)
    np.testing.assert_allclose(backend.odometry.variance, [1.0, 1.0])
    assert backend.odometry.factor(previous, kf) is given
    in_isam2 = graph.isam.getFactorsUnsafe().at(graph.odometry_index[kf.index])
    np.testing.assert_allclose(sigmas(in_isam2), sigmas(given), rtol=1e-9)
