"""Landmark -> BIM face association.

Each candidate is a landmark plane mapped into B with its 4x4 covariance there (propagated
from the joint marginal of landmark, anchor pose and extrinsic, or, for the baselines, from a
`T_B_S` estimate and a plane in S taken as independent). Against every face it is scored with
the residual of the plane-to-BIM factor that would join them, `e = face.errorVector(plane_B)`,
gated by chi-square with that covariance plus the as-built tolerance; then the geometric
filters (area, corner proximity, centre alignment); then a one-to-one assignment in which a
landmark whose second-best face scores nearly as well as its best waits for more evidence.

`match_faces` is the whole of it and needs nothing from the graph, so that baselines which
re-estimate only `T_B_S` share it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np
import shapely
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2
from shapely.geometry import Point, Polygon

from bimgraph.backend.graph import E, L, X, extrinsic_cov_E, pose3
from bimgraph.backend.landmarks import Landmark, hull_2d, plane_basis
from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import BimAssociationConfig
from factors.plane import face_tolerance_cov, predict_local_plane

_INFEASIBLE = 1e12


@dataclass
class PlaneInB:
    """A landmark as the BIM association sees it."""

    landmark: int
    plane_B: np.ndarray  # (n, d)
    cov_B: np.ndarray  # 4x4 covariance of (n, d) in R^4 (rank 3)
    extent_B: np.ndarray  # M x 3 points on the plane, possibly empty
    area: float


@dataclass(frozen=True)
class FaceMatch:
    landmark: int
    face: str
    score: float  # squared Mahalanobis distance


# a wall cut in more sections than this has them prefiltered by their boxes (`member_at`)
_MANY_SECTIONS = 16


class FaceIndex:
    """The plane map, stacked for vectorised scoring. Coplanar faces (a wall split per room,
    collinear walls) form a group: one landmark may span several of them, so a landmark is
    matched to a group, gated on the group's outline, and each of its observations then takes
    the group member it lies on."""

    def __init__(self, plane_map: PlaneMap, cfg: BimAssociationConfig):
        self.faces = plane_map.faces
        self.ids = [f.id for f in self.faces]
        self.row = {face_id: i for i, face_id in enumerate(self.ids)}
        self.planes = plane_map.planes
        self.centres = np.array([f.centre for f in self.faces], dtype=float).reshape(-1, 3)
        self.bases = np.array([plane_basis(p[:3]) for p in self.planes]).reshape(-1, 3, 2)
        # e = D_f (n, d) + (0, 0, d_f): D_f = [[B_f^T, 0], [0, -1]]
        self.D = np.zeros((len(self.faces), 3, 4))
        self.D[:, :2, :3] = self.bases.transpose(0, 2, 1)
        self.D[:, 2, 3] = -1.0
        cos_tol = np.cos(np.radians(cfg.coplanar_normal_deg))
        self.group = np.full(len(self.faces), -1)
        self.members: list[np.ndarray] = []
        for i in range(len(self.faces)):
            if self.group[i] < 0:
                same = np.flatnonzero((self.planes[:, :3] @ self.planes[i, :3] > cos_tol) & (self.group < 0)
                                      & (np.abs(self.planes[:, 3] - self.planes[i, 3]) < cfg.coplanar_offset_m))
                self.group[same] = len(self.members)
                self.members.append(same)
        self.rep = np.array([m[0] for m in self.members], dtype=int)
        # outer boundaries in the frame of the group's first face; for the geometric filters
        # each face's convex hull, since an observed extent is one, over doors and windows
        # alike (a door at a face's edge is a notch in its outline, not a hole: the hull of a
        # wall seen whole centres in the doorway)
        self.outline = np.array([Polygon(self.to_2d(self.rep[self.group[i]], np.asarray(f.polygon))) for i, f in enumerate(self.faces)],
                                dtype=object)
        self.outline_bounds = shapely.bounds(self.outline).reshape(-1, 4)
        self.member_outlines = [self.outline[m] for m in self.members]  # (asked per observation and keyframe)
        self.group_outline = [shapely.union_all([self.outline[i].convex_hull for i in m]) for m in self.members]
        for poly in self.group_outline:
            shapely.prepare(poly)

    def __len__(self) -> int:
        return len(self.faces)

    def to_2d(self, i: int, points: np.ndarray) -> np.ndarray:
        return (points + self.planes[i, 3] * self.planes[i, :3]) @ self.bases[i]

    def group_of(self, face: str) -> int:
        """The group of coplanar sections the face belongs to."""
        return int(self.group[self.row[face]])

    def has_sections(self, face: str) -> bool:
        """Whether the face is one of several coplanar sections (of a wall spanning rooms)."""
        return len(self.members[self.group_of(face)]) > 1

    def member_at(self, group: int, point_B: np.ndarray) -> str:
        """The face of the group nearest to a point on it."""
        members, outlines = self.members[group], self.member_outlines[group]
        if len(members) == 1:
            return self.ids[members[0]]
        uv = self.to_2d(self.rep[group], point_B[None])[0]
        p = shapely.points(uv)
        if len(members) > _MANY_SECTIONS:
            # A member's box is no farther than the member: only those whose box is nearer
            # than the member of the nearest box can be nearest (a facade of eight storeys
            # has hundreds; for a few, the test costs more than it saves)
            lo, hi = self.outline_bounds[members, :2], self.outline_bounds[members, 2:]
            box_distance = np.linalg.norm(np.maximum(np.maximum(lo - uv, uv - hi), 0.0), axis=1)
            near = box_distance <= shapely.distance(outlines[np.argmin(box_distance)], p) + 1e-9
            members, outlines = members[near], outlines[near]
        return self.ids[members[np.argmin(shapely.distance(outlines, p))]]

    def observation_faces(self, face: str | None, centres_B: list[np.ndarray | None]) -> list[str | None]:
        """The face behind each observation of a landmark matched to `face` (its group)."""
        if face is None:
            return [None] * len(centres_B)
        group = self.group_of(face)
        return [face if c is None else self.member_at(group, c) for c in centres_B]

    def residuals(self, plane_B: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The plane-to-BIM residual of `plane_B` against faces `rows` (K x 3)."""
        return self.D[rows] @ plane_B + np.stack([np.zeros(len(rows)), np.zeros(len(rows)), self.planes[rows, 3]], 1)


