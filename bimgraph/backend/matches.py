"""A landmark's match to a BIM face, judged alike online and offline: how far the landmark
sits from its face, when a match no longer fits, whether two landmarks are one plane, and
undoing a match. No I/O."""

from __future__ import annotations

import math
from collections.abc import Callable

import gtsam
import numpy as np

from bimgraph.backend.associate_bim import FaceIndex
from bimgraph.backend.associate_slam import same_plane_d2
from bimgraph.backend.graph import L, X
from bimgraph.backend.landmarks import Landmark, LandmarkTable
from bimgraph.backend.records import Listener
from factors.plane import predict_local_plane


def misfit(plane_B: np.ndarray, face_plane: np.ndarray, centre_B: np.ndarray) -> tuple[float, float]:
    """How far a plane in B is from a face: (angle in degrees, distance in metres of the face's
    centre from the plane)."""
    # (math on scalars: numpy's calls cost ten times as much, and every match is judged per keyframe)
    angle = math.degrees(math.acos(min(max(float(plane_B[:3] @ face_plane[:3]), -1.0), 1.0)))
    return angle, abs(float(plane_B[:3] @ centre_B + plane_B[3]))


def face_misfit(lm: Landmark, face: str, faces: FaceIndex, T_S_B: gtsam.Pose3, cfg) -> float:
    """How far the landmark is from `face`, in units of the gate's as-built tolerance."""
    plane_B = predict_local_plane(T_S_B, gtsam.Pose3(lm.T_S_A), gtsam.OrientedPlane3(lm.plane_A))
    row = faces.row[face]
    angle, offset = misfit(plane_B, faces.planes[row], faces.centres[row])
    return (angle / cfg.face_normal_deg) ** 2 + (offset / cfg.face_offset_m) ** 2


def one_plane_d2(a: Landmark, b: Landmark, joint: Callable[[list[int]], np.ndarray]) -> float:
    """Two landmarks' squared Mahalanobis distance as one plane (`same_plane_d2`), with
    `joint(keys)` the joint marginal covariance of keys in the order given."""
    keys = [X(a.anchor)] + ([X(b.anchor)] if b.anchor != a.anchor else []) + [L(b.id), L(a.id)]
    return same_plane_d2(a.plane_A, a.T_S_A, b.plane_A, b.T_S_A, joint(keys))


def behind(lm: Landmark, table: LandmarkTable, cos_max: float, min_gap_m: float) -> dict[int, float]:
    """The active landmarks parallel to `lm` (normals within `cos_max`, in S) whose planes lie at
    least `min_gap_m` behind it, each with its gap: `lm`'s centre (its extent's, else its
    plane's foot) is that far in front of them, on the side their normals point to, the free
    space a wall faces."""
    n_S, d_S = table.planes_S[lm.id, :3], table.planes_S[lm.id, 3]
    centre = table.centres_S[lm.id] if np.isfinite(table.radii[lm.id]) else -d_S * n_S
    parallel = table.planes_S[:, :3] @ n_S >= cos_max
    gap = table.planes_S[:, :3] @ centre + table.planes_S[:, 3]
    return {int(k): float(gap[k]) for k in np.flatnonzero(table.active & parallel & (gap >= min_gap_m)) if k != lm.id}


def offset_sigma(plane_S: np.ndarray, T_S_B: np.ndarray, centre_B: np.ndarray, cov_T_B_S: np.ndarray) -> float:
    """The standard deviation of a plane's offset from a face centre that the extrinsic's
    covariance alone gives (`cov_T_B_S` in gtsam's right-perturbation tangent of T_B_S). The
    offset is the plane's value at the centre carried into S, `n_S . (T_S_B c) + d_S`;
    perturbing T_B_S by (w, v) moves `p = T_S_B c` by `-w x p - v`, so its Jacobian is
    `-[p x n_S, n_S]`."""
    n_S = plane_S[:3]
    p = T_S_B[:3, :3] @ centre_B + T_S_B[:3, 3]
    J = -np.concatenate([np.cross(p, n_S), n_S])
    return float(np.sqrt(max(J @ cov_T_B_S @ J, 0.0)))


def revision_reason(plane_B: np.ndarray, faces: FaceIndex, face: str, cfg,
                    sigma: Callable[[], float] | None = None,
                    gated: Callable[[], bool] | None = None) -> str | None:
    """Why a landmark matched to `face` no longer fits it, or None if it does. An offset past
    `revision_offset_m` stands if `sigma()` (the offset's standard deviation from the
    extrinsic's uncertainty, asked only then) allows it `revision_offset_sigmas` times; a
    normal past `revision_normal_deg` stands if `gated()` (whether the BIM gate, with the
    landmark's covariance as it stands, still takes the face, asked only then) says so."""
    row = faces.row[face]
    angle, offset = misfit(plane_B, faces.planes[row], faces.centres[row])
    if angle > cfg.revision_normal_deg and (gated is None or not gated()):
        return f"normal {angle:.1f} deg off"
    # the normals' elevations: how far the plane leans out of the plumb of a wall-like face
    # (a slab's tilt is its whole normal angle, judged above)
    elevation = [math.asin(min(max(float(z), -1.0), 1.0)) for z in (plane_B[2], faces.planes[row, 2])]
    plumb = math.degrees(abs(elevation[0] - elevation[1]))
    if abs(elevation[1]) < math.pi / 4 and plumb > cfg.revision_plumb_deg:
        return f"leaning {plumb:.1f} deg out of plumb"
    if offset > cfg.revision_offset_m and (sigma is None or offset > cfg.revision_offset_sigmas * sigma()):
        return f"offset {offset:.3f} m off"
    return None


def unmatch(lm: Landmark, reason: str, listener: Listener) -> None:
    """Undo landmark lm's match (for `reason`); it is not matched to that face again."""
    lm.rejected.add(lm.face)
    listener.on_association_removed(lm.id, lm.face, reason)
    lm.face, lm.score = None, float("nan")
