"""Plane detections sampled from the visible parts of the as-built surfaces (--sensor planes).

A coarse ray cast (every `stride_px` pixels of the camera image) finds which part of which
element the camera sees within range. Each element seen on enough pixels and area becomes a
detection: its as-built plane in C, perturbed in the tangent space of gtsam's OrientedPlane3
by noise that grows with distance and shrinks with obliquity (as a plane fitted to the depth
sensor's images does), with that noise as its covariance; its polygon is the visible part
(the element's outline clipped to the hull of the pixels that see it), projected onto the
noisy plane.
Pure computation: no files.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from shapely.geometry import Polygon, box

from bimgraph.config import ObserveConfig
from bimgraph.geometry import inverse, plane_to_frame
from bimgraph.sequence.format import Camera, PlaneObservation
from bimgraph.sequence.groundtruth import rounded
from bimgraph.sim.world import Element, plane_basis

# The least sigma a detection claims (radians, metres).
_MIN_SIGMA = 1e-6


@dataclass
class Detection:
    observation: PlaneObservation
    element: int  # index into the world's element list
    plane_C_true: np.ndarray  # as-built plane in C, before noise


def coarse_camera(camera: Camera, stride: int) -> Camera:
    """The same view sampled every `stride` pixels (pixel centres kept aligned)."""
    return Camera(width=camera.width // stride, height=camera.height // stride,
                  fx=camera.fx / stride, fy=camera.fy / stride,
                  cx=(camera.cx + 0.5) / stride - 0.5, cy=(camera.cy + 0.5) / stride - 0.5,
                  depth_scale=camera.depth_scale)


def perturb_plane(plane: np.ndarray, sigma_n: float, sigma_d: float, rng: np.random.Generator) -> np.ndarray:
    """OrientedPlane3 retraction of a random tangent vector: the normal turned by a 2-D
    Gaussian angle (isotropic, so the tangent basis does not matter), d shifted."""
    n = plane[:3]
    v = plane_basis(n) @ (rng.standard_normal(2) * sigma_n)
    angle = np.linalg.norm(v)
    n_new = n * np.cos(angle) + (v / angle * np.sin(angle) if angle > 0 else 0.0)
    return np.concatenate([n_new / np.linalg.norm(n_new), [plane[3] + rng.standard_normal() * sigma_d]])


def visible_part(element: Element, points_B: np.ndarray, buffer_m: float):
    """The element's outline clipped to the hull of the points that see it (in its 2-D
    frame), as the largest polygon; None if nothing is left."""
    origin, basis = element.frame
    xy = (points_B - origin) @ basis
    mean = xy.mean(axis=0)
    hull_xy = cv2.convexHull((xy - mean).astype(np.float32)).reshape(-1, 2) + mean
    if len(hull_xy) < 3:
        return None
    # Grown by half a sample so that the hull reaches the edges the samples fall short of.
    hull = Polygon(hull_xy).buffer(buffer_m, join_style="mitre").simplify(0.25 * buffer_m)
    part = element.shape.intersection(hull)
    if part.is_empty or part.area <= 0:
        return None
    if part.geom_type != "Polygon":
        part = max((g for g in getattr(part, "geoms", []) if g.geom_type == "Polygon"), key=lambda g: g.area, default=None)
    return part


def detect(depth: np.ndarray, ids: np.ndarray, coarse: Camera, T_B_C: np.ndarray, elements: list[Element],
           stride: int, cfg: ObserveConfig, rng: np.random.Generator) -> tuple[list[Detection], dict[int, int]]:
    """Detections in one keyframe from a coarse z-depth and element-id image, and the number of
    full-resolution pixels each element covers within range (its visibility)."""
    rays = np.stack(np.meshgrid((np.arange(coarse.width) - coarse.cx) / coarse.fx,
                                (np.arange(coarse.height) - coarse.cy) / coarse.fy), axis=-1)
    in_range = (depth >= cfg.min_range_m) & (depth <= cfg.max_range_m) & (ids >= 0)
    pixel_area = stride * stride
    camera_B = T_B_C[:3, 3]
    visible: dict[int, int] = {}
    detections = []
    found = ids[in_range]
    for e in np.unique(found):
        e = int(e)
        mask = in_range & (ids == e)
        count = int(mask.sum())
        visible[e] = count * pixel_area
        element = elements[e]
        if element.kind in ("floor", "ceiling") and not cfg.floors_and_ceilings:
            continue
        if count * pixel_area < cfg.min_pixels:
            continue
        z = depth[mask]
        points_C = np.column_stack([rays[mask] * z[:, None], z])
        points_B = points_C @ T_B_C[:3, :3].T + camera_B
        plane_C = plane_to_frame(element.plane, T_B_C)
        if plane_C[3] <= 0:  # seen from behind: not a surface the sensor can face
            continue
        part = visible_part(element, points_B, 0.5 * float(np.median(z)) * stride / coarse.fx)
        if part is None:
            continue
        origin, basis = element.frame
        to_centre = origin + np.asarray(part.centroid.coords)[0] @ basis.T - camera_B
        cos_view = abs(float(element.plane[:3] @ to_centre)) / float(np.linalg.norm(to_centre))
        if part.area < cfg.min_area_m2 or np.degrees(np.arccos(min(cos_view, 1.0))) > cfg.max_obliquity_deg:
            continue
        # A detector sometimes breaks one surface into two planes.
        pieces = [part]
        if part.area >= 2 * cfg.min_area_m2 and rng.random() < cfg.oversegment_probability:
            # a cut through the centroid of an odd shape can leave a piece below the minimum:
            # the detector would not report it
            pieces = [p for p in split_in_two(part) if p.area >= cfg.min_area_m2] or [part]
        for piece in pieces:
            observation = _observe(piece, element, plane_C, T_B_C, round(count * pixel_area * piece.area / part.area), cfg, rng)
            detections.append(Detection(observation, e, plane_C))
    return detections, visible


def split_in_two(part: Polygon) -> list[Polygon]:
    """The polygon cut across its longer side through its centroid (the larger pieces of the
    cut if it falls apart into more)."""
    (x0, y0, x1, y1), (cx, cy) = part.bounds, part.centroid.coords[0]
    cut = box(cx, y0 - 1, x1 + 1, y1 + 1) if x1 - x0 >= y1 - y0 else box(x0 - 1, cy, x1 + 1, y1 + 1)
    halves = [part.intersection(cut), part.difference(cut)]
    pieces = [max(getattr(h, "geoms", [h]), key=lambda g: g.area) for h in halves if not h.is_empty]
    return [p for p in pieces if p.geom_type == "Polygon" and p.area > 0] or [part]


def _observe(part: Polygon, element: Element, plane_C: np.ndarray, T_B_C: np.ndarray, inliers: int,
             cfg: ObserveConfig, rng: np.random.Generator) -> PlaneObservation:
    """The noisy detection of the visible `part` of `element`: its plane in C perturbed by the
    noise of its view, its outline and centre projected onto that plane."""
    origin, basis = element.frame
    T_C_B = inverse(T_B_C)
    ring_B = origin + np.asarray(part.exterior.coords)[:-1] @ basis.T
    centre_B = origin + np.asarray(part.centroid.coords)[0] @ basis.T
    to_centre = centre_B - T_B_C[:3, 3]
    range_m = float(np.linalg.norm(to_centre))
    cos_view = abs(float(element.plane[:3] @ to_centre)) / range_m
    sigma_n, sigma_d = cfg.noise.sigmas(range_m, cos_view)
    # (a covariance must be positive definite: with the noise off, detections claim 1e-6)
    sigma_n, sigma_d = max(sigma_n, _MIN_SIGMA), max(sigma_d, _MIN_SIGMA)
    noisy = perturb_plane(plane_C, sigma_n, sigma_d, rng)
    ring_C = _project(ring_B @ T_C_B[:3, :3].T + T_C_B[:3, 3], noisy)
    centre_C = _project((T_C_B[:3, :3] @ centre_B + T_C_B[:3, 3])[None], noisy)[0]
    cov = np.diag([sigma_n**2, sigma_n**2, sigma_d**2])
    return PlaneObservation(
        n=tuple(rounded(noisy[:3])), d=rounded(noisy[3]), cov=tuple(tuple(rounded(r, 12)) for r in cov),
        polygon=[tuple(rounded(p)) for p in ring_C], area=rounded(part.area), centre=tuple(rounded(centre_C)),
        inliers=inliers,
    )


def _project(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    return points - np.outer(points @ plane[:3] + plane[3], plane[:3])

