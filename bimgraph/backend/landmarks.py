"""Plane landmarks as the association sees them: the current estimate in the anchor keyframe
A, its marginal covariance, its extent (convex hull of every observed polygon, in A) and its
match to a BIM face. The graph holds the estimates; this is the cache association reads."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np
import shapely
from shapely.geometry import Polygon

from bimgraph.backend.graph import L, X
from bimgraph.backend.incremental import FrozenPlane
from bimgraph.geometry import inverse, plane_from_frame


def plane_basis(n: np.ndarray) -> np.ndarray:
    """3x2 orthonormal basis of the plane with normal n (gtsam's Unit3 basis)."""
    return gtsam.Unit3(np.asarray(n, dtype=float)).basis()


def to_plane_2d(points: np.ndarray, plane: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Points (N x 3) projected into the plane's own 2-D frame (origin at its foot point);
    `basis` is the plane's `plane_basis`, which callers keep (gtsam's Unit3 costs more than
    the projection)."""
    return (points + plane[3] * plane[:3]) @ basis


def from_plane_2d(uv: np.ndarray, plane: np.ndarray, basis: np.ndarray) -> np.ndarray:
    return -plane[3] * plane[:3] + uv @ basis.T


def hull_2d(uv: np.ndarray):
    """Convex hull of 2-D points as a shapely geometry (a polygon, or less when degenerate)."""
    # a line string through the points has their hull and is made straight from the array
    # (a multipoint makes a point geometry per row first: twice the time of the hull itself)
    return (shapely.linestrings(uv) if len(uv) > 1 else shapely.multipoints(uv)).convex_hull


def centroid(points: np.ndarray) -> np.ndarray:
    """The mean of points (N x 3, N > 0); np.mean costs three times this per call."""
    return points.sum(axis=0) / len(points)


def bounding_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The centroid of points (N x 3, N > 0) and the radius about it that holds them all."""
    centre = centroid(points)
    return centre, math.sqrt(((points - centre) ** 2).sum(axis=1).max())


def transform_points(T_A_B: np.ndarray, points_B: np.ndarray) -> np.ndarray:
    return points_B @ T_A_B[:3, :3].T + T_A_B[:3, 3]


# How the alignment uses a matched landmark's plane-to-BIM factor: kept whole; the wall's
# direction kept and its offset left to the observations; or out of the alignment. Offline the
# robust alignment decides (`bimgraph.backend.robust_alignment`: a wall found off plan is
# measured, not followed); online every match is kept.
KEPT, DIRECTION, OUT = "kept", "direction", "out"


@dataclass
class Landmark:
    id: int
    anchor: int | None  # the keyframe it is held in; None: held in S (`graph.landmark_keys`)
    plane_A: np.ndarray
    cov_A: np.ndarray
    T_S_A: np.ndarray
    extent_A: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    area: float = 0.0
    observations: list[tuple[int, int]] = field(default_factory=list)
    face: str | None = None
    score: float = float("nan")
    rejected: set[str] = field(default_factory=set)  # faces it was matched to and unmatched from
    hull_A: object = None  # the extent as a shapely geometry in the plane's 2-D frame (when grown)
    sphere_A: np.ndarray | None = None  # the extent's centre in A (when grown)...
    radius: float = float("inf")  # ...and the radius of a sphere about it holding the extent
    centres_A: list = field(default_factory=list)  # per observation, its centre in A (or None)
    observation_faces: list | None = None  # per observation, the face behind it, once resolved
    bim_attempt: int = 0  # observation count when last scored against the BIM faces
    merged_into: int | None = None  # set when an offline round found it to be another landmark's plane
    # how the alignment uses its plane-to-BIM factor (offline GNC decides; see below)
    alignment: str = KEPT
    # online, once frozen: its anchor and plane as they were (`incremental.FrozenPlane`); later
    # observations use copies
    frozen: FrozenPlane | None = None

    def absorb(self, other: "Landmark", max_points: int) -> None:
        """Take over the observations and extent of a landmark found to be the same plane."""
        T_A_B = inverse(self.T_S_A) @ other.T_S_A
        moved = [None if c is None else transform_points(T_A_B, c[None])[0] for c in other.centres_A]
        pairs = sorted(zip(self.observations + other.observations, self.centres_A + moved), key=lambda p: p[0])
        self.observations = [o for o, _ in pairs]
        self.centres_A = [c for _, c in pairs]
        self.grow_extent(transform_points(T_A_B, other.extent_A), other.area, max_points)
        other.merged_into = self.id

    def add_observation(self, k: int, index: int, points_A: np.ndarray, area: float | None, max_points: int) -> None:
        self.observations.append((k, index))
        self.centres_A.append(centroid(points_A) if len(points_A) else None)
        self.grow_extent(points_A, area, max_points)

    def centres_in(self, T_X_S: np.ndarray) -> list[np.ndarray | None]:
        T_X_A = T_X_S @ self.T_S_A
        return [None if c is None else T_X_A[:3, :3] @ c + T_X_A[:3, 3] for c in self.centres_A]

    @property
    def plane_S(self) -> np.ndarray:
        return plane_from_frame(self.plane_A, self.T_S_A)

    @property
    def keyframes(self) -> list[int]:
        return sorted({k for k, _ in self.observations})

    def grow_extent(self, points_A: np.ndarray, area: float | None, max_points: int) -> None:
        """Add observed boundary points (in A) to the extent: the hull on the current plane."""
        if len(points_A) == 0:
            if area is not None:
                self.area = max(self.area, area)
            return
        basis = plane_basis(self.plane_A[:3])
        uv = to_plane_2d(np.vstack([self.extent_A, points_A]), self.plane_A, basis)
        hull = hull_2d(uv)
        # (a hull polygon has no holes: its coordinates are its exterior ring, closed)
        if isinstance(hull, Polygon):
            coords = shapely.get_coordinates(hull)[:-1]
            if len(coords) > max_points:
                coords = shapely.get_coordinates(hull.simplify(0.02))[:-1]
            self.area = max(hull.area, area or 0.0)
        else:
            coords = shapely.get_coordinates(hull)
            self.area = max(self.area, area or 0.0)
        self.extent_A = from_plane_2d(coords, self.plane_A, basis)
        self.hull_A = hull
        # its bounding sphere, which association moves into S with every new estimate
        self.sphere_A, self.radius = bounding_sphere(self.extent_A)

    def extent_in(self, T_X_S: np.ndarray) -> np.ndarray:
        """The extent's points in frame X, given T_X_S."""
        return transform_points(T_X_S @ self.T_S_A, self.extent_A)


class LandmarkTable:
    """Every landmark, with what gating needs stacked in arrays: planes in S and in their
    anchors, anchor poses, covariances, Unit3 bases, and a bounding sphere of each extent in S."""

    def __init__(self):
        self.items: list[Landmark] = []
        self.planes_S = np.zeros((0, 4))
        self.planes_A = np.zeros((0, 4))
        self.T_A_S = np.zeros((0, 4, 4))
        self.covs_A = np.zeros((0, 3, 3))
        self.bases_A = np.zeros((0, 3, 2))
        self.centres_S = np.zeros((0, 3))
        self.radii = np.zeros(0)  # inf where the extent is unknown
        self.active = np.zeros(0, dtype=bool)  # False once merged into another landmark

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, j: int) -> Landmark:
        return self.items[j]

    def current(self) -> list[Landmark]:
        """The landmarks not merged into another."""
        return [lm for lm in self.items if lm.merged_into is None]

    def merge(self, keep: Landmark, gone: Landmark, max_points: int) -> None:
        """`gone` is `keep`'s plane: `keep` takes its observations and extent, and association
        no longer offers `gone`."""
        keep.absorb(gone, max_points)
        self.active[gone.id] = False

    def add(self, landmark: Landmark) -> None:
        assert landmark.id == len(self.items)
        self.items.append(landmark)
        self.planes_S = np.vstack([self.planes_S, np.zeros(4)])
        self.planes_A = np.vstack([self.planes_A, np.zeros(4)])
        self.T_A_S = np.concatenate([self.T_A_S, np.eye(4)[None]])
        self.covs_A = np.concatenate([self.covs_A, np.eye(3)[None]])
        self.bases_A = np.concatenate([self.bases_A, np.zeros((1, 3, 2))])
        self.centres_S = np.vstack([self.centres_S, np.zeros(3)])
        self.radii = np.append(self.radii, np.inf)
        self.active = np.append(self.active, True)
        self.set_estimate(landmark.id, landmark.plane_A, landmark.T_S_A, landmark.cov_A)

    def set_estimate(self, j: int, plane_A: np.ndarray, T_S_A: np.ndarray, cov_A: np.ndarray | None = None) -> None:
        self.set_estimates([j], plane_A[None], T_S_A[None], {} if cov_A is None else {j: cov_A})

    def read(self, values: gtsam.Values, js: list[int], covs_A: dict[int, np.ndarray] | None = None) -> None:
        """The estimates of landmarks `js` (each plane and its anchor) from a graph's `values`,
        and the marginals in `covs_A` (by landmark)."""
        self.set_estimates(js, np.array([values.atOrientedPlane3(L(j)).planeCoefficients() for j in js]),
                           np.array([values.atPose3(X(self.items[j].anchor)).matrix() for j in js]), covs_A or {})

    def set_estimates(self, js: list[int], planes_A: np.ndarray, T_S_A: np.ndarray, covs_A: dict[int, np.ndarray]) -> None:
        """New estimates of landmarks `js` (planes in their anchors, anchor poses, stacked) and
        of the marginals in `covs_A` (by landmark), in one pass (per landmark, numpy's calls
        cost more than the maths)."""
        if not js:
            return
        R_S_A, t_S_A = T_S_A[:, :3, :3], T_S_A[:, :3, 3]
        R_A_S = R_S_A.transpose(0, 2, 1)
        T_A_S = np.zeros_like(T_S_A)
        T_A_S[:, :3, :3] = R_A_S
        T_A_S[:, :3, 3] = -(R_A_S @ t_S_A[:, :, None])[:, :, 0]
        T_A_S[:, 3, 3] = 1.0
        self.planes_A[js] = planes_A
        self.T_A_S[js] = T_A_S
        # (`plane_to_frame(plane_A, T_A_S)`: the plane in S)
        n_A = planes_A[:, :3]
        self.planes_S[js] = np.concatenate([(R_S_A @ n_A[:, :, None])[:, :, 0],
                                            planes_A[:, 3:] + (n_A * T_A_S[:, :3, 3]).sum(axis=1, keepdims=True)], axis=1)
        for row, j in enumerate(js):
            lm = self.items[j]
            lm.plane_A, lm.T_S_A = planes_A[row], T_S_A[row]
            if j in covs_A:
                lm.cov_A = covs_A[j]
                self.covs_A[j] = covs_A[j]
            self.bases_A[j] = plane_basis(planes_A[row, :3])
            if lm.sphere_A is not None:
                self.centres_S[j] = R_S_A[row] @ lm.sphere_A + t_S_A[row]
                self.radii[j] = lm.radius


def observation_points(polygon, centre) -> np.ndarray:
    """The points an observation contributes to an extent (its polygon, else its centre)."""
    if polygon:
        return np.asarray(polygon, dtype=float)
    if centre is not None:
        return np.asarray(centre, dtype=float)[None, :]
    return np.zeros((0, 3))


def anchor_from(T_S_C: np.ndarray, T_S_A: np.ndarray) -> np.ndarray:
    """T_A_C."""
    return inverse(T_S_A) @ T_S_C
