"""All metrics of one method's estimates on one simulated sequence. No I/O: the callers load
the sequence, its ground truth and the method's outputs."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.evaluation.metrics import (
    WallMatch,
    association_scores,
    ate,
    extrinsic_error,
    extrinsic_nees,
    mean_wall_errors,
    rotation_errors_deg,
    rpe,
    translation_errors,
    wall_errors,
)
from bimgraph.geometry import normalise_plane
from bimgraph.sequence.format import Keyframe
from bimgraph.sequence.groundtruth import GroundTruth


@dataclass
class Estimate:
    """What a method says about a sequence: `T_B_C` per keyframe (in keyframe order), the
    final `T_B_S`, its observation -> face associations and the 6x6 covariance of `T_B_S`
    (gtsam's Pose3 tangent; each None when the method has none)."""

    T_B_C: Sequence[np.ndarray]
    T_B_S: np.ndarray
    associations: Mapping[tuple[int, int], str] | None = None
    cov_T_B_S: np.ndarray | None = None
    stamps: np.ndarray | None = None  # of `T_B_C`, where read from a file


def true_associations(keyframes: Sequence[Keyframe], gt: GroundTruth) -> dict[tuple[int, int], str | None]:
    """(keyframe index, plane index) -> the planned face truly behind it (None: clutter etc.)."""
    return {(kf.index, i): obs.get("face_id") for kf, planes in zip(keyframes, gt.observations) for i, obs in enumerate(planes)}


def true_wall_matches(keyframes: Sequence[Keyframe], gt: GroundTruth, plane_map: PlaneMap) -> list[WallMatch]:
    """Every observed plane truly of a planned face: the set the wall metrics average over, the
    same for every method."""
    matches = []
    for kf, planes in zip(keyframes, gt.observations):
        for obs, truth in zip(kf.planes, planes):
            face = truth.get("face_id")
            if face is None or face not in plane_map.index:
                continue
            plane_C = normalise_plane(obs.plane)
            centre_C = np.asarray(obs.centre) if obs.centre is not None else -plane_C[3] * plane_C[:3]
            matches.append(WallMatch(kf.index, plane_C, centre_C, plane_map.faces[plane_map.index[face]].plane))
    return matches


def evaluate(estimate: Estimate, keyframes: Sequence[Keyframe], gt: GroundTruth, plane_map: PlaneMap) -> dict:
    """Aggregates and per-keyframe series of every metric in DESIGN.md."""
    indices = [kf.index for kf in keyframes]
    by_kf = dict(zip(indices, estimate.T_B_C))
    per_kf_wall = wall_errors(true_wall_matches(keyframes, gt, plane_map), by_kf)
    wall_angle, wall_dist = mean_wall_errors(per_kf_wall)
    rpe_t, rpe_r = rpe(estimate.T_B_C, gt.T_B_C)
    ext_deg, ext_cm = extrinsic_error(estimate.T_B_S, gt.T_B_S)
    out = {
        "keyframes": len(indices),
        "ate_m": ate(estimate.T_B_C, gt.T_B_C),
        "rpe_trans_m": rpe_t,
        "rpe_rot_deg": rpe_r,
        "extrinsic_rot_deg": ext_deg,
        "extrinsic_trans_cm": ext_cm,
        "wall_angle_deg": wall_angle,
        "wall_distance_m": wall_dist,
    }
    if estimate.cov_T_B_S is not None and np.isfinite(estimate.cov_T_B_S).all():
        out["extrinsic_nees"] = extrinsic_nees(estimate.T_B_S, estimate.cov_T_B_S, gt.T_B_S)
    if estimate.associations is not None:
        precision, recall = association_scores(estimate.associations, true_associations(keyframes, gt))
        out.update(association_precision=precision, association_recall=recall)
    out["per_keyframe"] = {
        "index": indices,
        "translation_error_m": translation_errors(estimate.T_B_C, gt.T_B_C).tolist(),
        "rotation_error_deg": rotation_errors_deg(estimate.T_B_C, gt.T_B_C).tolist(),
        "wall_angle_deg": [per_kf_wall.get(k, (None, None))[0] for k in indices],
        "wall_distance_m": [per_kf_wall.get(k, (None, None))[1] for k in indices],
    }
    return out


def reduction_percent(method: float, manual: float) -> float:
    """How much lower `method` is than `manual`, in percent (the paper's figure)."""
    return float(100.0 * (1.0 - method / manual)) if manual else float("nan")
