"""The front-end's drift rates: measured from the smoothed poses, taken out of the odometry."""

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimgraph.backend import drift
from bimgraph.backend.offline import OfflineEstimator
from bimgraph.backend.online import Backend
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig
from bimgraph.evaluation.metrics import ate
from bimgraph.geometry import inverse, make_pose, pose_to_tum

YAW_DEG_PER_M = 0.2
DRIFT_PER_M = 0.01 * np.array([0.6, -0.8, 0.0])  # 1 % of the distance, in a fixed direction of S


def biased(T_S_C: list[np.ndarray], scale_error: float = 0.0) -> list[np.ndarray]:
    """A front-end whose heading turns at a steady rate about S's z and whose position runs
    off in a fixed direction, both per metre travelled (as a gyroscope or accelerometer bias
    does; the simulator's front-end, without its noise), its steps `scale_error` too long."""
    R_drift, p = np.eye(3), T_S_C[0][:3, 3].copy()
    out = [T_S_C[0]]
    for previous, T in zip(T_S_C, T_S_C[1:]):
        step = T[:3, 3] - previous[:3, 3]
        length = np.linalg.norm(step)
        R_drift = Rotation.from_rotvec([0.0, 0.0, np.radians(YAW_DEG_PER_M) * length]).as_matrix() @ R_drift
        p = p + (1.0 + scale_error) * (R_drift @ step) + DRIFT_PER_M * length
        out.append(make_pose(R_drift @ T[:3, :3], p))
    return out


def rebuilt(frontend: list[np.ndarray], rates: drift.DriftRates) -> list[np.ndarray]:
    """The front-end's walk made again from its steps, each without the drift `rates`."""
    out = [frontend[0]]
    for previous, T in zip(frontend, frontend[1:]):
        out.append(out[-1] @ rates.corrected(previous, inverse(previous) @ T))
    return out


def hand_held(T_S_C: list[np.ndarray]) -> list[np.ndarray]:
    """The walk with the camera rolled and pitched from step to step, so that a rate taken in
    the wrong keyframe's frame would show."""
    rng = np.random.default_rng(0)
    return [make_pose(T[:3, :3] @ Rotation.from_rotvec(rng.normal(size=3) * 0.2).as_matrix(), T[:3, 3]) for T in T_S_C]


def test_no_drift_is_no_correction():
    T = make_pose(Rotation.from_euler("zx", [0.4, 0.1]).as_matrix(), np.array([1.0, 2.0, 0.5]))
    step = make_pose(Rotation.from_euler("z", 0.2).as_matrix(), np.array([0.3, -0.1, 0.0]))
    np.testing.assert_allclose(drift.DriftRates().corrected(T, step), step, atol=1e-15)
    assert drift.estimate([T, T @ step], [T, T @ step]).differs(drift.DriftRates(), 1e-6) is False


def test_rates_of_a_biased_front_end_are_recovered_and_removed():
    scene = make_scene(120, rooms=(1, 1), floor=False)
    T_S_C = hand_held([inverse(scene.T_B_S) @ T for T in scene.T_B_C])
    frontend = biased(T_S_C)
    rates = drift.estimate(frontend, T_S_C)
    # what to add to the front-end's steps: the bias, negated (to first order in the step)
    np.testing.assert_allclose(np.degrees(rates.rotation), [0.0, 0.0, -YAW_DEG_PER_M], atol=0.01 * YAW_DEG_PER_M)
    np.testing.assert_allclose(rates.translation, -DRIFT_PER_M, atol=0.02 * np.linalg.norm(DRIFT_PER_M))
    # the corrected steps rebuild the true path to well below the drift (5 cm here)
    path = rebuilt(frontend, rates)
    assert np.linalg.norm(frontend[-1][:3, 3] - T_S_C[-1][:3, 3]) > 0.05
    assert max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(path, T_S_C)) < 0.005
    # and its orientation, where the correction's frame matters (measured: 0.005 deg; taken
    # in the frame of the keyframe after instead of before, 0.12 deg)
    angles = [Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).magnitude() for a, b in zip(path, T_S_C)]
    assert np.degrees(max(angles)) < 0.02


