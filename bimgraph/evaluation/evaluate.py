"""All metrics of one method's estimates on one sequence against its truth. No I/O: the
callers load the sequence, its reference and the method's outputs."""

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


@dataclass
class Estimate:
    """What a method says about a sequence: `T_B_C` per keyframe (in keyframe order), the
    final `T_B_S`, its observation -> face associations and the 6x6 covariance of `T_B_S`
    (gtsam's Pose3 tangent; each but `T_B_C` None when the method has none)."""

    T_B_C: Sequence[np.ndarray]
    T_B_S: np.ndarray | None
    associations: Mapping[tuple[int, int], str] | None = None
    cov_T_B_S: np.ndarray | None = None
    stamps: np.ndarray | None = None  # of `T_B_C`, where read from a file


@dataclass
class Truth:
    """What methods are measured against on one sequence: the true `T_B_C` of the keyframes a
    reference has a pose for (by keyframe index), the true `T_B_S` and the face truly behind
    each (keyframe, plane) where known, and the observed planes the wall errors average over
    (the same for every method)."""

    T_B_C: dict[int, np.ndarray]
    T_B_S: np.ndarray | None
    faces: dict[tuple[int, int], str | None] | None
    wall_matches: list[WallMatch]


def wall_matches(keyframes: Sequence[Keyframe], faces: Mapping[tuple[int, int], str | None], plane_map: PlaneMap) -> list[WallMatch]:
    """Every observed plane that `faces` gives a face of the plane map: the set the wall
    metrics average over."""
    matches = []
    for kf in keyframes:
        for i, obs in enumerate(kf.planes):
            face = faces.get((kf.index, i))
            if face is None or face not in plane_map.index:
                continue
            plane_C = normalise_plane(obs.plane)
            centre_C = np.asarray(obs.centre) if obs.centre is not None else -plane_C[3] * plane_C[:3]
            matches.append(WallMatch(kf.index, plane_C, centre_C, plane_map.faces[plane_map.index[face]].plane))
    return matches


def evaluate(estimate: Estimate, keyframes: Sequence[Keyframe], truth: Truth) -> dict:
    """Aggregates and per-keyframe series of every metric in DESIGN.md, of `estimate`'s poses
    of `keyframes` (one each, in order): the trajectory's over the keyframes the truth has a
    pose for, the extrinsic's and the association's where the truth has them."""
    indices = [kf.index for kf in keyframes]
    by_kf = dict(zip(indices, estimate.T_B_C))
    scored = [k for k in indices if k in truth.T_B_C]
    estimated, true = [by_kf[k] for k in scored], [truth.T_B_C[k] for k in scored]
    per_kf_wall = wall_errors([m for m in truth.wall_matches if m.keyframe in by_kf], by_kf)
    wall_angle, wall_dist = mean_wall_errors(per_kf_wall)
    rpe_t, rpe_r = rpe(estimated, true)
    out = {"keyframes": len(indices), "keyframes_with_reference": len(scored),
           "ate_m": ate(estimated, true) if scored else float("nan"), "rpe_trans_m": rpe_t, "rpe_rot_deg": rpe_r}
    if truth.T_B_S is not None and estimate.T_B_S is not None:
        out["extrinsic_rot_deg"], out["extrinsic_trans_cm"] = extrinsic_error(estimate.T_B_S, truth.T_B_S)
    out.update(wall_angle_deg=wall_angle, wall_distance_m=wall_dist)
    if truth.T_B_S is not None and estimate.cov_T_B_S is not None and np.isfinite(estimate.cov_T_B_S).all():
        out["extrinsic_nees"] = extrinsic_nees(estimate.T_B_S, estimate.cov_T_B_S, truth.T_B_S)
    if estimate.associations is not None and truth.faces is not None:
        reached = {key: face for key, face in truth.faces.items() if key[0] in by_kf}
        out["association_precision"], out["association_recall"] = association_scores(estimate.associations, reached)
    translation = dict(zip(scored, translation_errors(estimated, true).tolist())) if scored else {}
    rotation = dict(zip(scored, rotation_errors_deg(estimated, true).tolist())) if scored else {}
    out["per_keyframe"] = {
        "index": indices,
        "translation_error_m": [translation.get(k) for k in indices],
        "rotation_error_deg": [rotation.get(k) for k in indices],
        "wall_angle_deg": [per_kf_wall.get(k, (None, None))[0] for k in indices],
        "wall_distance_m": [per_kf_wall.get(k, (None, None))[1] for k in indices],
    }
    return out


def reduction_percent(method: float, manual: float) -> float:
    """How much lower `method` is than `manual`, in percent (the paper's figure)."""
    return float(100.0 * (1.0 - method / manual)) if manual else float("nan")
