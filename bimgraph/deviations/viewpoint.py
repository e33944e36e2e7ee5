"""Where a BIM tool's camera should stand to show a wall face (a BCF topic's viewpoint). Pure
geometry in frame B, no I/O.

The face's centre is no target on a wall with a window or a door in its middle: a tool centred
there shows the window (AC20-FZK-Haus: 21 of its 34 wall faces). Nor is a fixed distance in
front of the face always in the room: from a 1.5 m corridor it looks through the opposite
wall's door, from a 2 m room it stands behind the opposite wall.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.ops import nearest_points, polylabel

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.deviations.visibility import face_shape

# how far inside the face's edges and openings its target lies, where the face is wide enough
TARGET_MARGIN_M = 0.25
# the camera stands at most this fraction of the way to the first face behind it
_FREE_FRACTION = 0.8


def face_target(face: BimFace, margin_m: float = TARGET_MARGIN_M) -> np.ndarray:
    """The point of the face's material nearest its centre that lies `margin_m` inside its
    edges and openings; on a face too narrow for that margin, the point farthest from them."""
    shape, origin, basis = face_shape(face)
    centre = shapely.Point((np.asarray(face.centre, dtype=float) - origin) @ basis)
    inner = shape.buffer(-margin_m)
    if inner.is_empty:
        largest = max(getattr(shape, "geoms", [shape]), key=lambda p: p.area)
        point = polylabel(largest, tolerance=0.01)
    else:
        point = nearest_points(inner, centre)[0]
    return origin + basis @ np.array([point.x, point.y])


def first_hit(plane_map: PlaneMap, start: np.ndarray, direction: np.ndarray, max_m: float) -> float:
    """The distance from `start` along the unit `direction` to the first face of the map the ray
    meets, or `max_m` if none is nearer. A face blocks over its convex hull: its openings hold
    doors and windows, which block the view in a BIM tool (a door at the floor is a notch in
    the outline, not a hole)."""
    planes = plane_map.planes
    along = planes[:, :3] @ direction
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(planes[:, :3] @ start + planes[:, 3]) / along
    order = np.argsort(t)
    for i in order[(t[order] > 1e-6) & (t[order] < max_m)]:
        shape, origin, basis = face_shape(plane_map.faces[i])
        if shape.convex_hull.covers(shapely.Point((start + t[i] * direction - origin) @ basis)):
            return float(t[i])
    return max_m


def viewpoint(plane_map: PlaneMap, face: BimFace, distance_m: float, rise_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, target) in B to look at `face` from `distance_m` in front of it and
    `rise_m` above its target, or nearer, where another face stands in between."""
    target = face_target(face)
    offset = distance_m * np.asarray(face.normal, dtype=float) + np.array([0.0, 0.0, rise_m])
    length = float(np.linalg.norm(offset))
    free = first_hit(plane_map, target, offset / length, length)
    return target + offset * (1.0 if free >= length else _FREE_FRACTION * free / length), target