def test_a_scale_error_is_recovered_beside_the_bias():
    """Steps 2 % too long (a wheel odometry's scale), on top of the heading and position
    bias: the fit names the scale apart from the bias (measured: -1.955 %, the bias to 1e-7),
    and the steps without both rebuild the path (measured: 0.7 mm off at worst; 4.7 cm with
    the bias alone taken out, 6.3 cm with nothing)."""
    scene = make_scene(120, rooms=(1, 1), floor=False)
    T_S_C = hand_held([inverse(scene.T_B_S) @ T for T in scene.T_B_C])
    frontend = biased(T_S_C, scale_error=0.02)
    rates = drift.estimate(frontend, T_S_C)
    assert rates.scale == pytest.approx(-0.02 / 1.02, rel=0.02)
    # (per metre of the front-end's steps, 2 % longer, and taken out before the scale is)
    np.testing.assert_allclose(rates.translation, -DRIFT_PER_M / 1.02**2, atol=0.01 * np.linalg.norm(DRIFT_PER_M))
    assert max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(rebuilt(frontend, rates), T_S_C)) < 0.005
    without_scale = drift.DriftRates(rates.rotation, rates.translation)
    assert max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(rebuilt(frontend, without_scale), T_S_C)) > 0.03
    assert rates.summary()["scale_percent"] == pytest.approx(-1.96, abs=0.02)


def test_a_scale_needs_steps_in_more_than_one_direction():
    """Along one line a scale and a position bias along it are the same: the bias takes it,
    as before the scale was fitted; nor is a scale found where there is none, against the
    steps' noise."""
    T_S_C = [make_pose(np.eye(3), np.array([0.3 * k, 0.0, 0.0])) for k in range(50)]
    rates = drift.estimate([make_pose(np.eye(3), 1.02 * T[:3, 3]) for T in T_S_C], T_S_C)
    assert rates.scale == 0.0 and rates.translation[0] == pytest.approx(-0.02 / 1.02)
    scene = make_scene(120, rooms=(1, 1), floor=False)
    truth = [inverse(scene.T_B_S) @ T for T in scene.T_B_C]
    rng = np.random.default_rng(3)
    noisy = [make_pose(T[:3, :3], T[:3, 3] + rng.normal(scale=0.002, size=3)) for T in biased(truth)]
    assert drift.estimate(noisy, truth, (1e-3, 0.002 * np.sqrt(2)), 0.999).scale == 0.0
    assert drift.estimate(biased(truth, scale_error=0.02), truth, (1e-3, 0.002 * np.sqrt(2)), 0.999).scale < -0.015


def biased_scene():
    """The synthetic rooms walked by a biased front-end that gives no covariance (as the
    simulator's): the configured odometry noise."""
    scene = make_scene(200, rooms=(2, 2), seed=1, drift_rot_deg=0.01, drift_trans_m=0.001)
    frontend = biased([kf.pose for kf in scene.keyframes])
    keyframes = [kf.model_copy(update={"T_S_C": tuple(pose_to_tum(T)), "cov": None}) for kf, T in zip(scene.keyframes, frontend)]
    return scene, keyframes


@functools.cache
def _offline_on_the_biased_scene(estimate_drift: bool):
    """(estimator, results, ATE) of the offline run on `biased_scene`, once per setting for both tests."""
    scene, keyframes = biased_scene()
    cfg = BackendConfig()
    cfg.offline.estimate_drift = estimate_drift
    # 13 m of walk: the drift is at the edge of significance against the configured noise
    cfg.offline.drift_probability = 0.5
    # the walls trusted as the test was written (the tolerance estimate's 95 % upper bound, a
    # 0.1 deg floor)
    cfg.offline.tolerance_confidence, cfg.offline.tolerance_floor_deg = 0.95, 0.1
    est = OfflineEstimator(scene.plane_map, cfg, scene.initial)
    res = est.run(keyframes)
    return est, res, ate(res.T_B_C, scene.T_B_C)


