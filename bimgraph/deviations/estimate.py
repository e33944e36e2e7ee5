"""As-built deviation of each observed BIM face, with its uncertainty. Pure maths, no I/O.

A face's deviation is read off the plane-to-BIM residual of the landmark that observed it
(`factors.plane.local_plane_error`, with the face as the measurement):

    e = ( B_F^T n_B ,  d_F - d_B )

where `(n_B, d_B)` is the landmark mapped into B by the extrinsic and `B_F` the Unit3 basis at
the face normal `n_F`. Writing the face centre `c = -d_F n_F + B_F B_F^T c`:

    offset = -(n_B . c + d_B) = e_3 - e_12 . (B_F^T c) - d_F (1 - cos tilt),   cos tilt = sqrt(1 - |e_12|^2)
    tilt   = asin |e_12|

`offset` is the distance of the as-built plane from the face centre, positive when the wall
surface moved along its normal into the room (the simulator's convention); `e_12` are the two
tilt components in radians (to first order). Their covariance is `H J Sigma J^T H^T`, with
`J` the residual's Jacobian over the keys (E, X_anchor, L) and `Sigma` their joint marginal.

The face's own plane-to-BIM factor, if the graph has one, pulls the landmark toward the face;
measuring the deviation with it in would measure the plan against itself. So the factor is
taken out of the joint marginal first (exact for the linearised problem, since the factor
touches only these keys): information `Sigma^-1 - A^T A`, mean moved by
`(Sigma^-1 - A^T A)^-1 A^T e_w`, with `(A, e_w)` the factor's whitened (and robustly
re-weighted) Jacobian and error. What is left is the face measured against the alignment that
the observations and the other faces decide: Baarda's externally studentised residual.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import gtsam
import numpy as np

from bimgraph.bim.planemap import BimFace
from bimgraph.config import DeviationConfig
from bimgraph.geometry import plane_from_frame
from factors.plane import face_tolerance_coordinates, local_plane_error

Status = Literal["within_tolerance", "deviating", "not_enough_evidence", "possibly_not_built", "unplanned"]

# Tangent dimensions of the keys (E, X_anchor, L), in the plane-to-BIM factor's key order.
JOINT_DIM = 15
# A factor whose residual the rest of the graph determines less than this (share of its own
# information, 0..1) cannot be measured against the rest.
_MIN_REDUNDANCY = 1e-6


@dataclass(frozen=True)
class ObservedPlane:
    """One plane landmark as the graph estimates it.

    `plane_A` is the landmark in its anchor keyframe's camera frame A, `T_S_A` the anchor's
    pose; `cov` is the 15 x 15 joint marginal covariance of (E = T_S_B, X_anchor, L) in gtsam's
    tangent spaces, in that order (the plane-to-BIM factor's key order). `face_id` is the
    graph's association; `bim_factor` the whitened linearisation `(A 3x15, e_w 3)` of its
    plane-to-BIM factor at the estimate (None if the graph has no such factor). `extent_S`
    (points on the plane, in S; may be empty) and `area_m2` describe the landmark's extent (for
    matching and for unplanned planes).
    """

    landmark: int
    plane_A: np.ndarray
    T_S_A: np.ndarray
    cov: np.ndarray
    n_keyframes: int
    face_id: str | None = None
    bim_factor: tuple[np.ndarray, np.ndarray] | None = None
    extent_S: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    area_m2: float = 0.0
    # the graph's keys (E, X_anchor, L) and its joint marginal over every landmark's, shared
    # by all of one solve's planes: the covariance of two faces measured together (`widths`)
    keys: tuple[int, int, int] | None = None
    joint: Callable[[list[int]], np.ndarray] | None = field(default=None, repr=False, compare=False)

    def plane_S(self) -> np.ndarray:
        return plane_from_frame(self.plane_A, self.T_S_A)

    def extent_in(self, T_X_S: np.ndarray) -> np.ndarray:
        return np.asarray(self.extent_S).reshape(-1, 3) @ T_X_S[:3, :3].T + T_X_S[:3, 3]


@dataclass(frozen=True)
class RivalAlignment:
    """The robust alignment's runner-up: the consensus of walls it judged otherwise, with the
    probability that it, not the estimate's, is the one on plan, the extrinsic `T_S_B` under
    it and every landmark read under it (by landmark id). Where the data barely choose (two
    parallel walls seen alone, one of them built off plan: which one is a coin toss), each
    deviation is reported over both (`mixed`)."""

    probability: float
    T_S_B: np.ndarray
    cov_T_B_S: np.ndarray  # 6x6, as `Results.cov_T_B_S`, under it
    planes: dict[int, ObservedPlane]


def about_estimate(cov, cov_rival, difference, probability: float) -> np.ndarray:
    """The second moment about the estimate of the mixture of the estimate's Gaussian (`cov`)
    and the rival's (`cov_rival`, its mean `difference` away), the rival with `probability`:
    `(1 - p) cov + p (cov_rival + d d^T)`, a covariance that NEES tests honestly whichever of
    the two holds."""
    d = np.atleast_1d(difference)
    return (1.0 - probability) * np.asarray(cov) + probability * (np.asarray(cov_rival) + np.outer(d, d))


@dataclass(frozen=True)
class Deviation:
    """Offset (m: the face centre's distance to the as-built plane, positive into the room)
    and tilt (deg) of the as-built plane from the planned face, with one-sigma uncertainties. `tilt_sigma_deg` is the larger
    principal sigma of the two tilt components (the tilt's direction is free)."""

    offset_m: float
    offset_sigma_m: float
    tilt_deg: float
    tilt_sigma_deg: float
    measurable: bool = True  # False if taking the face's own factor out left no information


@dataclass(frozen=True)
class FaceReport:
    face_id: str
    wall_guid: str
    wall_name: str
    storey: str
    status: Status
    n_keyframes: int = 0
    deviation: Deviation | None = None
    landmark: int | None = None
    matched_by: Literal["graph", "proximity", ""] = ""
    expected_keyframes: int = 0
    centre: tuple[float, float, float] | None = None  # the plane map's: where the offset is measured
    area_m2: float | None = None


@dataclass(frozen=True)
class UnplannedPlane:
    landmark: int
    plane_B: np.ndarray
    centre_B: np.ndarray | None
    area_m2: float
    n_keyframes: int


@dataclass(frozen=True)
class Explanation:
    """One of the two alignments the data barely choose between (`RivalAlignment`), with its
    probability, and the faces built off plan under it, each measured under it alone, of those
    the two alignments judge otherwise: the faces of a contest ("one of these walls is off,
    which one the data cannot tell")."""

    probability: float
    deviating: tuple[FaceReport, ...]


@dataclass
class DeviationReport:
    tolerance_m: float
    tilt_tolerance_deg: float
    k_sigma: float
    faces: list[FaceReport] = field(default_factory=list)
    unplanned: list[UnplannedPlane] = field(default_factory=list)
    contested: list[Explanation] = field(default_factory=list)  # none, or two, the likelier first
    widths: list = field(default_factory=list)  # `bimgraph.deviations.widths.Width`s
    thicknesses: list = field(default_factory=list)  # `bimgraph.deviations.widths.Thickness`es

    def by_status(self, status: Status) -> list[FaceReport]:
        return [f for f in self.faces if f.status == status]


def plane_to_bim_residual(face: BimFace, plane: ObservedPlane, T_S_B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face's plane-to-BIM residual and its 3 x 15 Jacobian over (E, X_anchor, L)."""
    e, (H_E, H_a, H_L) = local_plane_error(gtsam.Pose3(T_S_B), gtsam.Pose3(plane.T_S_A),
                                           gtsam.OrientedPlane3(plane.plane_A), face.plane, jacobians=True)
    return e, np.hstack([H_E, H_a, H_L])


def without_own_factor(cov: np.ndarray, bim_factor) -> tuple[np.ndarray, np.ndarray] | None:
    """Tangent-space shift of the mean, and covariance, of (E, X_a, L) once the face's own
    factor is taken out; None if the factor was all that constrained its residual. (Of any
    variables and any factors on them, the factors' whitened rows `A` stacked.)

    In covariance form (Woodbury), so that a nearly fixed anchor (the gauge keyframe) costs no
    precision: with the redundancy `R = I - A Sigma A^T`, `Sigma' = Sigma + Sigma A^T
    R^-1 A Sigma` and the shift is `Sigma A^T R^-1 e_w`."""
    if bim_factor is None:
        return np.zeros(JOINT_DIM), cov
    A, e_w = bim_factor
    SAt = cov @ A.T
    R = np.eye(len(A)) - A @ SAt
    R = 0.5 * (R + R.T)
    if np.linalg.eigvalsh(R)[0] <= _MIN_REDUNDANCY:
        return None
    K = np.linalg.solve(R, SAt.T).T  # Sigma A^T R^-1
    return K @ e_w, cov + K @ SAt.T


def deviation_terms(e: np.ndarray, face: BimFace) -> tuple[np.ndarray, np.ndarray]:
    """`y = (offset, tilt_1, tilt_2)` (m, rad, rad) from the face's plane-to-BIM residual `e`,
    and its 3 x 3 Jacobian `dy/de` (see the module docstring)."""
    # to first order, the map the plane-to-BIM tolerance is written in; then the offset's
    # second-order term in the tilt
    M = face_tolerance_coordinates(gtsam.Unit3(np.asarray(face.normal, dtype=float)).basis(), face.centre)
    e12 = e[:2]
    cos_tilt = np.sqrt(max(1.0 - float(e12 @ e12), 0.0))
    d_F = face.offset
    y = M @ e
    y[0] -= d_F * (1.0 - cos_tilt)
    H = M.copy()
    H[0, :2] -= d_F * e12 / max(cos_tilt, 1e-9)
    return y, H


def deviation_from_residual(e: np.ndarray, cov_e: np.ndarray, face: BimFace, measurable: bool = True) -> Deviation:
    """Offset and tilt of the as-built plane, with one-sigma, from the face's plane-to-BIM
    residual `e` and its 3 x 3 covariance."""
    y, H = deviation_terms(e, face)
    cov_y = H @ cov_e @ H.T
    return Deviation(
        offset_m=float(y[0]),
        offset_sigma_m=float(np.sqrt(max(cov_y[0, 0], 0.0))),
        tilt_deg=float(np.degrees(np.arcsin(min(float(np.linalg.norm(y[1:])), 1.0)))),
        tilt_sigma_deg=float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov_y[1:, 1:])[-1], 0.0)))),
        measurable=measurable,
    )


