"""Planar faces of a triangulated solid, and plane sections of triangulated solids.

Pure maths on numpy meshes (vertices V x 3 in B, triangles T x 3). A face lives in its own
2-D frame with `origin = -d * n`, `axis_u = ref x n` and `axis_v = n x axis_u`, where ref is
z for a vertical face (so u runs horizontally along the face and v is the height z in B) and
y for a horizontal one (so u, v are x, y up to sign).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import shapely
import shapely.errors
from shapely.geometry import MultiPolygon, Polygon

Z = np.array([0.0, 0.0, 1.0])
Y = np.array([0.0, 1.0, 0.0])
# How far either side of an open surface its solid is probed (metres): thinner than any wall,
# far above the rounding of a section's corners.
_PROBE_M = 1e-4


@dataclass
class Face:
    """A planar face: `normal` unit, out of the solid; `region` the face's area in the face
    frame (a shapely Polygon or MultiPolygon, holes included)."""

    normal: np.ndarray
    offset: float
    region: object

    def __post_init__(self):
        n = np.asarray(self.normal, dtype=float)
        self.normal = n / np.linalg.norm(n) + 0.0  # + 0.0: no negative zeros in the output
        ref = Z if abs(self.normal[2]) < 0.7 else Y
        self.axis_u = cross(ref, self.normal)
        self.axis_u /= np.linalg.norm(self.axis_u)
        self.axis_v = cross(self.normal, self.axis_u)
        self.origin = -self.offset * self.normal
        # B -> face frame as one affine map: (u, v) = points_B @ A + b
        self._A = np.column_stack([self.axis_u, self.axis_v])
        self._b = -self.origin @ self._A

    def to_2d(self, points_B: np.ndarray) -> np.ndarray:
        """Points in B (... x 3) in the face frame (... x 2), dropped onto the face's plane."""
        return np.asarray(points_B, dtype=float) @ self._A + self._b

    def to_3d(self, points_2d: np.ndarray) -> np.ndarray:
        q = np.asarray(points_2d, dtype=float).reshape(-1, 2)
        return self.origin + q[:, :1] * self.axis_u + q[:, 1:2] * self.axis_v


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis; np.cross costs ten times more on the small arrays here, and
    two single vectors go faster still as Python floats (the same IEEE operations)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape == b.shape == (3,):
        (a0, a1, a2), (b0, b1, b2) = a.tolist(), b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def triangle_normals(V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (T x 3, by the right-hand rule) and areas of the triangles."""
    c = cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
    norm = np.linalg.norm(c, axis=1)
    return c / np.maximum(norm, 1e-300)[:, None], norm / 2.0


def orient_outward(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The triangles of a mesh wound so that the normals of each closed part point out.
    Tessellated bodies (surface models) come with triangles wound either way: each part
    connected by edges with exactly two sides is made consistent first (where solids touch,
    as the layers of a wall do, four triangles meet at an edge and say nothing about
    winding); then the sign of its enclosed volume decides."""
    T = T.copy()
    directed = T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    half = np.sort(directed, axis=1)
    owner = np.repeat(np.arange(len(T)), 3)
    key = half[:, 0].astype(np.int64) * len(V) + half[:, 1]  # one integer per undirected edge
    order = np.argsort(key, kind="stable")
    key = key[order]
    first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1], [True]]))  # runs of one edge
    pairs = first[:-1][np.diff(first) == 2]  # edges of exactly two triangles
    a, b = order[pairs], order[pairs + 1]
    parts, label = _components(len(T), owner[a], owner[b])
    # Two triangles that run their common edge the same way disagree: one must flip.
    disagree = directed[a, 0] == directed[b, 0]
    if disagree.any():
        adjacency = scipy.sparse.coo_matrix((np.ones(len(a)), (owner[a], owner[b])), shape=(len(T), len(T)))
        pairs = {}
        for i, j, d in zip(owner[a], owner[b], disagree):
            pairs[(i, j)] = pairs[(j, i)] = d
        for part in range(parts):
            visit, parent = scipy.sparse.csgraph.breadth_first_order(
                adjacency, int(np.flatnonzero(label == part)[0]), directed=False)
            flip = {visit[0]: False}
            for t in visit[1:]:
                flip[t] = flip[parent[t]] ^ pairs[(t, parent[t])]
            flipped = np.array([t for t in visit if flip[t]], dtype=int)
            T[flipped] = T[flipped, ::-1]
    unpaired = np.ones(len(directed), dtype=bool)
    unpaired[a] = unpaired[b] = False
    closed = np.bincount(owner[unpaired], minlength=len(T))
    closed = np.bincount(label, weights=closed, minlength=parts) == 0
    volume = np.einsum("ij,ij->i", V[T[:, 0]], cross(V[T[:, 1]], V[T[:, 2]]))
    inside_out = np.bincount(label, weights=volume, minlength=parts) < 0
    for part in np.flatnonzero(~closed):  # an open surface encloses no volume to take the sign of
        inside_out[part] = _faces_into_material(V, T, label == part)
    T[inside_out[label]] = T[inside_out[label], ::-1]
    return T


