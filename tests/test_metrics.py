"""Metrics on hand-made cases with known answers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimgraph.evaluation.metrics import (
    WallMatch,
    association_scores,
    ate,
    extrinsic_error,
    extrinsic_nees,
    mean_wall_errors,
    nearest_stamps,
    rpe,
    wall_errors,
)
from bimgraph.geometry import exp_se3, make_pose


def _trajectory(n=20, seed=0):
    rng = np.random.default_rng(seed)
    return [exp_se3(np.concatenate([rng.normal(0, 0.5, 3), rng.normal(0, 3, 3)])) for _ in range(n)]


def test_offset_trajectory_gives_that_ate():
    gt = _trajectory()
    offset = np.array([0.03, -0.04, 0.0])  # 5 cm
    est = [make_pose(T[:3, :3], T[:3, 3] + offset) for T in gt]
    assert ate(est, gt) == pytest.approx(0.05, abs=1e-12)
    # A constant offset of every position moves no relative motion (its rotations are the same)
    t_rpe, r_rpe = rpe(est, gt)
    assert t_rpe == pytest.approx(0.0, abs=1e-12)
    assert r_rpe == pytest.approx(0.0, abs=1e-6)


def test_rpe_of_a_scaled_step():
    gt = [make_pose(np.eye(3), [i, 0, 0]) for i in range(5)]
    est = [make_pose(np.eye(3), [1.1 * i, 0, 0]) for i in range(5)]
    assert rpe(est, gt)[0] == pytest.approx(0.1)
    assert ate(est, gt) == pytest.approx(np.sqrt(np.mean((0.1 * np.arange(5)) ** 2)))


def test_extrinsic_error():
    gt = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [1, 2, 0])
    est = make_pose(Rotation.from_euler("z", 32, degrees=True).as_matrix(), [1, 2.03, 0.04])
    deg, cm = extrinsic_error(est, gt)
    assert deg == pytest.approx(2.0)
    assert cm == pytest.approx(5.0)


def test_extrinsic_nees_of_a_known_error():
    """An estimate yawed 40 deg and tilted a few, the covariance isotropic: an error of 2 sigma
    along B's x gives 4, one in height is not counted, one in heading is."""
    est = make_pose(Rotation.from_euler("zyx", [40, 3, -2], degrees=True).as_matrix(), [3.0, -2.0, 1.5])
    cov = np.diag([0.002, 0.002, 0.002, 0.01, 0.01, 0.01]) ** 2
    assert extrinsic_nees(est, cov, make_pose(est[:3, :3], est[:3, 3] + [0.02, 0.0, 0.0])) == pytest.approx(4.0, rel=1e-9)
    assert extrinsic_nees(est, cov, make_pose(est[:3, :3], est[:3, 3] + [0.0, 0.0, 0.05])) == pytest.approx(0.0, abs=1e-12)
    yawed = make_pose(Rotation.from_euler("z", 0.1, degrees=True).as_matrix() @ est[:3, :3], est[:3, 3])
    assert extrinsic_nees(est, cov, yawed) == pytest.approx((np.radians(0.1) / 0.002) ** 2, rel=1e-6)


def test_extrinsic_nees_is_chi_square_with_three_dof_for_errors_drawn_from_the_covariance():
    """Errors drawn in gtsam's tangent (T_gt = T_est Exp(xi)) from a strongly correlated
    covariance (as an extrinsic's is: heading and position trade off), mapped by gtsam's exact
    exponential: the mean NEES is 3 and the tail chi-square's; a NEES that ignored the
    correlations, or read the covariance in another frame, would not be."""
    import gtsam
    from scipy.stats import chi2

    rng = np.random.default_rng(1)
    A = rng.normal(size=(6, 2))  # two dominant modes: correlations of 0.9 and more
    D = np.diag([0.002] * 3 + [0.01] * 3)
    cov = D @ (A @ A.T + 0.02 * np.eye(6)) @ D
    est = make_pose(Rotation.from_euler("zyx", [115, 0.5, -0.3], degrees=True).as_matrix(), [10.0, 4.0, 1.2])
    draws = rng.multivariate_normal(np.zeros(6), cov, size=4000)
    nees = np.array([extrinsic_nees(est, cov, est @ gtsam.Pose3.Expmap(xi).matrix()) for xi in draws])
    assert nees.mean() == pytest.approx(3.0, abs=0.2)  # (the mean of 4000 has a sigma of 0.04)
    assert np.mean(nees > chi2.ppf(0.95, 3)) == pytest.approx(0.05, abs=0.015)