def test_a_jump_the_front_end_reports_is_no_drift():
    """A relocalisation: the front-end's pose jumps 2 m at one step and it says so through that
    step's covariance. The smoothed walk does not follow it; fitted as drift, the jump had
    made one of -21 % of the distance online. The step is left out of the fit."""
    from bimgraph.backend.graph import FactorBuilder
    from bimgraph.backend.odometry import OdometryModel

    scene = make_scene(120, rooms=(1, 1), floor=False)
    T_S_C = [inverse(scene.T_B_S) @ T for T in scene.T_B_C]
    frontend = [T if k < 60 else make_pose(T[:3, :3], T[:3, 3] + [2.0, 0.0, 0.0]) for k, T in enumerate(T_S_C)]
    jump = np.diag([1e-4] * 3 + [4.0] * 3)
    keyframes = [kf.model_copy(update={"T_S_C": tuple(pose_to_tum(T)),
                                       "cov": tuple(map(tuple, jump)) if kf.index == 60 else None})
                 for kf, T in zip(scene.keyframes, frontend)]
    odometry = OdometryModel(FactorBuilder(BackendConfig()), np.array([0.0, 0.0, 1.0]))
    regular = odometry.regular(keyframes)
    assert not regular[59] and regular.sum() == len(keyframes) - 2
    rates = drift.estimate(frontend, T_S_C, odometry.step_sigmas(keyframes), 0.999, regular)
    assert not rates.differs(drift.DriftRates(), 1e-9)
    assert np.linalg.norm(drift.estimate(frontend, T_S_C).translation) > 0.05  # (the jump taken for a drift)


def test_offline_measures_the_drift():
    est, res, _ = _offline_on_the_biased_scene(True)
    assert np.degrees(est.odometry.drift.rotation[2]) == pytest.approx(-YAW_DEG_PER_M, rel=0.2)
    # the translation rate's direction, and most of its size (the short walk leaves some of it
    # to the walls)
    found, true = est.odometry.drift.translation, -DRIFT_PER_M
    assert found @ true / (np.linalg.norm(found) * np.linalg.norm(true)) > 0.95
    assert 0.5 < np.linalg.norm(found) / np.linalg.norm(true) < 1.2
    assert res.frontend_drift["rotation_deg_per_m"][2] == pytest.approx(-YAW_DEG_PER_M, rel=0.2)
    _, res, _ = _offline_on_the_biased_scene(False)
    assert res.frontend_drift is None


@pytest.mark.xfail(strict=True, reason="known defect (docs/experiments.md, fourteenth and twentieth sessions): "
                   "in this short walk without gravity the drift becomes significant only once the judgement "
                   "has tightened the walls, and settles at 82 % of the yaw rate under its verdicts; the "
                   "odometry noise estimate then stiffens the walk to the front-end's true noise, and two sound "
                   "walls are judged out: ATE 4.6 cm with the drift estimated, 1.4 cm without (both 1.3-1.4 cm "
                   "without the noise estimate)")
def test_offline_drift_estimate_does_not_cost_the_trajectory():
    """Where the walls alone already place the walk (1.4 cm), measuring and removing the drift
    must not make it worse."""
    errors = {estimate: _offline_on_the_biased_scene(estimate)[2] for estimate in (True, False)}
    assert errors[True] <= 1.1 * errors[False], errors


@pytest.mark.parametrize("shares, fits, rtol", [
    ([0.1] * 3 + [0.3] * 4, 3, 1e-9),  # one share per block: the secant is exact
    ([0.1, 0.1, 0.1, 0.3, 0.15, 0.3, 0.2], 6, 0.02),  # the translation's differ by axis
])
def test_settle_extrapolates_to_the_fixed_point(shares, fits, rtol):
    """Each solve recovers a share of the drift still in the odometry (here 10 % of the
    rotation's, 15-30 % of the translation's): plain iteration would need dozens of solves,
    the extrapolation lands on the rates in a few."""
    true = drift.DriftRates(np.array([0.0, 0.0, -0.0035]), np.array([0.006, -0.008, 0.0]), -0.01)
    shares = np.asarray(shares)

    def solve_and_fit(current):
        r = drift.as_vector(current)
        out = r + shares * (drift.as_vector(true) - r)
        return drift.DriftRates(out[:3], out[3:6], float(out[6]))

    settle, rates = drift.Settle(), drift.DriftRates()
    for _ in range(fits):
        rates = settle.next(rates, solve_and_fit(rates))
    np.testing.assert_allclose(drift.as_vector(rates), drift.as_vector(true), rtol=rtol, atol=1e-12)


