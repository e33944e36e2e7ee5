"""A 2-D occupancy grid of one storey: where a person carrying the camera can walk.

Obstacles are the mesh sliced at a few heights between the floor and head height. "Inside" is
over the storey's floor slabs, or for a model without slabs what the planned walls enclose
once their doors are closed, so that the exterior never counts as free space even where an
outside door opens onto it.
Pure computation: no files.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull

from bimgraph.bim.planemap import BimFace
from bimgraph.sim.world import Mesh

# Heights above the floor at which the walls are sliced: knee, waist, chest, head. Low
# enough to catch window sills and boxes, below the door heads.
SLICE_HEIGHTS_M = (0.15, 0.5, 1.0, 1.5, 1.9)
# Telling inside from outside: openings up to these widths are closed in turn (doors first)
# on a grid of INSIDE_CELL_M until the enclosed area is INSIDE_HULL_SHARE of the walls' hull.
OPENING_CLOSE_M = (2.0, 4.0, 8.0)
INSIDE_CELL_M = 0.2
INSIDE_HULL_SHARE = 0.7


@dataclass
class Grid:
    origin: np.ndarray  # xy of cell (0, 0)'s centre
    cell: float
    shape: tuple[int, int]  # (nx, ny)

    @classmethod
    def around(cls, xy: np.ndarray, cell: float, margin: float = 1.0) -> "Grid":
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        shape = tuple(int(v) for v in np.ceil((hi - lo) / cell).astype(int) + 1)
        return cls(lo, cell, shape)

    def index(self, xy: np.ndarray) -> np.ndarray:
        """Cell indices (..., 2) of points, clipped into the grid."""
        ij = np.round((np.asarray(xy) - self.origin) / self.cell).astype(int)
        return np.clip(ij, 0, np.array(self.shape) - 1)

    def centre(self, flat: int) -> np.ndarray:
        """The xy of one cell's centre, by its flat index."""
        return self.origin + self.cell * np.array(np.unravel_index(flat, self.shape))

    def lookup(self, mask: np.ndarray, xy: np.ndarray) -> np.ndarray:
        ij = self.index(xy)
        return mask[ij[..., 0], ij[..., 1]]


def slice_mesh(mesh: Mesh, z: float) -> np.ndarray:
    """Segments (S x 2 x 2, xy) where the mesh crosses the horizontal plane at z."""
    tri = mesh.vertices[mesh.triangles]  # T x 3 x 3
    s = tri[:, :, 2] - z
    segments = []
    for a, b in [(0, 1), (1, 2), (2, 0)]:
        crosses = (s[:, a] * s[:, b]) < 0
        t = s[crosses, a] / (s[crosses, a] - s[crosses, b])
        p = tri[crosses, a, :2] + t[:, None] * (tri[crosses, b, :2] - tri[crosses, a, :2])
        point = np.full((len(tri), 2), np.nan)
        point[crosses] = p
        segments.append(point)
    pts = np.stack(segments, axis=1)  # T x 3 x 2, two of three finite where the plane cuts
    ok = np.isfinite(pts[:, :, 0]).sum(axis=1) == 2
    pairs = [row[np.isfinite(row[:, 0])] for row in pts[ok]]
    return np.array(pairs).reshape(-1, 2, 2)


def rasterise(grid: Grid, segments: np.ndarray) -> np.ndarray:
    """Cells touched by the segments (sampled at a third of a cell)."""
    occupied = np.zeros(grid.shape, dtype=bool)
    if len(segments) == 0:
        return occupied
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    counts = np.ceil(lengths / (grid.cell / 3.0)).astype(int) + 1
    seg = np.repeat(np.arange(len(segments)), counts)
    t = np.concatenate([np.linspace(0.0, 1.0, c) for c in counts])
    points = segments[seg, 0] + t[:, None] * (segments[seg, 1] - segments[seg, 0])
    ij = grid.index(points)
    occupied[ij[:, 0], ij[:, 1]] = True
    return occupied


def obstacles(grid: Grid, mesh: Mesh, floor_z: float) -> np.ndarray:
    occupied = np.zeros(grid.shape, dtype=bool)
    for h in SLICE_HEIGHTS_M:
        occupied |= rasterise(grid, slice_mesh(mesh, floor_z + h))
    return occupied


