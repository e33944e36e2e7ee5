"""Which BIM faces the camera should have seen: the evidence for "possibly not built".

Each face is sampled on a grid; a sample is in view at a keyframe if it lies in the camera's
image and range, faces the camera not too obliquely, and the ray from the camera reaches it
before any other face of the model (open3d's RaycastingScene over the planned faces, so a
wall that is missing still hides what is behind it: the test errs toward "not expected").
A map of walls alone (no slab faces, the import's default) gets a floor at every storey's
elevation across the whole map, so that walls of the storeys above and below are not
expected through floors and ceilings; where the map has slab faces, they hide what they
cover, stairwells left open.
Pure computation, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely
from scipy.spatial import cKDTree

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.geometry import plane_frame, plane_shape
from bimgraph.viewer.meshes import face_mesh

if TYPE_CHECKING:  # (open3d takes a third of a second to load: only where rays are cast, not for `eval` or `view`)
    import open3d as o3d

# Samples sit this far in front of their face, so that the ray to one never stops on the face
# it belongs to.
_LIFT_M = 0.02
# A face's grid is coarsened to hold at most this many cells (a 0.25 m grid: 1250 m2, a large
# facade; a plane map in millimetres read as metres, 13 km across, had asked for 24 GB)
_MAX_CELLS = 20_000


def face_shape(face: BimFace) -> tuple[shapely.Polygon, np.ndarray, np.ndarray]:
    """The face's outline minus its holes in its plane's 2-D frame, with the frame's origin
    (the plane's foot point) and 3 x 2 basis: p = origin + basis @ xy."""
    origin, basis = plane_frame(face.plane)
    return plane_shape(face.plane, face.polygon, face.holes), origin, basis


@dataclass(frozen=True)
class FaceSamples:
    points_B: np.ndarray  # N x 3
    face: np.ndarray  # N, index into the plane map's faces
    area_m2: np.ndarray  # N, the area each sample stands for


def sample_faces(faces: Sequence[BimFace], grid_m: float) -> FaceSamples:
    """Grid points inside each face (its centre alone for faces smaller than a cell), the grid
    coarser than `grid_m` on a face it would cover with more than `_MAX_CELLS` cells."""
    points, index, area = [], [], []
    for i, face in enumerate(faces):
        shape, origin, basis = face_shape(face)
        x0, y0, x1, y1 = shape.bounds
        step = max(grid_m, float(np.sqrt((x1 - x0) * (y1 - y0) / _MAX_CELLS)))
        gx, gy = np.meshgrid(np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step))
        xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
        xy = xy[shapely.contains_xy(shape, xy[:, 0], xy[:, 1])]
        cell = step**2
        if len(xy) == 0:
            xy, cell = (np.array([[shape.centroid.x, shape.centroid.y]]), shape.area) if not shape.is_empty else (xy, 0.0)
        points.append(origin + xy @ basis.T + _LIFT_M * np.asarray(face.normal))
        index.append(np.full(len(xy), i))
        area.append(np.full(len(xy), cell))
    return FaceSamples(np.concatenate(points), np.concatenate(index), np.concatenate(area))


def storey_floors(faces: Sequence[BimFace], margin_m: float) -> list[np.ndarray]:
    """Where the map has no slab faces and several storeys: a horizontal rectangle (4 x 3
    corners) at each storey's elevation, over the map's extent grown by `margin_m`. Without
    them every wall of the storeys above and below is in view through the floor and the
    ceiling (walks through the sample models: 4-19 faces of other storeys expected in view,
    each listed as possibly not built). A double-height room loses what lies above its upper
    storey's elevation, erring toward "not expected" as the rest of the test does. A map of one
    storey, or faces without one (a hand-written map), get none: a floor there would be
    invented."""
    if any(face.kind != "wall" for face in faces):
        return []
    elevations = {face.storey: face.elevation for face in faces if face.storey}
    if len(elevations) < 2:
        return []
    corners = np.concatenate([np.asarray(face.polygon, dtype=float) for face in faces])
    (x0, y0), (x1, y1) = corners[:, :2].min(axis=0) - margin_m, corners[:, :2].max(axis=0) + margin_m
    return [np.array([(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]) for z in sorted(set(elevations.values()))]


def _scene(faces: Sequence[BimFace], floors: list[np.ndarray]) -> o3d.t.geometry.RaycastingScene:
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    meshes = [face_mesh(face.polygon, face.holes, face.plane) for face in faces]
    meshes += [(floor, np.array([[0, 1, 2], [0, 2, 3]])) for floor in floors]
    for V, T in meshes:
        if len(T):
            scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(T.astype(np.uint32)))
    return scene


