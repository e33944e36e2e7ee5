"""Split wall faces per room. Pure geometry on faces in their 2-D frames (see `faces.Face`).

A room claims a region of a face, by the best evidence available for that face:
1. `space_boundary`: 2nd-level space boundaries lying on the face (ArchiCAD, BlenderBIM);
2. `space_boundary_projected`: boundaries parallel to the face inside the wall (Revit puts
   them on the centre line), projected onto the face if the room lies on the face's side;
3. `space_footprint`: the rooms' solids, cut by a plane just in front of the face.
Parts of a face that no room claims (slab edges, wall ends at junctions) join the section
they share the longest border with. In a model without rooms, `junction`: the face is cut
where other walls meet it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from bimgraph.bim.faces import Face, boxes_apart, overlap_area, plane_section, polygons


@dataclass
class Claim:
    space_guid: str | None  # None: a section of no room
    method: str  # the plane map's `split`
    region: object  # in the face frame


def boundary_claims(face: Face, depth: float, boundaries, on_face_tol: float, angle_tol_rad: float,
                    rooms_in_front: dict) -> list[Claim]:
    """Claims from the space boundaries of the face's wall. A boundary inside the wall counts
    for the face only where its room is in front of the face (`rooms_in_front`: space guid ->
    the room's region just in front, from `Rooms.claims`)."""
    claims = []
    for boundary in boundaries:
        normal = boundary.normal
        if normal is None or abs(normal @ face.normal) < np.cos(angle_tol_rad):
            continue
        distance = boundary.points @ face.normal + face.offset
        if np.abs(distance).max() <= on_face_tol:
            claims.append(Claim(boundary.space_guid, "space_boundary", _region(face, boundary.points)))
        elif distance.max() <= on_face_tol and distance.min() >= -depth - on_face_tol:
            room = rooms_in_front.get(boundary.space_guid)
            if room is None:  # the boundary of a room behind the wall
                continue
            region = _region(face, boundary.points)
            if overlap_area(room, region) > 0:
                claims.append(Claim(boundary.space_guid, "space_boundary_projected", region))
    return claims


def _region(face: Face, points: np.ndarray):
    """A boundary loop (points in B) as a region in the face frame."""
    return shapely.union_all(polygons(shapely.make_valid(shapely.Polygon(face.to_2d(points)))))


class Rooms:
    """The rooms' closed meshes (space guid -> meshes in B) with their bounding boxes, to find
    quickly which rooms a plane in front of a face cuts."""

    def __init__(self, rooms: dict):
        self.items = [(guid, mesh) for guid, meshes in rooms.items() for mesh in meshes]
        boxes = np.array([[m.V.min(axis=0), m.V.max(axis=0)] for _, m in self.items]).reshape(-1, 2, 3)
        pick = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])  # the 8 corners
        self.corners = boxes[:, pick, [0, 1, 2]]  # rooms x 8 x 3

    def claims(self, face: Face, probe: float) -> list[Claim]:
        """Claims of every room whose solid the plane `probe` in front of the face cuts: the
        section, seen on the face."""
        if not self.items:
            return []
        u0, v0, u1, v1 = face.region.bounds
        distance = self.corners @ face.normal + face.offset - probe
        uv = face.to_2d(self.corners)
        u, z = uv[..., 0], uv[..., 1]
        near = ((distance.min(axis=1) <= 0) & (distance.max(axis=1) >= 0) & (u.min(axis=1) <= u1)
                & (u.max(axis=1) >= u0) & (z.min(axis=1) <= v1) & (z.max(axis=1) >= v0))
        regions = {}
        for i in np.flatnonzero(near):
            guid, mesh = self.items[i]
            region = plane_section(mesh.V, mesh.T, face, -probe)
            if not region.is_empty:
                regions.setdefault(guid, []).append(region)
        claims = [Claim(guid, "space_footprint", shapely.union_all(r)) for guid, r in regions.items()]
        return [c for c in claims if c.region.area > 0]


class Junctions:
    """Where other walls meet a face: the paper's split for models without rooms."""

    def __init__(self, walls: dict):
        self.items = list(walls.items())  # wall id -> mesh in B
        self.boxes = np.array([[m.V.min(axis=0), m.V.max(axis=0)] for _, m in self.items]).reshape(-1, 2, 3)

    def cuts(self, face: Face, wall_id: int, touch: float, min_width: float) -> list[float]:
        """u of the axis of every wall abutting the face from the front (its end lies on the
        face's plane), at least `min_width` from the face's ends."""
        u0, v0, u1, v1 = face.region.bounds
        out = []
        for (wall, mesh), (lo, hi) in zip(self.items, self.boxes):
            if wall == wall_id or lo[2] >= v1 - touch or hi[2] <= v0 + touch:  # a wall above or below
                continue
            distance = mesh.V @ face.normal + face.offset
            on_plane = np.abs(distance) <= touch
            if not on_plane.any() or distance.max() <= touch:
                continue
            u = face.to_2d(mesh.V[on_plane])[:, 0]
            centre = (u.min() + u.max()) / 2
            if u0 + min_width < centre < u1 - min_width:
                out.append(float(centre))
        return sorted(out)


