"""Metric definitions shared by every script (DESIGN.md, "Metrics"). Pure numpy, no I/O.

Trajectories are sequences of 4x4 poses `T_B_C` matched index by index with ground truth
(a reference at stamps of its own is matched first: `nearest_stamps`); B is absolute, so
nothing is re-aligned.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.geometry import inverse, normal_angle_deg, plane_from_frame, point_plane_distance, rotation_angle_deg

# seconds a reference pose may be from an estimate's stamp to be its truth (evo's default `--t_max_diff`)
T_MAX_DIFF_S = 0.01


def nearest_stamps(stamps: np.ndarray, reference: np.ndarray, max_diff_s: float) -> np.ndarray:
    """For each of `stamps`, the row of the nearest of `reference` (any order) within
    `max_diff_s` seconds, else -1 (evo's association by `--t_max_diff`)."""
    order = np.argsort(reference, kind="stable")
    ref = np.asarray(reference, dtype=float)[order]
    if len(ref) == 0:
        return np.full(len(stamps), -1)
    right = np.clip(np.searchsorted(ref, stamps), 0, len(ref) - 1)
    left = np.maximum(right - 1, 0)
    nearer = np.where(np.abs(ref[left] - stamps) <= np.abs(ref[right] - stamps), left, right)
    return np.where(np.abs(ref[nearer] - stamps) <= max_diff_s, order[nearer], -1)


def _stack(poses) -> np.ndarray:
    return np.asarray(poses, dtype=float).reshape(-1, 4, 4)


def translation_errors(T_B_C_est, T_B_C_gt) -> np.ndarray:
    """Per-keyframe translation error (m) of estimated against true camera positions."""
    est, gt = _stack(T_B_C_est), _stack(T_B_C_gt)
    if est.shape != gt.shape:
        raise ValueError(f"{len(est)} estimated poses against {len(gt)} true ones")
    return np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)


def rotation_errors_deg(T_B_C_est, T_B_C_gt) -> np.ndarray:
    est, gt = _stack(T_B_C_est), _stack(T_B_C_gt)
    return np.array([rotation_angle_deg(e[:3, :3].T @ g[:3, :3]) for e, g in zip(est, gt)])


def ate(T_B_C_est, T_B_C_gt) -> float:
    """Absolute trajectory error: RMSE of translation, without re-alignment (evo_ape tum, no -a)."""
    e = translation_errors(T_B_C_est, T_B_C_gt)
    return float(np.sqrt(np.mean(e**2)))


def rpe(T_B_C_est, T_B_C_gt, delta: int = 1) -> tuple[float, float]:
    """Relative pose error over `delta` keyframes: RMSE of translation (m) and rotation (deg)
    of the relative motions (evo_rpe's definition with the same delta in frames)."""
    est, gt = _stack(T_B_C_est), _stack(T_B_C_gt)
    t_err, r_err = [], []
    for i in range(len(est) - delta):
        rel_est = inverse(est[i]) @ est[i + delta]
        rel_gt = inverse(gt[i]) @ gt[i + delta]
        E = inverse(rel_gt) @ rel_est
        t_err.append(np.linalg.norm(E[:3, 3]))
        r_err.append(rotation_angle_deg(E[:3, :3]))
    if not t_err:
        return 0.0, 0.0
    return float(np.sqrt(np.mean(np.square(t_err)))), float(np.sqrt(np.mean(np.square(r_err))))


def extrinsic_error(T_B_S_est: np.ndarray, T_B_S_gt: np.ndarray) -> tuple[float, float]:
    """Error of the BIM<-SLAM extrinsic as (degrees, centimetres).

    The translation part is measured where it matters, at the origin of S (the first camera)."""
    E = inverse(T_B_S_gt) @ T_B_S_est
    return rotation_angle_deg(E[:3, :3]), float(np.linalg.norm(T_B_S_est[:3, 3] - T_B_S_gt[:3, 3]) * 100.0)


def extrinsic_nees(T_B_S_est: np.ndarray, cov_T_B_S: np.ndarray, T_B_S_gt: np.ndarray) -> float:
    """Normalised estimation error squared of the extrinsic's heading and horizontal position
    in B (3 dof: chi-square with 3 degrees of freedom, mean 3, where the covariance is
    honest). Those are what the walls observe and a site team reads; the height and, for a
    gravity-aligned front-end, the tilt are held by priors. `cov_T_B_S` is the estimate's
    6x6 covariance in gtsam's Pose3 tangent (rotation, translation; `T_B_S_gt = T_B_S_est
    Exp(xi)`); the error is taken to first order, which at centimetres and tenths of a degree
    is the log map."""
    delta = inverse(T_B_S_est) @ T_B_S_gt
    xi = np.concatenate([Rotation.from_matrix(delta[:3, :3]).as_rotvec(), delta[:3, 3]])
    R = T_B_S_est[:3, :3]
    J = np.zeros((3, 6))  # tangent -> (yaw, x, y) in B
    J[0, :3] = R[2]
    J[1:, 3:] = R[:2]
    e, P = J @ xi, J @ cov_T_B_S @ J.T
    return float(e @ np.linalg.solve(P, e))


@dataclass(frozen=True)
class WallMatch:
    """One observed plane matched to a BIM face in one keyframe: the plane (n, d) and its
    centre in the camera frame, and the face's plane in B."""

    keyframe: int
    plane_C: np.ndarray
    centre_C: np.ndarray
    face_B: np.ndarray


def wall_errors(matches: Iterable[WallMatch], T_B_C_by_keyframe: Mapping[int, np.ndarray]):
    """The seed paper's metric: per keyframe, the mean angular deviation (deg) between each BIM
    face normal and its observed plane's normal mapped into B with the method's `T_B_C`, and
    the mean distance (m) of the observed plane's centre to the BIM plane. Returns
    `{keyframe: (angle_deg, distance_m)}`; average the values over keyframes for the total."""
    per_kf: dict[int, list[tuple[float, float]]] = {}
    for m in matches:
        T_B_C = T_B_C_by_keyframe[m.keyframe]
        plane_B = plane_from_frame(m.plane_C, T_B_C)
        centre_B = T_B_C[:3, :3] @ m.centre_C + T_B_C[:3, 3]
        angle = normal_angle_deg(plane_B[:3], m.face_B[:3])
        dist = abs(float(point_plane_distance(centre_B, m.face_B)))
        per_kf.setdefault(m.keyframe, []).append((angle, dist))
    return {k: tuple(np.mean(v, axis=0)) for k, v in sorted(per_kf.items())}


def mean_wall_errors(per_keyframe: Mapping[int, tuple[float, float]]) -> tuple[float, float]:
    if not per_keyframe:
        return float("nan"), float("nan")
    a = np.array(list(per_keyframe.values()))
    return float(a[:, 0].mean()), float(a[:, 1].mean())


def association_scores(predicted: Mapping, truth: Mapping) -> tuple[float, float]:
    """Precision and recall of observation->face associations.

    Both map an observation key (e.g. `(keyframe, plane index)`) to a face id; `truth` holds
    None for observations of no planned face (clutter). Precision: correct among predicted.
    Recall: correct among the observations that truly have a face."""
    predicted = {k: v for k, v in predicted.items() if v is not None}
    correct = sum(1 for k, v in predicted.items() if truth.get(k) == v)
    positives = sum(1 for v in truth.values() if v is not None)
    precision = correct / len(predicted) if predicted else 1.0
    recall = correct / positives if positives else 1.0
    return precision, recall