def _in_reach(faces: Sequence[BimFace], centres_B: np.ndarray, reach_m: float) -> np.ndarray:
    """Indices of the faces whose bounding box comes within `reach_m` of the box of the camera
    centres: no other face holds a point in range of a camera, or lies on the way to one."""
    lo, hi = centres_B.min(axis=0) - reach_m, centres_B.max(axis=0) + reach_m
    corners = [np.asarray(face.polygon, dtype=float) for face in faces]
    return np.array([i for i, c in enumerate(corners) if (c.max(axis=0) >= lo).all() and (c.min(axis=0) <= hi).all()],
                    dtype=int)


def expected_view_counts(plane_map: PlaneMap, T_B_C: np.ndarray, K: np.ndarray, width: int, height: int,
                         cfg: DeviationConfig) -> dict[str, int]:
    """For every face, the number of keyframes (poses `T_B_C`, K x 4 x 4, OpenCV camera axes)
    at which at least `cfg.visibility_min_area_m2` of it was in view and not hidden."""
    import open3d as o3d

    faces = plane_map.faces
    T_B_C = np.asarray(T_B_C).reshape(-1, 4, 4)
    T_B_C = T_B_C[np.isfinite(T_B_C).all(axis=(1, 2))]  # (a pose not known sees nothing)
    # Only the faces near the walk are sampled and hide others: a building's map has thousands.
    reach = _in_reach(faces, T_B_C[:, :3, 3], cfg.visibility_max_range_m + 0.1) if len(T_B_C) else np.zeros(0, dtype=int)
    nearby = [faces[i] for i in reach]
    if not nearby:
        return {f.id: 0 for f in faces}  # (a walk outside the building)
    counts = np.zeros(len(faces), dtype=int)
    samples = sample_faces(nearby, cfg.visibility_grid_m)
    normals = np.asarray([f.normal for f in nearby])[samples.face]
    # (floors beyond the map by the range: a camera farther out sees nothing of it anyway)
    scene = _scene(nearby, storey_floors(faces, cfg.visibility_max_range_m))
    cos_max = np.cos(np.radians(cfg.visibility_max_obliquity_deg))
    # A camera sees only the samples within range: on a building's map (a thousand walls,
    # 300 000 samples) testing all of them at every keyframe took a minute.
    tree = cKDTree(samples.points_B)
    for T in T_B_C:
        c = T[:3, 3]
        near = np.sort(np.asarray(tree.query_ball_point(c, cfg.visibility_max_range_m + 1e-6), dtype=int))
        to_cam = c - samples.points_B[near]
        dist = np.linalg.norm(to_cam, axis=1)
        p_C = -to_cam @ T[:3, :3]
        z = p_C[:, 2]
        ok = (dist >= cfg.visibility_min_range_m) & (dist <= cfg.visibility_max_range_m) & (z > 1e-6)
        ok &= np.einsum("ij,ij->i", normals[near], to_cam) >= cos_max * dist
        u = K[0, 0] * p_C[:, 0] / np.where(ok, z, 1.0) + K[0, 2]
        v = K[1, 1] * p_C[:, 1] / np.where(ok, z, 1.0) + K[1, 2]
        ok &= (u >= 0) & (u < width) & (v >= 0) & (v < height)
        idx = np.flatnonzero(ok)
        if len(idx):
            dirs = -to_cam[idx] / dist[idx, None]
            rays = np.hstack([np.broadcast_to(c, (len(idx), 3)), dirs]).astype(np.float32)
            t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            seen = near[idx[t_hit >= dist[idx] - 1e-3]]
            area = np.bincount(samples.face[seen], weights=samples.area_m2[seen], minlength=len(nearby))
            counts[reach] += area >= max(cfg.visibility_min_area_m2, 1e-12)
    return {f.id: int(n) for f, n in zip(faces, counts)}