def _faces_into_material(V: np.ndarray, T: np.ndarray, members: np.ndarray) -> bool:
    """Whether the triangles `members` of a mesh (an open part, consistently wound) face into
    its solid. The solid is read off the whole mesh, whatever its winding: its section through
    the centre of the part's largest triangle, across it (for a vertical triangle, the
    horizontal section: the footprint at that height), is closed wherever the mesh closes
    around that line (a wall's sides and ends without top or bottom do); the material lies on
    one side of the triangle. False where the section says nothing (no closed loop there)."""
    part = T[members]
    normals, areas = triangle_normals(V, part)
    k = int(np.argmax(areas))
    if areas[k] <= 0:
        return False
    normal, centre = normals[k], V[part[k]].mean(axis=0)
    across = Face(normal, -normal @ centre, None).axis_v  # in the triangle's plane
    cut = Face(across, -across @ centre, None)
    section = plane_section(V, T, cut, 0.0)
    (x_front, y_front), (x_back, y_back) = cut.to_2d(centre + np.outer([_PROBE_M, -_PROBE_M], normal))
    return bool(shapely.contains_xy(section, x_front, y_front)) and not shapely.contains_xy(section, x_back, y_back)


def _components(n: int, i: np.ndarray, j: np.ndarray, rounds: int = 8) -> tuple[int, np.ndarray]:
    """(count, labels) of the connected components of the graph of n nodes and edges i-j, up
    to numbering. Minimum labels spread along the edges with pointer jumping settle in a few
    rounds on a wall's mesh, without scipy's set-up cost (a third of a millisecond, more than
    the rest of a small wall's faces); long chains of triangles go to scipy."""
    label = np.arange(n)
    for _ in range(rounds):
        low = np.minimum(label[i], label[j])
        spread = label.copy()
        np.minimum.at(spread, i, low)
        np.minimum.at(spread, j, low)
        spread = spread[spread]
        if (spread == label).all():  # each node holds its component's smallest node: number those
            roots = label == np.arange(n)
            return int(roots.sum()), (np.cumsum(roots) - 1)[label]
        label = spread
    adjacency = scipy.sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    return scipy.sparse.csgraph.connected_components(adjacency, directed=False)


def _split_sorted(values: np.ndarray, tol: float) -> tuple[np.ndarray, int]:
    """Cluster labels (0 to count - 1) of 1-D values and their count: a new cluster starts
    wherever the sorted gap exceeds tol."""
    order = np.argsort(values)
    labels = np.empty(len(values), dtype=int)
    labels[order] = np.cumsum(np.concatenate([[False], np.diff(values[order]) > tol]))
    count = int(labels[order[-1]]) + 1 if len(values) else 0
    return labels, count


def vertical_faces(V, T, vertical_tol_rad: float, angle_tol_rad: float, distance_tol: float,
                   grid: float, along=None, along_tol_rad: float = 0.0) -> list[Face]:
    """The exposed vertical faces of a closed triangulated solid: triangles within
    `vertical_tol_rad` of vertical, grouped into planes by direction (`angle_tol_rad`) and
    offset (`distance_tol`); `grid` is the precision of the polygon operations. With `along` (unit
    horizontal directions), only the faces parallel to one of them (`is_side_face`).

    Triangles are grouped by unoriented plane: direction modulo pi, then offset.
    """
    V = np.asarray(V, dtype=float)
    T = orient_outward(V, np.asarray(T, dtype=int).reshape(-1, 3))
    normals, areas = triangle_normals(V, T)
    keep = (np.abs(normals[:, 2]) < np.sin(vertical_tol_rad)) & (areas > 0)
    T, normals, areas = T[keep], normals[keep], areas[keep]
    if len(T) == 0:
        return []
    theta = np.arctan2(normals[:, 1], normals[:, 0]) % np.pi
    # Directions within the tolerance of pi are the same line as those near 0.
    theta = np.where(theta > np.pi - angle_tol_rad, theta - np.pi, theta)
    faces = []
    labels, count = _split_sorted(theta, angle_tol_rad)
    for direction in range(count):
        in_dir = labels == direction
        mean = theta[in_dir].mean()
        n0 = np.array([np.cos(mean), np.sin(mean), 0.0])
        if along is not None and not is_side_face(n0 / np.linalg.norm(n0), along, along_tol_rad):
            continue
        offsets = -V[T[in_dir]].mean(axis=1) @ n0
        faces += _plane_faces(V, T[in_dir], normals[in_dir] @ n0, areas[in_dir], n0, offsets, distance_tol, grid)
    return faces


