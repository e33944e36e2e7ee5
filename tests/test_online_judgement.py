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


@pytest.mark.parametrize("scale", [1.0, 0.2])
def test_the_judgement_sees_the_walk_stiffer_than_the_noise_given(scale):
    """The front-end gives no covariance, so the odometry takes the configured default, ten
    times the walk's true noise per step (0.1 deg and 5 mm against 0.01 deg and 1 mm). The walk
    starts facing a wall built 6 cm off. Judged under the noise as given
    (`isam2.judge_odometry_scale` 1), the walk bends around that wall until it fits, the wall is
    kept and the extrinsic ends 5.8 cm off; judged at the default 0.2, the wall goes out and the
    extrinsic ends within 1 cm."""
    scene = make_scene(160, rooms=(2, 1), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = moved_plan(scene.plane_map, {"r00E": 0.06})
    cfg = BackendConfig()
    cfg.isam2.judge_every = 10
    cfg.isam2.judge_odometry_scale = scale
    backend = Backend(plan, cfg, scene.initial)
    results = [backend.process(kf.model_copy(update={"cov": None})) for kf in scene.keyframes]
    verdicts = {lm.face: lm.alignment for lm in backend.landmarks.items if lm.face == "r00E"}
    error_cm = extrinsic_error(results[-1].T_B_S, scene.T_B_S)[1]
    if scale == 1.0:
        assert verdicts == {"r00E": "kept"} and error_cm > 4.0
    else:
        assert verdicts == {"r00E": "out"} and error_cm < 1.0
