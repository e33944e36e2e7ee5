"""The paper's baselines on cases with known answers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimgraph.backend.alignment import Alignment
from bimgraph.config import Config
from bimgraph.evaluation.baselines import MatchedPlane, PlaneRegistration, estimate_extrinsics
from bimgraph.geometry import make_pose, plane_to_frame
from bimgraph.sequence.format import Keyframe

T_B_S_TRUE = make_pose(Rotation.from_euler("zyx", [25, 1, -2], degrees=True).as_matrix(), [3.0, -1.5, 0.2])
FACES_B = [np.array([1.0, 0, 0, -4.0]), np.array([0, 1.0, 0, 2.0]), np.array([0, 0, 1.0, 0.0])]


def _plane_S(face_B):
    # plane_to_frame(plane_A, T_A_B) gives the plane in B: here A = B, B = S.
    return plane_to_frame(face_B, T_B_S_TRUE)


def test_global_recovers_a_known_transform_from_three_exact_planes():
    reg = PlaneRegistration(np.eye(4), offset_sigma_m=0.02, prior_trans_m=1e6)
    for face in FACES_B:
        reg.add(_plane_S(face), face)
    assert np.allclose(reg.solve(), T_B_S_TRUE, atol=1e-8)


def test_one_normal_turns_the_prior_the_least():
    """One plane fixes its normal only: the prior, 5 degrees off, is turned onto it by the
    smallest rotation (about the axis across both normals, by the angle between them)."""
    R_off = Rotation.from_rotvec(np.radians(5.0) * np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])).as_matrix()
    prior = make_pose(R_off @ T_B_S_TRUE[:3, :3], T_B_S_TRUE[:3, 3])
    reg = PlaneRegistration(prior, offset_sigma_m=0.02, prior_trans_m=2.0)
    plane_S, n_B = _plane_S(FACES_B[0]), FACES_B[0][:3]
    reg.add(plane_S, FACES_B[0])
    R = reg.solve()[:3, :3]
    np.testing.assert_allclose(R @ plane_S[:3], n_B, atol=1e-9)
    n_prior = prior[:3, :3] @ plane_S[:3]
    turned = Rotation.from_matrix(R @ prior[:3, :3].T).magnitude()
    assert turned > np.radians(1.0)
    assert turned == pytest.approx(np.arccos(np.clip(n_prior @ n_B, -1, 1)), abs=1e-9)


def test_methods_over_keyframes():
    cfg = Config()
    manual = Alignment.from_sigmas(make_pose(np.eye(3), [3.1, -1.4, 0.2]) @ make_pose(
        Rotation.from_euler("zyx", [25, 1, -2], degrees=True).as_matrix(), [0, 0, 0]), 2.0, 0.2)
    keyframes = [Keyframe(index=k, stamp=float(k), T_S_C=[0, 0, 0, 0, 0, 0, 1]) for k in range(3)]
    matches = [[MatchedPlane(k, _plane_S(f), np.zeros(3), f)] for k, f in enumerate(FACES_B)]
    manual_out = estimate_extrinsics("manual", keyframes, matches, manual, cfg.backend, cfg.baselines)
    assert all(np.array_equal(T, manual.T_B_S) for T in manual_out)
    global_out = estimate_extrinsics("global", keyframes, matches, manual, cfg.backend, cfg.baselines)
    assert np.allclose(global_out[-1], T_B_S_TRUE, atol=1e-6)
    local_out = estimate_extrinsics("local", keyframes, matches, manual, cfg.backend, cfg.baselines)
    assert np.allclose(local_out[-1], T_B_S_TRUE, atol=1e-6)
    with pytest.raises(ValueError, match="'best'"):
        estimate_extrinsics("best", keyframes, matches, manual, cfg.backend, cfg.baselines)