def sloped_sides(V, T, vertical_tol_rad: float, along, along_tol_rad: float, steepest_rad: float) -> tuple[float, float]:
    """(area, largest slope from vertical in radians) of the triangles of a solid that would
    be side faces (across one of the `along` directions) but lean more than
    `vertical_tol_rad` and less than `steepest_rad` out of vertical: faces the import leaves
    out, which must not go unnoticed."""
    normals, areas = triangle_normals(np.asarray(V, dtype=float), np.asarray(T, dtype=int).reshape(-1, 3))
    slope = np.arcsin(np.minimum(np.abs(normals[:, 2]), 1.0))
    leaning = (slope >= vertical_tol_rad) & (slope < steepest_rad) & (areas > 0)
    horizontal = normals[leaning] * [1, 1, 0]
    across = is_side_face(horizontal / np.linalg.norm(horizontal, axis=1)[:, None], along, along_tol_rad)
    area = float(areas[leaning][across].sum())
    return area, float(slope[leaning][across].max()) if area > 0 else 0.0


def horizontal_faces(V, T, tol_rad: float, distance_tol: float, grid: float) -> list[Face]:
    """The exposed horizontal faces of a closed triangulated solid (tops, normal +z, and
    bottoms, -z), as `vertical_faces` finds the vertical ones."""
    V = np.asarray(V, dtype=float)
    T = orient_outward(V, np.asarray(T, dtype=int).reshape(-1, 3))
    normals, areas = triangle_normals(V, T)
    keep = (np.abs(normals[:, 2]) > np.cos(tol_rad)) & (areas > 0)
    offsets = -V[T[keep]].mean(axis=1)[:, 2]
    return _plane_faces(V, T[keep], normals[keep, 2], areas[keep], Z, offsets, distance_tol, grid)


def _plane_faces(V, T, sides, areas, n0, offsets, distance_tol, grid) -> list[Face]:
    """Faces of triangles of one direction `n0`: `sides` (n . n0) says which way each one
    faces, `offsets` where its plane lies; triangles are grouped by offset. Within a plane, a
    region covered by triangles of both orientations is an internal interface (the layers of
    a multi-layer wall, two items touching) and belongs to no face."""
    faces = []
    labels, count = _split_sorted(offsets, distance_tol)
    for plane in range(count):
        members = labels == plane
        weights = areas[members]
        d0 = float((offsets[members] * weights).sum() / weights.sum())  # np.average's sums, without its checks
        reference = Face(n0, d0, None)
        regions = {s: _union_of_triangles(reference.to_2d(V[T[members & (np.sign(sides) == s)]]), grid)
                   for s in (1.0, -1.0)}
        for s in (1.0, -1.0):
            exposed = regions[s].difference(regions[-s], grid_size=grid) if not regions[-s].is_empty else regions[s]
            if exposed.is_empty or exposed.area <= 0:
                continue
            # The frame of the opposite orientation mirrors u.
            face = reference if s > 0 else Face(-n0, -d0, None)
            face.region = exposed if s > 0 else shapely.transform(exposed, lambda c: c * [-1.0, 1.0])
            faces.append(face)
    return faces


def _union_of_triangles(triangles: np.ndarray, grid: float):
    """The region covered by 2-D triangles (N x 3 x 2), to within `grid`. The triangles of
    one face of a mesh tile it edge to edge, which a coverage union merges more than ten
    times faster than a general one; anything else (overlaps, T-junctions) takes the general one."""
    if len(triangles) == 0:
        return Polygon()
    pieces = shapely.polygons(triangles)
    areas = shapely.area(pieces)
    pieces, areas = pieces[areas > 0], areas[areas > 0]
    try:
        region = shapely.coverage_union_all(pieces)
        tiled = region.is_valid and abs(region.area - areas.sum()) <= grid * region.length
    except shapely.errors.GEOSException:  # raised on some overlaps, others give a wrong area
        tiled = False
    if not tiled:
        region = shapely.union_all(pieces)
    return region


def depth_behind(face: Face, others: list[Face], angle_tol_rad: float) -> float:
    """How deep the solid is behind `face`: the distance to the nearest opposite face whose
    region overlaps it (0 if none does)."""
    depth = np.inf
    for other in others:
        if other is face or np.dot(other.normal, face.normal) > -np.cos(angle_tol_rad):
            continue
        projected = shapely.transform(other.region, lambda c: face.to_2d(other.to_3d(c)))
        if overlap_area(projected, face.region) > 0:
            depth = min(depth, abs(face.offset + other.offset))
    return 0.0 if np.isinf(depth) else depth