def face_deviation(face: BimFace, plane: ObservedPlane, T_S_B: np.ndarray) -> Deviation:
    """The face measured by the landmark, against the alignment the rest of the graph decides."""
    e, J = plane_to_bim_residual(face, plane, T_S_B)
    loo = without_own_factor(plane.cov, plane.bim_factor)
    if loo is None:
        return deviation_from_residual(e, J @ plane.cov @ J.T, face, measurable=False)
    delta, cov = loo
    return deviation_from_residual(e + J @ delta, J @ cov @ J.T, face)


def mixed(dev: Deviation, rival: Deviation, probability: float) -> Deviation:
    """`dev`, its sigmas made the root mean square error about it when the alignment `rival`
    was measured under holds with `probability` (`about_estimate`), the offset's and the
    tilt's alike."""
    def rms(x, sigma, x_rival, sigma_rival):
        return float(np.sqrt(about_estimate(sigma ** 2, sigma_rival ** 2, x_rival - x, probability)[0, 0]))

    return replace(dev, offset_sigma_m=rms(dev.offset_m, dev.offset_sigma_m, rival.offset_m, rival.offset_sigma_m),
                   tilt_sigma_deg=rms(dev.tilt_deg, dev.tilt_sigma_deg, rival.tilt_deg, rival.tilt_sigma_deg))


