"""The seed paper's three ways to estimate the BIM<-SLAM transform (DESIGN.md, "Baselines").

Each re-estimates only `T_B_S`, keyframe by keyframe and causally, and leaves the front-end's
drifting poses `T_S_C` as they are; all three use the same plane-to-face associations (those
of a bimgraph run), so that a comparison is about estimation alone.
The paper solves its least squares by Gauss-Newton; `PlaneRegistration` reaches the same
minimum in closed form (normals and offsets decouple when the residual is taken against the
face's normal), which keeps the global baseline O(1) per keyframe.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bimgraph.backend.alignment import Alignment, unobservable_directions
from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import BackendConfig, BaselineConfig
from bimgraph.evaluation.evaluate import wall_matches
from bimgraph.geometry import least_rotation, make_pose, plane_from_frame, rotation_from_correlation
from bimgraph.sequence.format import Keyframe

METHODS = ("manual", "global", "local")


@dataclass(frozen=True)
class MatchedPlane:
    """An observed plane mapped into S by the front-end pose, and the face it was matched to."""

    keyframe: int
    plane_S: np.ndarray
    centre_S: np.ndarray
    face_B: np.ndarray


def matched_planes(keyframes: Sequence[Keyframe], associations: Mapping[tuple[int, int], str],
                   plane_map: PlaneMap) -> list[list[MatchedPlane]]:
    """Per keyframe (in order), its observations that `associations` matched to a face."""
    poses = {kf.index: kf.pose for kf in keyframes}
    out: dict[int, list[MatchedPlane]] = {kf.index: [] for kf in keyframes}
    for m in wall_matches(keyframes, associations, plane_map):
        T_S_C = poses[m.keyframe]
        out[m.keyframe].append(MatchedPlane(m.keyframe, plane_from_frame(m.plane_C, T_S_C), T_S_C[:3, :3] @ m.centre_C + T_S_C[:3, 3],
                                            m.face_B))
    return list(out.values())


class PlaneRegistration:
    """Least-squares `T_B_S` from plane pairs (plane in S, face in B), in closed form from sums
    that grow by one term a pair: the rotation by Kabsch on the normals, then the translation
    from the offsets (`n_B . t = d_S - d_B`, linear in t), with a weak prior toward `prior`
    where the normals leave a direction free. Adding pairs costs O(1), solving O(1)."""

    def __init__(self, prior: np.ndarray, offset_sigma_m: float, prior_trans_m: float):
        self.prior = prior
        self.H = np.zeros((3, 3))
        self.A = np.eye(3) * (offset_sigma_m / prior_trans_m) ** 2
        self.b = self.A @ prior[:3, 3]
        self.first: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, plane_S: np.ndarray, plane_B: np.ndarray) -> None:
        n_B = plane_B[:3]
        self.H += np.outer(plane_S[:3], n_B)
        self.A += np.outer(n_B, n_B)
        self.b += n_B * (plane_S[3] - plane_B[3])
        if self.first is None:
            self.first = (plane_S[:3], n_B)

    def solve(self) -> np.ndarray:
        if self.first is None:
            return self.prior
        R = rotation_from_correlation(self.H)
        if R is None:  # parallel normals: turn the prior the least that aligns them
            R_prior = self.prior[:3, :3]
            R = least_rotation(R_prior @ self.first[0], self.first[1]) @ R_prior
        return make_pose(R, np.linalg.solve(self.A, self.b))


def _solve(planes: list[MatchedPlane], prior: np.ndarray, cfg: BaselineConfig) -> np.ndarray:
    registration = PlaneRegistration(prior, cfg.offset_sigma_m, cfg.prior_trans_m)
    for m in planes:
        registration.add(m.plane_S, m.face_B)
    return registration.solve()


def _free_directions(planes: list[MatchedPlane], cfg: BackendConfig) -> int:
    return len(unobservable_directions(np.array([m.face_B[:3] for m in planes]), cfg.unobservable_min_angle_deg))


def estimate_extrinsics(method: str, keyframes: Sequence[Keyframe], matches: list[list[MatchedPlane]],
                        manual: Alignment, cfg: BackendConfig, baseline_cfg: BaselineConfig) -> list[np.ndarray]:
    """`T_B_S` after each keyframe by `method` (manual, global or local)."""
    if method not in METHODS:
        raise ValueError(f"unknown baseline {method!r}")
    T_B_S = manual.T_B_S
    everything = PlaneRegistration(manual.T_B_S, baseline_cfg.offset_sigma_m, baseline_cfg.prior_trans_m)
    seen: list[MatchedPlane] = []
    out = []
    for kf, current in zip(keyframes, matches):
        seen.extend(current)
        for m in current:
            everything.add(m.plane_S, m.face_B)
        if method == "global" and current:
            T_B_S = everything.solve()
        elif method == "local" and current:
            T_B_S = _solve(_local_set(kf.pose[:3, 3], current, seen, cfg, baseline_cfg), manual.T_B_S, baseline_cfg)
        out.append(T_B_S)
    return out


def _local_set(camera_S: np.ndarray, current: list[MatchedPlane], seen: list[MatchedPlane], cfg: BackendConfig,
               baseline_cfg: BaselineConfig) -> list[MatchedPlane]:
    """The planes of this keyframe, then the nearest matched planes seen before, added one by
    one until three independent normals fix every direction or the limit is reached."""
    chosen = list(current)
    if _free_directions(chosen, cfg) == 0:
        return chosen
    others = [m for m in seen if m.keyframe != current[0].keyframe]
    others.sort(key=lambda m: float(np.linalg.norm(m.centre_S - camera_S)))
    for m in others:
        if len(chosen) >= baseline_cfg.local_max_planes:
            break
        if np.linalg.norm(m.centre_S - camera_S) > baseline_cfg.local_radius_m:
            break
        chosen.append(m)
        if _free_directions(chosen, cfg) == 0:
            break
    return chosen