def long_axis(V: np.ndarray) -> np.ndarray:
    """Direction of the long side of a solid's footprint (its minimum rotated rectangle): a
    wall's axis when the model gives none."""
    rectangle = np.asarray(shapely.MultiPoint(np.asarray(V)[:, :2]).minimum_rotated_rectangle.exterior.coords)
    sides = np.diff(rectangle[:3], axis=0)
    longest = sides[np.argmax(np.linalg.norm(sides, axis=1))]
    return np.append(longest / np.linalg.norm(longest), 0.0)


def is_side_face(normal: np.ndarray, axis_directions, angle_tol_rad: float):
    """Whether a wall's face of unit `normal` is a side face (or, for unit normals k x 3,
    which are): side faces run along the wall's axis (along one of its segments); its ends,
    the steps of its profile and the faces where it is mitred to another wall do not."""
    return (np.abs(np.asarray(normal) @ np.asarray(axis_directions, dtype=float).T) < np.sin(angle_tol_rad)).any(axis=-1)


def plane_section(V, T, face: Face, depth: float) -> object:
    """The section of a closed triangulated solid by the plane `depth` behind `face`, as a
    region in the face's frame (empty if the plane misses the solid)."""
    V = np.asarray(V, dtype=float)
    T = np.asarray(T, dtype=int).reshape(-1, 3)
    s = V @ face.normal + face.offset + depth
    below = s < 0
    # Each edge once, ordered, so that both triangles of an edge cut it at the same point.
    edges = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 3, 2), axis=2)
    crossing = below[edges[..., 0]] != below[edges[..., 1]]
    cut = crossing.sum(axis=1) == 2
    if not cut.any():
        return Polygon()
    a, b = edges[cut][crossing[cut]].T
    t = (s[a] / (s[a] - s[b]))[:, None]
    points = face.to_2d(V[a] + (V[b] - V[a]) * t).reshape(-1, 2, 2)
    # A loop inside another bounds a hole (a ring-shaped wall or room): the area builder
    # takes nested loops in turn as solid and hole, where a union of the loops would fill it.
    return shapely.build_area(shapely.multilinestrings(shapely.linestrings(points)))


def recess_back(opening, face: Face, depth: float, wall, openings, slice_m: float, grid: float) -> Face | None:
    """The back of a recess: an `opening` (a mesh with V and T) that enters the `wall`
    through `face` (`depth` of wall behind it) and ends inside it. Its deepest point sets the
    back's plane, parallel to the face; its region is where the opening, just in front of
    that plane, has wall just behind it, and none of the wall's `openings` (a window set into
    the wall, its openings from either side meeting at the frame, has no back). None for an
    opening that reaches the wall's other side or stays in front of the face."""
    reach = -float((np.asarray(opening.V, dtype=float) @ face.normal + face.offset).min())  # (its deepest point)
    if not slice_m < reach < depth - slice_m:
        return None
    back = Face(face.normal, face.offset + reach, Polygon())
    region = plane_section(opening.V, opening.T, back, -slice_m).intersection(plane_section(wall.V, wall.T, back, slice_m))
    through = [h for h in (plane_section(o.V, o.T, back, slice_m) for o in openings) if not h.is_empty]
    back.region = region.difference(shapely.union_all(through, grid_size=grid), grid_size=grid) if through else region
    return back


def boxes_apart(a, b, margin: float = 0.0) -> bool:
    """Whether the bounding boxes of two regions are at least `margin` apart (touching, with
    none): then the regions share no area, which a region operation takes far longer to find."""
    (a0, a1, a2, a3), (b0, b1, b2, b3) = a.bounds, b.bounds
    return a2 + margin <= b0 or b2 + margin <= a0 or a3 + margin <= b1 or b3 + margin <= a1


def overlap_area(a, b) -> float:
    """The area of the intersection of two regions; 0 at once when their bounding boxes are
    apart or touch, as they do for a good part of the pairs a face's rooms and boundaries make."""
    return 0.0 if boxes_apart(a, b) else a.intersection(b).area


def polygons(region) -> list[Polygon]:
    if isinstance(region, Polygon):
        return [] if region.is_empty else [region]
    if isinstance(region, MultiPolygon):
        return list(region.geoms)
    return [g for g in getattr(region, "geoms", []) if isinstance(g, Polygon) and not g.is_empty]


def loop_normal(points: np.ndarray) -> np.ndarray | None:
    """Unit normal of a planar loop (Newell's method), None if degenerate."""
    p, q = points, np.roll(points, -1, axis=0)
    n = np.array([((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])).sum(),
                  ((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])).sum(),
                  ((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])).sum()])
    norm = np.linalg.norm(n)
    return n / norm if norm > 1e-12 else None