def excess_sigma(dev: Deviation, cfg: DeviationConfig) -> float:
    """How many sigma the deviation lies beyond the tolerance, offset or tilt, whichever more."""
    offset = (abs(dev.offset_m) - cfg.tolerance_m) / max(dev.offset_sigma_m, 1e-12)
    tilt = (dev.tilt_deg - cfg.tilt_tolerance_deg) / max(dev.tilt_sigma_deg, 1e-12)
    return float(max(offset, tilt))


def classify(dev: Deviation, n_keyframes: int, cfg: DeviationConfig) -> Status:
    """Deviating where the deviation exceeds the tolerance by more than `k_sigma` sigma
    (however large sigma is); within tolerance where it lies inside the tolerance by
    `conformance_k` sigma, offset and tilt alike (ISO 14253-1's decision rule: conformity is
    proven only inside the tolerance less the expanded uncertainty; a face measured 1.9 cm off
    at a sigma of 1 cm is as likely built beyond 2 cm as not); otherwise undecided, which is
    reported as not enough evidence."""
    if not dev.measurable or n_keyframes < cfg.min_keyframes:
        return "not_enough_evidence"
    excess = excess_sigma(dev, cfg)
    if excess > cfg.k_sigma:
        return "deviating"
    if excess <= -cfg.conformance_k:
        return "within_tolerance"
    return "not_enough_evidence"
