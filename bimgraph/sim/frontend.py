"""A drifting SLAM front-end: keyframe poses `T_S_C` in the frame S of its first camera.

S is the first camera's pose, turned to have z up when `gravity_aligned` (as AR trackers
report: gravity is observed, heading and position are not). The estimate integrates the true
motion with a heading error growing with the distance travelled (`yaw_drift_deg_per_m` plus a
random walk) and a position bias growing with it (`translation_drift` in a fixed horizontal
direction plus a random walk), each step's length off by `scale_error`, and adds white noise
to each reported pose. So the final
position error is about `translation_drift` times the distance (before the heading error's
share) and the final heading error about `yaw_drift_deg_per_m` times the distance. Pure maths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.config import FrontEndConfig
from bimgraph.geometry import exp_se3, inverse, make_pose


@dataclass
class FrontEnd:
    T_B_S: np.ndarray  # true extrinsic
    T_S_C: np.ndarray  # N x 4 x 4, the drifting estimate
    drift: dict  # measured final drift, for the metadata


def frame_of_first_camera(T_B_C0: np.ndarray, gravity_aligned: bool) -> np.ndarray:
    """T_B_S: at the first camera, z up and x along its horizontal viewing direction when
    gravity-aligned, else the camera frame itself."""
    if not gravity_aligned:
        return T_B_C0.copy()
    forward = T_B_C0[:3, 2]
    yaw = np.arctan2(forward[1], forward[0])
    return make_pose(Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix(), T_B_C0[:3, 3])


def drift_stats(T_S_C_true: np.ndarray, T_S_C: np.ndarray, up_S: np.ndarray) -> dict:
    """Final position error in % of the distance travelled, final heading error (about the
    gravity direction `up_S`) per metre."""
    distance = float(np.linalg.norm(np.diff(T_S_C_true[:, :3, 3], axis=0), axis=1).sum())
    error = inverse(T_S_C_true[-1]) @ T_S_C[-1]
    position = float(np.linalg.norm(T_S_C[-1][:3, 3] - T_S_C_true[-1][:3, 3]))
    R_err = T_S_C[-1][:3, :3] @ T_S_C_true[-1][:3, :3].T
    yaw = float(np.degrees(Rotation.from_matrix(R_err).as_rotvec() @ up_S))
    return {
        "distance_m": round(distance, 6),
        "final_position_error_m": round(position, 6),
        "final_drift_percent": round(100.0 * position / max(distance, 1e-9), 6),
        "final_yaw_error_deg": round(yaw, 6),
        "yaw_drift_deg_per_m": round(abs(yaw) / max(distance, 1e-9), 6),
        "final_rotation_error_deg": round(float(np.degrees(np.linalg.norm(Rotation.from_matrix(error[:3, :3]).as_rotvec()))), 6),
    }


def simulate_frontend(T_B_C: np.ndarray, cfg: FrontEndConfig, rng: np.random.Generator) -> FrontEnd:
    T_B_S = frame_of_first_camera(T_B_C[0], cfg.gravity_aligned)
    T_S_B = inverse(T_B_S)
    T_S_C_true = np.array([T_S_B @ T for T in T_B_C])
    # S's gravity axis: z when gravity-aligned, else B's z seen from S.
    up_S = T_S_B[:3, :3] @ np.array([0.0, 0.0, 1.0])
    angle = rng.uniform(0.0, 2 * np.pi)
    horizontal = np.cross(up_S, [1.0, 0.0, 0.0] if abs(up_S[0]) < 0.9 else [0.0, 1.0, 0.0])
    horizontal /= np.linalg.norm(horizontal)
    bias_direction = Rotation.from_rotvec(angle * up_S).apply(horizontal)

    yaw_rate = np.radians(cfg.yaw_drift_deg_per_m)
    rw_rot = np.radians(cfg.random_walk_deg)
    noise_rot = np.radians(cfg.noise_deg)
    R_drift = np.eye(3)
    p = T_S_C_true[0][:3, 3].copy()
    T_S_C = [T_S_C_true[0].copy()]
    for k in range(1, len(T_S_C_true)):
        step = T_S_C_true[k][:3, 3] - T_S_C_true[k - 1][:3, 3]
        length = float(np.linalg.norm(step))
        rot_walk = rng.standard_normal(3) * rw_rot * np.sqrt(length)
        if cfg.gravity_aligned:
            rot_walk = (rot_walk @ up_S) * up_S  # roll and pitch stay observed through gravity
        R_drift = Rotation.from_rotvec(yaw_rate * length * up_S + rot_walk).as_matrix() @ R_drift
        p = p + (1.0 + cfg.scale_error) * (R_drift @ step) + cfg.translation_drift * length * bias_direction \
            + rng.standard_normal(3) * cfg.random_walk_m * np.sqrt(length)
        T_S_C.append(make_pose(R_drift @ T_S_C_true[k][:3, :3], p))
    T_S_C = np.array(T_S_C)
    noisy = np.array([T @ exp_se3(np.concatenate([rng.standard_normal(3) * noise_rot, rng.standard_normal(3) * cfg.noise_m]))
                      for T in T_S_C[1:]])
    T_S_C = np.concatenate([T_S_C[:1], noisy])
    return FrontEnd(T_B_S=T_B_S, T_S_C=T_S_C, drift=drift_stats(T_S_C_true, T_S_C, up_S))