def split_at(face: Face, cuts: list[float]) -> list:
    """The face's region cut by vertical lines at `cuts` (u), left to right."""
    u0, v0, u1, v1 = face.region.bounds
    edges = [u0 - 1, *cuts, u1 + 1]
    return [face.region.intersection(shapely.box(a, v0 - 1, b, v1 + 1)) for a, b in zip(edges, edges[1:])]


def split_face(face: Face, claims: list[Claim], grid: float) -> list[tuple[object, Claim | None]]:
    """The face's region cut into one region per claiming room (first claim first), with the
    unclaimed remainder merged into its neighbours; [(region, claim or None)]. A face with
    a single room in front belongs to it, but for the parts of the face its room does not reach."""
    if not claims:
        return [(face.region, None)]
    if len({c.space_guid for c in claims}) == 1:  # one room in front: its parts of the face
        claimed = shapely.union_all([c.region for c in claims])
        parts = polygons(face.region)
        reached = [overlap_area(p, claimed) > grid for p in parts]
        out = []
        for group_reached in (True, False):
            group = [p for p, r in zip(parts, reached) if r == group_reached]
            if group:
                out.append((shapely.union_all(group), claims[0] if group_reached else None))
        return out
    # A room often claims a face in pieces (a boundary each side of a door): one region each.
    merged: dict[tuple, list] = {}
    for claim in claims:
        merged.setdefault((claim.space_guid, claim.method), []).append(claim.region)
    remaining = face.region
    parts: dict[str, list] = {}
    for (guid, method), regions in merged.items():
        # A claim lying apart from what remains of the face takes nothing (the room above a
        # face claims along its top edge at most): its costly overlays are skipped.
        if remaining.is_empty or all(boxes_apart(remaining, region) for region in regions):
            continue
        claim = Claim(guid, method, shapely.union_all(regions))
        piece = shapely.union_all(polygons(remaining.intersection(claim.region, grid_size=grid)))
        if piece.area <= grid:
            continue
        remaining = remaining.difference(piece, grid_size=grid)
        if claim.space_guid in parts:
            parts[claim.space_guid][0] = parts[claim.space_guid][0].union(piece, grid_size=grid)
        else:
            parts[claim.space_guid] = [piece, claim]
    leftovers = polygons(remaining)
    if not leftovers:
        return [(region, claim) for region, claim in parts.values()]
    # Unclaimed area (a slab edge above two rooms) is cut where the sections' sides are, so
    # that each piece goes to the room it continues.
    cuts = np.unique([x for region, _ in parts.values() for p in polygons(region) for x in p.bounds[0::2]])
    pieces = []
    for leftover in leftovers:
        u0, v0, u1, v1 = leftover.bounds
        inner = cuts[(cuts > u0 + grid) & (cuts < u1 - grid)]
        edges = [u0 - 1, *inner, u1 + 1]
        pieces += [piece for a, b in zip(edges, edges[1:]) for piece in polygons(
            leftover.intersection(shapely.box(a, v0 - 1, b, v1 + 1), grid_size=grid))] if len(inner) else [leftover]
    # The border a piece shares with a part, as the area of the piece within 2 grid of it; a
    # part's grown region is only made for a piece near it (the others share 0).
    grown = {}
    merged_pieces = {guid: [] for guid in parts}
    unclaimed = []
    for leftover in pieces:
        if leftover.area < grid * grid:
            continue  # a sliver left by rounding
        shared = {}
        for guid, (region, _) in parts.items():
            if boxes_apart(leftover, region, 3 * grid):
                shared[guid] = 0.0
                continue
            if guid not in grown:
                grown[guid] = region.buffer(2 * grid)
            shared[guid] = overlap_area(leftover, grown[guid])
        best = max(shared, key=shared.get, default=None)
        if best is not None and shared[best] > 0:
            merged_pieces[best].append(leftover)
        else:
            unclaimed.append(leftover)
    for guid, extra in merged_pieces.items():
        if extra:
            parts[guid][0] = shapely.union_all([parts[guid][0], *extra], grid_size=grid)
    out = [(region, claim) for region, claim in parts.values()]
    if unclaimed:
        out.append((shapely.union_all(unclaimed, grid_size=grid), None))
    return out