def test_online_takes_the_drift_out_as_it_finds_it():
    scene, keyframes = biased_scene()
    cfg = BackendConfig()
    cfg.offline.drift_probability = 0.5  # (as offline, above)
    errors = {}
    for every in (50, 0):
        backend = Backend(scene.plane_map, cfg, scene.initial, drift_every=every)
        results = [backend.process(kf) for kf in keyframes]
        errors[every] = ate([r.T_B_C for r in results], scene.T_B_C)
        # one odometry factor per step, whatever was replaced
        assert sorted(backend.graph.odometry_index) == [kf.index for kf in keyframes[1:]]
        if every:
            assert np.degrees(backend.odometry.drift.rotation[2]) == pytest.approx(-YAW_DEG_PER_M, rel=0.3)
    assert errors[50] < 0.8 * errors[0], errors


def test_odometry_factors_are_rebuilt_when_the_drift_or_the_noise_changes():
    """The odometry model keeps each step's factor; a new drift or noise estimate replaces them."""
    from bimgraph.backend.graph import FactorBuilder
    from bimgraph.backend.odometry import OdometryModel
    from bimgraph.sequence.format import Keyframe

    model = OdometryModel(FactorBuilder(BackendConfig()), np.array([0.0, 0.0, 1.0]))
    a, b = (Keyframe(index=k, stamp=float(k), T_S_C=[float(k), 0, 0, 0, 0, 0, 1]) for k in range(2))
    first = model.factor(a, b)
    assert model.factor(a, b) is first
    model.drift = drift.DriftRates(np.array([0.0, 0.0, 0.01]), np.array([0.01, 0.0, 0.0]))
    moved = model.factor(a, b)
    np.testing.assert_allclose(moved.measured().translation(), [1.01, 0.0, 0.0], atol=1e-12)
    model.variance = np.array([0.25, 0.25])
    tightened = model.factor(a, b)
    assert tightened is not moved
    np.testing.assert_allclose(tightened.noiseModel().sigmas(), 0.5 * moved.noiseModel().sigmas(), rtol=1e-12)


def test_odometry_noise_estimate_reads_each_steps_joint_marginal():
    """The noise estimate marginalises onto many steps' poses at once; the redundancies it reads
    are those of gtsam's own joint marginal of each step's two poses."""
    import gtsam

    from bimgraph.backend.graph import X, BatchSolver, joint_covariance
    from bimgraph.backend.odometry import _POSE_GROUPS, _STEPS_AT_ONCE
    from bimgraph.backend.online import observations_of
    from bimgraph.backend.tolerance import redundancy, variance_factors

    scene, keyframes = biased_scene()
    est = OfflineEstimator(scene.plane_map, BackendConfig(), scene.initial)
    est.run(keyframes)
    observations = {kf.index: observations_of(kf, est.online.build) for kf in keyframes}
    start = est.online.graph.estimate()
    graph = est._graph(keyframes, observations, start)
    values = BatchSolver(50, 1e-9)(graph, start)
    steps = 3 * _STEPS_AT_ONCE  # spread over the walk, in three marginalisations
    found = est.odometry.estimated_variance(keyframes, graph, values, 0.95, 0.01, steps)
    marginals = gtsam.Marginals(graph, values)
    pairs = list(zip(keyframes, keyframes[1:]))
    terms = []
    for i in np.unique(np.linspace(0, len(pairs) - 1, steps).round().astype(int)):
        previous, kf = pairs[i]
        A, b = est.odometry.factor(previous, kf).linearize(values).jacobian()
        terms.append(redundancy(A, -b, joint_covariance(marginals, [X(previous.index), X(kf.index)])))
    expected = np.clip(est.odometry.variance * variance_factors(terms, 0.95, _POSE_GROUPS), 0.01**2, 1.0)
    np.testing.assert_allclose(found, expected, rtol=1e-9)
    assert (found < 1.0).all()  # the smoothed steps do say something
