"""Poses and planes turned into the arrays the viewer logs: segments, padded outlines,
pixels, angles. Pure numpy, no rerun."""

from __future__ import annotations

import numpy as np

from bimgraph.sequence.format import Camera, PlaneObservation


def segments(points: np.ndarray) -> np.ndarray:
    """(n, 3) points -> (n - 1, 2, 3) segments between consecutive points."""
    return np.stack([points[:-1], points[1:]], axis=1)


def closed_rings(rings: list[list]) -> np.ndarray:
    """Closed polygons as one (n, m, 3) array, the shorter ones padded by repeating their
    last point: rerun converts such an array a strip at a time, a list a point at a time."""
    longest = max((len(r) for r in rings), default=2)
    return np.array([r + r[-1:] * (longest - len(r)) for r in rings], dtype=float).reshape(-1, longest, 3)


def project(points_C: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixel coordinates (..., 2) of points in C (..., 3); points at or behind the camera
    are pulled onto a plane just in front of it (detected outlines lie in view anyway)."""
    z = np.maximum(points_C[..., 2:3], 1e-3)
    return points_C[..., :2] / z * [camera.fx, camera.fy] + [camera.cx, camera.cy]


def angles_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angles of the rotations between (stacks of) rotation matrices, in degrees."""
    cos = (np.einsum("...ij,...ij->...", R_a, R_b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def plane_centre_C(plane: PlaneObservation) -> np.ndarray:
    """The plane's centre in C: given, else the mean of its polygon, else the point of the
    plane nearest the camera."""
    if plane.centre is not None:
        return np.asarray(plane.centre, dtype=float)
    if plane.polygon is not None:
        return np.mean(plane.polygon, axis=0)
    n_d = plane.plane
    return -n_d[3] * n_d[:3]