def test_rotated_plane_gives_that_angular_deviation():
    face_B = np.array([1.0, 0, 0, -2.0])  # x = 2
    T_B_C = make_pose(np.eye(3), [0, 0, 0])
    tilt = np.radians(3.0)
    n_C = np.array([np.cos(tilt), np.sin(tilt), 0.0])
    centre_C = np.array([2.0, 0.0, 0.0]) + np.array([0.0, 0.0, 0.0])
    plane_C = np.array([*n_C, -n_C @ centre_C])
    # A second plane, 4 cm off the face, in another keyframe.
    T2 = make_pose(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [0, 0, 0])
    centre2_B = np.array([2.04, 1.0, 1.0])
    centre2_C = T2[:3, :3].T @ centre2_B
    n2_C = T2[:3, :3].T @ np.array([1.0, 0, 0])
    plane2_C = np.array([*n2_C, -n2_C @ centre2_C])
    per_kf = wall_errors(
        [WallMatch(0, plane_C, centre_C, face_B), WallMatch(1, plane2_C, centre2_C, face_B)],
        {0: T_B_C, 1: T2},
    )
    assert per_kf[0][0] == pytest.approx(3.0)
    assert per_kf[0][1] == pytest.approx(0.0, abs=1e-12)
    assert per_kf[1][0] == pytest.approx(0.0, abs=1e-6)
    assert per_kf[1][1] == pytest.approx(0.04)
    assert mean_wall_errors(per_kf) == pytest.approx((1.5, 0.02))


def test_wrong_association_lowers_precision_by_the_right_amount():
    truth = {(k, i): f"F{i}" for k in range(5) for i in range(4)}  # 20 true matches
    truth[(0, 4)] = None  # clutter
    predicted = dict(truth)
    assert association_scores(predicted, truth) == (1.0, 1.0)
    predicted[(2, 1)] = "F3"  # one wrong
    predicted[(0, 4)] = "F0"  # clutter matched to a face: a false positive
    del predicted[(4, 0)]  # one missed
    precision, recall = association_scores(predicted, truth)
    assert precision == pytest.approx(18 / 20)
    assert recall == pytest.approx(18 / 20)


def test_ate_equals_evo_ape(tmp_path):
    """Our ATE is evo's APE (translation part, no alignment) on the same TUM files, to 1e-6 m.
    evo is GPL-3.0: run as an external command only, never imported."""
    import json
    import shutil
    import subprocess
    import sys
    import zipfile
    from pathlib import Path

    from bimgraph.sequence.tum import read_tum, write_tum

    evo_ape = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    if not Path(evo_ape).exists():
        pytest.fail("evo_ape not found: install the test extras (pip install -e .[test])")
    gt = _trajectory(50, seed=1)
    rng = np.random.default_rng(2)
    est = [T @ exp_se3(rng.normal(0, 0.02, 6)) for T in gt]
    stamps = np.arange(50) * 0.1
    write_tum(tmp_path / "gt.tum", stamps, gt)
    write_tum(tmp_path / "est.tum", stamps, est)
    subprocess.run(
        [evo_ape, "tum", str(tmp_path / "gt.tum"), str(tmp_path / "est.tum"), "--pose_relation", "trans_part",
         "--save_results", str(tmp_path / "ape.zip"), "--no_warnings"],
        check=True, capture_output=True, cwd=tmp_path, env={"HOME": str(tmp_path), "PATH": ""},
    )
    with zipfile.ZipFile(tmp_path / "ape.zip") as z:
        evo_rmse = json.loads(z.read("stats.json"))["rmse"]
    # Compare on what was written, so that the files' precision is not part of the test.
    _, gt_read = read_tum(tmp_path / "gt.tum")
    _, est_read = read_tum(tmp_path / "est.tum")
    assert ate(est_read, gt_read) == pytest.approx(evo_rmse, abs=1e-6)
    assert evo_rmse > 0.01


@pytest.mark.parametrize("line, message", [
    ("1.0 0 0 nan 0 0 0 1", "line 2: tz is not a finite number"),
    ("nan 0 0 0 0 0 0 1", "line 2: stamp is not a finite number"),
    ("1.0 0 0 0 0 0 0 2", "line 2: quaternion has norm 2.0000, must be unit"),
    ("1700000000123456 0 0 0 0 0 0 1", "line 2: stamp 1700000000123456 is not in seconds .it looks like microseconds"),
])
def test_a_bad_tum_line_names_its_field(tmp_path, line, message):
    from bimgraph.errors import FormatError
    from bimgraph.sequence.tum import read_tum

    (tmp_path / "t.tum").write_text("0.0 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(FormatError, match=message):
        read_tum(tmp_path / "t.tum")


def test_nearest_stamps_takes_the_nearest_within_the_tolerance_in_any_order():
    reference = np.array([3.0, 1.0, 2.004, 10.0])
    rows = nearest_stamps(np.array([1.0, 2.0, 2.5, 3.009, 9.98, 11.0]), reference, 0.01)
    assert rows.tolist() == [1, 2, -1, 0, -1, -1]
    assert nearest_stamps(np.array([0.0, 5.0]), np.array([5.005]), 0.01).tolist() == [-1, 0]
    assert nearest_stamps(np.array([0.0]), np.zeros(0), 0.01).tolist() == [-1]