class BimAssociator:
    def __init__(self, faces: FaceIndex, cfg: BimAssociationConfig):
        self.faces = faces
        self.cfg = cfg
        self.gate = chi2.ppf(cfg.gate_probability, 3)
        self.cos_max = np.cos(np.radians(cfg.max_normal_angle_deg))
        # the as-built tolerance about each face's centre, in the residual of that face: for
        # the faces that stand for their group, which alone are scored (NaN for the others)
        self.tolerance = np.full((len(faces), 3, 3), np.nan)
        for row in faces.rep:
            self.tolerance[row] = face_tolerance_cov(faces.bases[row], faces.centres[row], np.radians(cfg.face_normal_deg),
                                                     cfg.face_offset_m, np.radians(cfg.face_plumb_deg))

    def eligible(self, area: float, n_observations: int, last_attempt: int = 0) -> bool:
        """Worth matching: big enough, seen often enough, and seen more since the last try (a
        floor or a cabinet seen in every keyframe is not scored again each time)."""
        return (area >= self.cfg.min_area_m2 and n_observations >= self.cfg.min_observations
                and n_observations >= last_attempt * self.cfg.retry_growth)

    def _facing(self, plane_B: np.ndarray) -> np.ndarray:
        """The face groups (by their first face's row) within the normal angle of a plane."""
        faces = self.faces
        return faces.rep[faces.planes[faces.rep, :3] @ plane_B[:3] > self.cos_max]

    def scores(self, c: PlaneInB) -> dict[int, float]:
        """Face group -> squared Mahalanobis distance, for groups passing gate and filters."""
        faces = self.faces
        rows = self._facing(c.plane_B)
        if len(rows) == 0:
            return {}
        e = faces.residuals(c.plane_B, rows)
        D = faces.D[rows]
        S = D @ c.cov_B @ D.transpose(0, 2, 1) + self.tolerance[rows]
        d2 = np.einsum("ki,ki->k", e, np.linalg.solve(S, e[:, :, None])[:, :, 0])
        out = {}
        for row, score in zip(rows[d2 <= self.gate], d2[d2 <= self.gate]):
            group = int(faces.group[row])
            if self.fits(c.extent_B, c.area, group):
                out[group] = float(score)
        return out

    def may_match(self, plane_B: np.ndarray, extent_B: np.ndarray, area: float) -> bool:
        """Whether some face passes the normal angle and the geometric filters, which need no
        covariance: a landmark none passes is not worth its joint marginal, which costs
        more than the rest of its scoring (tens of milliseconds offline, with `E` in it)."""
        return any(self.fits(extent_B, area, int(self.faces.group[row])) for row in self._facing(plane_B))

    def fits(self, extent_B: np.ndarray, area: float, group: int) -> bool:
        """The paper's geometric filters: area, corner proximity, centre alignment."""
        cfg, outline = self.cfg, self.faces.group_outline[group]
        if area > cfg.max_area_ratio * outline.area:
            return False
        if len(extent_B) == 0:
            return True
        uv = self.faces.to_2d(self.faces.rep[group], extent_B)
        if shapely.distance(shapely.points(uv), outline).max() > cfg.corner_margin_m:
            return False
        hull = hull_2d(uv)
        return outline.distance(hull.centroid if not hull.is_empty else Point(uv[0])) <= cfg.centre_margin_m

    def match(self, candidates: list[PlaneInB]) -> list[FaceMatch]:
        """One-to-one matches of the candidates, leaving out ambiguous ones."""
        rows_of: list[tuple[PlaneInB, dict[int, float]]] = []
        for c in candidates:
            s = self.scores(c)
            if not s:
                continue
            ranked = sorted(s.values())
            if len(ranked) > 1 and ranked[1] - ranked[0] < self.cfg.ambiguity_margin:
                continue
            rows_of.append((c, s))
        if not rows_of:
            return []
        cols = sorted({f for _, s in rows_of for f in s})
        cost = np.full((len(rows_of), len(cols)), _INFEASIBLE)
        for r, (_, s) in enumerate(rows_of):
            for f, score in s.items():
                cost[r, cols.index(f)] = score
        matches = []
        for r, c in zip(*linear_sum_assignment(cost)):
            if cost[r, c] < _INFEASIBLE:
                candidate, group = rows_of[r][0], cols[c]
                centre = candidate.extent_B.mean(axis=0) if len(candidate.extent_B) else None
                face = self.faces.ids[self.faces.rep[group]] if centre is None else self.faces.member_at(group, centre)
                matches.append(FaceMatch(candidate.landmark, face, float(cost[r, c])))
        return matches


