"""Observation -> landmark association (SLAM side).

An observed plane in camera k matches landmark j when the residual of the plane factor that
would join them, `e = z.errorVector(L_j seen from k)`, passes a chi-square gate with the
landmark's marginal covariance propagated into the camera plus the observation's own, and when
the observed polygon comes close enough to the landmark's extent (coplanar walls of different
rooms must not merge). Matches are one-to-one within the keyframe; the rest become new
landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from bimgraph.backend.landmarks import LandmarkTable, bounding_sphere, hull_2d, to_plane_2d, transform_points
from bimgraph.config import SlamAssociationConfig
from factors.plane import local_plane_error

_INFEASIBLE = 1e12


@dataclass
class Observation:
    """One plane seen in the camera: (n, d), its 3x3 tangent covariance, its boundary points
    (and a sphere about them, for gating against landmarks' extents)."""

    index: int
    plane_C: np.ndarray
    cov: np.ndarray
    points_C: np.ndarray
    area: float | None = None
    centre_C: np.ndarray | None = field(init=False)  # None without points
    radius: float = field(init=False)

    def __post_init__(self):
        self.centre_C, self.radius = bounding_sphere(self.points_C) if len(self.points_C) else (None, np.nan)


@dataclass(frozen=True)
class Stacked:
    """A keyframe's observations as arrays, built once for all the association's steps (on a
    keyframe's handful of planes numpy's calls cost more than the maths: one per keyframe,
    not one per observation and step). Observations without points have NaN centre and
    radius, which every gap test passes."""

    planes_C: np.ndarray  # n x 4
    covs: np.ndarray  # n x 3 x 3
    centres_C: np.ndarray  # n x 3
    radii: np.ndarray  # n

    @classmethod
    def of(cls, observations: list[Observation]) -> Stacked:
        no_centre = np.full(3, np.nan)
        return cls(np.array([obs.plane_C for obs in observations]), np.array([obs.cov for obs in observations]),
                   np.array([no_centre if obs.centre_C is None else obs.centre_C for obs in observations]),
                   np.array([obs.radius for obs in observations]))


def mahalanobis_to_landmarks(stacked: Stacked, T_S_C: np.ndarray, landmarks: LandmarkTable,
                             pairs: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Squared Mahalanobis distance of each pair (observation index, landmark) in `pairs`:
    the residual of the plane factor that would join them (`factors.local_plane_error` with
    the camera as pose), with the landmark's marginal propagated through its Jacobian plus the
    observation's covariance. Vectorised over the pairs."""
    i, js = pairs
    # A plane is a covector: seen from C, landmark j's plane (n, d) in A is T_A_C^T @ (n, d).
    # With P taking it to the residual (n in the measurement's Unit3 basis; minus d), one
    # product per pair gives both the residual and, through the plane's own basis, its Jacobian.
    A_to_C = (landmarks.T_A_S[js] @ T_S_C).transpose(0, 2, 1)
    P = np.zeros((len(stacked.planes_C), 3, 4))
    for row, plane_C in enumerate(stacked.planes_C):
        P[row, :2, :3] = gtsam.Unit3(plane_C[:3]).basis().T
    P[:, 2, 3] = -1.0
    PM = P[i] @ A_to_C
    e = (PM @ landmarks.planes_A[js, :, None])[:, :, 0]
    e[:, 2] += stacked.planes_C[i, 3]
    # H = d e / d plane_A (the normal moving along its basis B_A, then d):
    # [[B_z^T R^T B_A, 0], [-t^T B_A, -1]]
    H = np.concatenate([PM[:, :, :3] @ landmarks.bases_A[js], PM[:, :, 3:]], axis=2)
    S = H @ landmarks.covs_A[js] @ H.transpose(0, 2, 1) + stacked.covs[i]
    # e^T S^-1 e through S's Cholesky factor, spelled out for 3x3 (np.linalg.solve's stacked
    # call costs several times these few operations on a keyframe's handful of pairs)
    l11 = np.sqrt(S[:, 0, 0])
    l21, l31 = S[:, 1, 0] / l11, S[:, 2, 0] / l11
    l22 = np.sqrt(S[:, 1, 1] - l21 * l21)
    l32 = (S[:, 2, 1] - l31 * l21) / l22
    l33 = np.sqrt(S[:, 2, 2] - l31 * l31 - l32 * l32)
    y1 = e[:, 0] / l11
    y2 = (e[:, 1] - l21 * y1) / l22
    y3 = (e[:, 2] - l31 * y1 - l32 * y2) / l33
    return y1 * y1 + y2 * y2 + y3 * y3


def same_plane_d2(plane_A1: np.ndarray, T_S_A1: np.ndarray, plane_A2: np.ndarray, T_S_A2: np.ndarray,
                  joint_cov: np.ndarray) -> float:
    """Squared Mahalanobis distance of two landmarks taken as one plane: landmark 2 seen from
    landmark 1's anchor, against landmark 1 (the plane factor's residual), with the joint
    marginal of (X_A1, X_A2, L2, L1), or of (X_A, L2, L1) when both have one anchor."""
    e, (H_1, H_2, H_L2) = local_plane_error(gtsam.Pose3(T_S_A1), gtsam.Pose3(T_S_A2), gtsam.OrientedPlane3(plane_A2),
                                            plane_A1, jacobians=True)
    # landmark 1 is the residual's measurement: moving it along its own basis moves e by -delta
    H_L1 = np.diag([-1.0, -1.0, 1.0])
    J = np.hstack([H_1 + H_2, H_L2, H_L1] if len(joint_cov) == 12 else [H_1, H_2, H_L2, H_L1])
    S = J @ joint_cov @ J.T
    return float(e @ np.linalg.solve(S, e))


def extent_gap(obs: Observation, T_A_C: np.ndarray, lm, basis_A: np.ndarray) -> float:
    """Distance on the landmark's plane between the observed polygon and the landmark's
    extent (its hull as last grown); 0 when either is unknown. `basis_A` is its plane's
    `plane_basis` (`LandmarkTable.bases_A`)."""
    if len(obs.points_C) == 0 or lm.hull_A is None:
        return 0.0
    seen = hull_2d(to_plane_2d(transform_points(T_A_C, obs.points_C), lm.plane_A, basis_A))
    return float(seen.distance(lm.hull_A))


class SlamAssociator:
    def __init__(self, cfg: SlamAssociationConfig):
        self.cfg = cfg
        self.gate = chi2.ppf(cfg.gate_probability, 3)
        self.cos_max = np.cos(np.radians(cfg.max_normal_angle_deg))

    def candidates(self, stacked: Stacked, T_S_C: np.ndarray, landmarks: LandmarkTable) -> np.ndarray:
        """(observation, landmark) pairs close enough in normal, offset and extent to be worth
        scoring, as a boolean matrix."""
        planes_in_C = landmarks.planes_S @ T_S_C  # (a plane is a covector: (n, d)_C = T_S_C^T (n, d)_S)
        planes_C = stacked.planes_C
        ok = (planes_C[:, :3] @ planes_in_C[:, :3].T > self.cos_max) & (
            np.abs(planes_in_C[:, 3] - planes_C[:, 3:]) < self.cfg.max_offset_m) & landmarks.active
        # bounding spheres: a lower bound of the exact extent gap (the distance spelled out:
        # np.linalg.norm's checks cost as much as the sum)
        offsets = landmarks.centres_S - transform_points(T_S_C, stacked.centres_C)[:, None]
        gap = np.sqrt((offsets * offsets).sum(axis=2)) - landmarks.radii - stacked.radii[:, None]
        return ok & ~(gap > self.cfg.max_extent_gap_m)

    def associate(self, observations: list[Observation], T_S_C: np.ndarray, landmarks: LandmarkTable):
        """Landmark id (or None for a new landmark) and Mahalanobis distance for each
        observation, given the camera pose estimate `T_S_C`."""
        n_obs = len(observations)
        out: list[tuple[int | None, float]] = [(None, float("nan"))] * n_obs
        if n_obs == 0 or len(landmarks) == 0:
            return out
        stacked = Stacked.of(observations)
        pairs = np.nonzero(self.candidates(stacked, T_S_C, landmarks))
        if len(pairs[0]) == 0:
            return out
        d2 = mahalanobis_to_landmarks(stacked, T_S_C, landmarks, pairs)
        gated = d2 <= self.gate
        scores = {(i, j): score for i, j, score in zip(pairs[0][gated].tolist(), pairs[1][gated].tolist(), d2[gated].tolist())
                  if extent_gap(observations[i], landmarks.T_A_S[j] @ T_S_C, landmarks[j], landmarks.bases_A[j]) <= self.cfg.max_extent_gap_m}
        if not scores:
            return out
        cols = sorted({j for _, j in scores})
        cost = np.full((n_obs, len(cols)), _INFEASIBLE)
        for (i, j), score in scores.items():
            cost[i, cols.index(j)] = score
        for row, col in zip(*linear_sum_assignment(cost)):
            if cost[row, col] < _INFEASIBLE:
                out[row] = (cols[col], float(cost[row, col]))
        return out
