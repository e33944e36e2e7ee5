"""Triangle meshes of BIM faces (a planar polygon with holes in B), for display.

The polygon is triangulated in 2-D by shapely's constrained Delaunay triangulation (GEOS),
after dropping the coordinate along which the face's normal is largest; the dropped
coordinate is then recovered from the plane equation, so every vertex lies exactly on the
face's plane. Pure geometry, no I/O.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon


def face_mesh(polygon_B, holes_B, plane_B) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V x 3, in B) and triangles (T x 3 vertex indices) of a planar polygon minus
    its holes. Holes may touch or cross the outline (a door cut at floor level): the area
    is computed as outline minus the union of holes, so that the result is always valid."""
    plane_B = np.asarray(plane_B, dtype=float)
    n, d = plane_B[:3], plane_B[3]
    drop = int(np.argmax(np.abs(n)))
    keep = [i for i in range(3) if i != drop]

    area = shapely.make_valid(Polygon(np.asarray(polygon_B, dtype=float)[:, keep]))
    if holes_B:
        area = area.difference(shapely.union_all([shapely.make_valid(Polygon(np.asarray(h, dtype=float)[:, keep])) for h in holes_B]))
    # make_valid and difference may leave stray lines or points next to the polygons.
    polygons = [g for g in getattr(area, "geoms", [area]) if g.geom_type in ("Polygon", "MultiPolygon") and g.area > 0]
    if not polygons:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint32)

    triangles_2d = shapely.get_parts(shapely.constrained_delaunay_triangles(shapely.MultiPolygon(
        [p for g in polygons for p in getattr(g, "geoms", [g])])))
    # Each triangle is a closed ring of 4 points; keep the first three.
    corners = shapely.get_coordinates(shapely.get_exterior_ring(triangles_2d)).reshape(-1, 4, 2)[:, :3]
    points_2d, triangles = np.unique(corners.reshape(-1, 2), axis=0, return_inverse=True)

    vertices = np.empty((len(points_2d), 3))
    vertices[:, keep] = points_2d
    vertices[:, drop] = -(d + points_2d @ n[keep]) / n[drop]
    triangles = triangles.reshape(-1, 3).astype(np.uint32)
    # Wind every triangle counter-clockwise seen from the normal's side, so that a renderer
    # culling back faces shows the side facing into the room.
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    flip = np.cross(b - a, c - a) @ n < 0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return vertices, triangles