def _over(grid: Grid, floors: list[BimFace]) -> np.ndarray:
    """Cells whose centre lies on one of the (horizontal) faces, minus their holes."""
    mask = np.zeros(grid.shape[::-1], dtype=np.uint8)  # cv2 images are rows (y) x columns (x)

    def fill(ring, value):
        xy = np.round((np.asarray(ring)[:, :2] - grid.origin) / grid.cell).astype(np.int32)
        cv2.fillPoly(mask, [xy], value)

    for face in floors:
        fill(face.polygon, 1)
        for hole in face.holes:
            fill(hole, 0)
    return mask.T.astype(bool)


def _enclosed(walls_2d: np.ndarray, radius: int) -> np.ndarray:
    """Cells not reachable from the border once gaps up to 2 `radius` cells are closed."""
    disk = np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius
    closed = ndimage.binary_closing(np.pad(walls_2d, radius + 1), structure=disk)[radius + 1:-radius - 1, radius + 1:-radius - 1]
    regions, _ = ndimage.label(~closed)
    border = np.unique(np.concatenate([regions[0], regions[-1], regions[:, 0], regions[:, -1]]))
    return ~np.isin(regions, border[border > 0])


def inside(grid: Grid, walls: Mesh, floor_z: float, floors: list[BimFace] = ()) -> np.ndarray:
    """Cells over the storey's floor slabs when the model has them. Else cells enclosed by the
    walls: not reachable from the grid's border once the openings are closed. Doors close at
    the first try; a model whose facades are missing (curtain walls are not wall faces) needs
    wider closing, tried until the enclosed area is a fair share of the walls' convex hull."""
    walls_2d = obstacles(grid, walls, floor_z)
    if floors:
        return _over(grid, floors) & ~walls_2d
    factor = max(1, int(round(INSIDE_CELL_M / grid.cell)))
    pad = (-np.array(walls_2d.shape)) % factor
    coarse = np.pad(walls_2d, [(0, pad[0]), (0, pad[1])])
    coarse = coarse.reshape(coarse.shape[0] // factor, factor, coarse.shape[1] // factor, factor).any(axis=(1, 3))
    points = np.argwhere(coarse)
    hull_cells = ConvexHull(points).volume if len(points) >= 3 else 0.0
    for width in OPENING_CLOSE_M:
        enclosed = _enclosed(coarse, int(np.ceil(width / 2 / (grid.cell * factor))))
        if enclosed.sum() >= INSIDE_HULL_SHARE * hull_cells:
            break
    fine = np.repeat(np.repeat(enclosed, factor, axis=0), factor, axis=1)
    return fine[:walls_2d.shape[0], :walls_2d.shape[1]] & ~walls_2d


def walkable(distance: np.ndarray, inside_mask: np.ndarray, clearance: float) -> np.ndarray:
    """Cells inside, at least `clearance` from any obstacle, in the largest connected region."""
    free = inside_mask & (distance >= clearance)
    labels, count = ndimage.label(free, structure=np.ones((3, 3)))
    if count == 0:
        return free
    sizes = np.bincount(labels.ravel())[1:]  # (ndimage.sum's per-label sum took five times as long)
    return labels == (1 + int(np.argmax(sizes)))


def free_space(occupied: np.ndarray, inside_mask: np.ndarray, cell: float, clearance: float):
    """(free, distance): the walkable cells, and every cell's distance to the nearest
    obstacle in metres."""
    distance = ndimage.distance_transform_edt(~occupied) * cell
    return walkable(distance, inside_mask, clearance), distance


def add_obstacle(distance: np.ndarray, footprint: np.ndarray, cell: float, reach: float) -> np.ndarray:
    """The distance field once `footprint` is occupied too, recomputed only within `reach`
    of it (farther cells cannot come closer than `reach` to it)."""
    rows, cols = np.flatnonzero(footprint.any(axis=1)), np.flatnonzero(footprint.any(axis=0))
    if len(rows) == 0:
        return distance
    pad = int(np.ceil(reach / cell)) + 1
    lo = np.maximum(np.array([rows[0], cols[0]]) - pad, 0)
    hi = np.minimum(np.array([rows[-1], cols[-1]]) + pad + 1, footprint.shape)
    window = (slice(lo[0], hi[0]), slice(lo[1], hi[1]))
    local = ndimage.distance_transform_edt(~footprint[window]) * cell
    out = distance.copy()
    out[window] = np.minimum(distance[window], local)
    return out
