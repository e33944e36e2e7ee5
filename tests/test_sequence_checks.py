"""Warnings about sequences the format accepts but the backend cannot use as their writer
likely meant (`bimgraph.sequence.checks`), and `bimgraph run` printing them."""

import numpy as np
from test_run import run, world  # noqa: F401 (a fixture)

from bimgraph.sequence.checks import sequence_warnings
from bimgraph.sequence.format import Keyframe, Sequence, load_sequence, save_sequence

STEP = np.diag([1e-6] * 3 + [1e-5] * 3)


def keyframes(covs, polygon=True):
    plane = {"n": (1.0, 0.0, 0.0), "d": 2.0}
    if polygon:
        plane["polygon"] = [(-2.0, 0.0, 0.0), (-2.0, 1.0, 0.0), (-2.0, 0.0, 1.0)]
    return [Keyframe(index=k, stamp=float(k), T_S_C=(float(k), 0, 0, 0, 0, 0, 1), cov=None if c is None else c.tolist(),
                     planes=[plane]) for k, c in enumerate(covs)]


def test_a_pose_covariance_growing_along_the_walk_is_told_from_a_step_covariance():
    growing = sequence_warnings(keyframes([STEP * (k + 1) for k in range(40)]))
    assert len(growing) == 1 and "grows along the walk (20x" in growing[0] and "step from the previous keyframe" in growing[0]
    assert sequence_warnings(keyframes([STEP] * 40)) == []
    assert sequence_warnings(keyframes([None] * 40)) == []
    # noisy but steady step covariances, as a real front-end's
    rng = np.random.default_rng(0)
    assert sequence_warnings(keyframes([STEP * rng.uniform(0.5, 5.0) for _ in range(40)])) == []


def test_planes_without_polygons_are_counted():
    (warning,) = sequence_warnings(keyframes([None] * 5, polygon=False))
    assert warning.startswith("5 of 5 plane detections have no polygon")
    # a floor's detections may lack one: not most
    assert sequence_warnings(keyframes([None] * 5, polygon=False) + keyframes([None] * 5)) == []


def test_keyframes_far_from_the_origin_of_s_are_told():
    """A walk 100 km from S's origin (coordinates of a map projection) failed with a traceback
    from the robust alignment's Cholesky, and at 10 km with "covariances far overconfident"."""
    far = [kf.model_copy(update={"T_S_C": (kf.T_S_C[0] + 1e5, 2e4, *kf.T_S_C[2:])}) for kf in keyframes([None] * 5)]
    (warning,) = sequence_warnings(far)
    assert warning.startswith("keyframes lie up to 102 km from the origin of S") and "subtract the first keyframe" in warning
    assert sequence_warnings(keyframes([None] * 5)) == []
    # a walk that jumps away names the keyframe where it does (a front-end's glitch)
    jump = keyframes([None] * 5)
    jump[3:] = [kf.model_copy(update={"T_S_C": (kf.T_S_C[0] + 1e6, *kf.T_S_C[1:])}) for kf in jump[3:]]
    (warning,) = sequence_warnings(jump)
    assert f"from keyframe {jump[3].index} on (stamp {jump[3].stamp})" in warning


def test_the_run_prints_the_warning(world, tmp_path):
    _, root = world
    sequence = load_sequence(root)
    grown = [kf.model_copy(update={"cov": tuple(map(tuple, STEP * (k + 1)))}) for k, kf in enumerate(sequence.keyframes)]
    save_sequence(Sequence(root=tmp_path / "seq", meta=sequence.meta.model_copy(update={"model": str(root / "planes.json")}),
                           keyframes=grown))
    result = run(tmp_path / "seq", "-o", tmp_path / "out", "--mode", "offline")
    assert result.exit_code == 0, result.output
    assert "the keyframes' cov grows along the walk" in " ".join(result.output.split())
