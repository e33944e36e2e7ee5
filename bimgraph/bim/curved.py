"""Side faces of walls along a bent or curved axis (pure maths, no I/O).

Along a straight axis, a face is a side if it runs parallel to the axis. Along a bent or
curved one that depends on where the face lies (`runs_along`), and the geometry kernel gives
a curved side as strips a degree or two apart, merged here into as few planar facets as keep
the surface within a tolerance (`merge_facets`).
"""

from __future__ import annotations

import numpy as np
import shapely

from bimgraph.bim.faces import Face, is_side_face

# Neighbouring faces turning by more than this meet at a corner: the kernel tessellates a
# curved surface in steps of at most its angular deflection, 0.5 rad (29 degrees).
_CORNER_RAD = np.radians(30.0)


def plan_ends(face: Face) -> np.ndarray:
    """The two ends (2 x 2, x and y in B) of a vertical face along the floor, in the order of
    its u axis."""
    u0, _, u1, _ = face.region.bounds
    return (face.origin + np.outer([u0, u1], face.axis_u))[:, :2]


def runs_along(face: Face, axis, angle_tol_rad: float, grid: float) -> bool:
    """Whether a vertical face runs along a wall's axis (a shapely LineString in plan, of
    several segments or a curve's) where the face lies: parallel to the stretch of axis
    between the points nearest its two ends. For a facet of a curved wall that stretch is the
    axis's chord over the same arc; an end face's two ends are nearest one point, the axis's
    end (`grid`: closer than that is one point)."""
    nearest = shapely.line_interpolate_point(axis, shapely.line_locate_point(axis, shapely.points(plan_ends(face))))
    stretch = np.diff(shapely.get_coordinates(nearest), axis=0)[0]
    length = float(np.linalg.norm(stretch))
    return length > grid and is_side_face(face.normal, [np.append(stretch / length, 0.0)], angle_tol_rad)


def merge_facets(faces: list[Face], tol: float, distance_tol: float, grid: float) -> list[Face]:
    """Vertical faces with a curved surface's facets merged into as few planes as keep the
    surface within `tol` of them. The kernel gives a curved wall's side as strips a degree or
    two apart; in plan, a run of faces each starting where the one before ends (within
    `distance_tol`, turning by less than a corner) is a polyline, simplified to `tol`
    (Douglas-Peucker: the kept vertices are the run's own); each of its segments becomes one
    face, the union of the faces it replaces projected onto it. Others are returned as they
    are."""
    if len(faces) < 2:
        return faces
    ends = np.array([plan_ends(face) for face in faces])
    normals = np.array([face.normal for face in faces])
    gap = np.linalg.norm(ends[:, None, 1] - ends[None, :, 0], axis=2)  # [i, j]: from i's end to j's start
    gap[(normals @ normals.T <= np.cos(_CORNER_RAD)) | np.eye(len(faces), dtype=bool)] = np.inf
    following = {i: int(np.argmin(gap[i])) for i in np.flatnonzero(gap.min(axis=1) <= distance_tol)}
    if not following:
        return faces
    # Runs start at faces nothing leads to; what is left is a closed loop (a round wall), cut anywhere.
    led = set(following.values())
    seen, out = set(), []
    for start in [i for i in range(len(faces)) if i not in led] + list(range(len(faces))):
        run = []
        i = start
        while i is not None and i not in seen:
            seen.add(i)
            run.append(i)
            i = following.get(i)
        if run:
            out += _merge_run([faces[i] for i in run], np.vstack([ends[run, 0], ends[run[-1], 1]]), tol, grid)
    return out


def _merge_run(run: list[Face], points: np.ndarray, tol: float, grid: float) -> list[Face]:
    """`run` (faces in order along the floor, `points` its polyline in plan: each face's start,
    then the last one's end) as the faces of its polyline simplified to `tol`."""
    kept = set(map(tuple, shapely.get_coordinates(shapely.LineString(points).simplify(tol, preserve_topology=False)).tolist()))
    corners = [k for k, p in enumerate(map(tuple, points.tolist())) if p in kept]
    out = []
    for k0, k1 in zip(corners, corners[1:]):
        members = run[k0:k1]
        if len(members) == 1:
            out += members
            continue
        along = points[k1] - points[k0]
        normal = np.array([along[1], -along[0], 0.0]) / np.linalg.norm(along)
        if normal @ sum(m.normal * m.region.area for m in members) < 0:
            normal = -normal
        face = Face(normal, -float(normal[:2] @ points[k0]), None)
        face.region = shapely.union_all([shapely.transform(m.region, lambda c, m=m: face.to_2d(m.to_3d(c)))
                                         for m in members], grid_size=grid)
        out.append(face)
    return out