def plane_in_B(T_S_B: gtsam.Pose3, T_S_A: gtsam.Pose3, plane_A: gtsam.OrientedPlane3, joint_cov: np.ndarray):
    """A plane anchored in A mapped into B, with its 4x4 covariance from the 15x15 joint
    covariance of (E = T_S_B, T_S_A, plane_A), the order of `predict_local_plane`."""
    plane_B, J = predict_local_plane(T_S_B, T_S_A, plane_A, jacobian=True)
    return plane_B, J @ joint_cov @ J.T


def planes_in_B_independent(T_B_S: np.ndarray, cov_T_B_S: np.ndarray, planes_S: np.ndarray, covs_S: np.ndarray,
                            extents_S: list[np.ndarray], areas: list[float]) -> list[PlaneInB]:
    """Candidates from a `T_B_S` estimate with covariance and planes in S with their 3x3
    tangent covariances, taken as independent (what a baseline that re-estimates `T_B_S`
    alone has). Landmark ids are the row numbers."""
    T_S_B = pose3(T_B_S).inverse()
    cov_E = extrinsic_cov_E(T_B_S, cov_T_B_S)
    identity = gtsam.Pose3()
    out = []
    for j, (plane_S, cov_S) in enumerate(zip(planes_S, covs_S)):
        joint = np.zeros((15, 15))
        joint[:6, :6] = cov_E
        joint[12:, 12:] = cov_S
        plane_B, cov_B = plane_in_B(T_S_B, identity, gtsam.OrientedPlane3(plane_S), joint)
        extent_B = extents_S[j] @ T_B_S[:3, :3].T + T_B_S[:3, 3] if len(extents_S[j]) else np.zeros((0, 3))
        out.append(PlaneInB(j, plane_B, cov_B, extent_B, areas[j]))
    return out


def candidate(lm: Landmark, T_S_B: gtsam.Pose3, joint: Callable[[list[int]], np.ndarray],
              bim: BimAssociator) -> PlaneInB | None:
    """Landmark `lm` as a candidate for `bim.match`, its covariance from `joint(keys)` (the
    joint marginal of `E`, its anchor and its plane, in that order, keys as in
    `bimgraph.backend.graph`); None where no face could take it whatever the covariance
    (`BimAssociator.may_match`)."""
    T_S_A, plane_A = pose3(lm.T_S_A), gtsam.OrientedPlane3(lm.plane_A)
    extent_B = lm.extent_in(T_S_B.inverse().matrix())
    if not bim.may_match(predict_local_plane(T_S_B, T_S_A, plane_A), extent_B, lm.area):
        return None
    plane_B, cov_B = plane_in_B(T_S_B, T_S_A, plane_A, joint([E, X(lm.anchor), L(lm.id)]))
    return PlaneInB(lm.id, plane_B, cov_B, extent_B, lm.area)
