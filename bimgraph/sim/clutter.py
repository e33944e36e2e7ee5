"""What stands in the rooms but not in the model: boxes, desks and cabinets, boards leaning
against walls, temporary partitions. All make planes that are no wall face of the model.

Each item is placed where it fits (inside, off every obstacle) and kept only if the walkable
space stays one piece of about the same size, so that clutter never closes a door.
Pure computation: no files.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.config import AsBuiltConfig
from bimgraph.sim import occupancy
from bimgraph.sim.world import UP, Element, box_elements, triangulate

# (width, depth, height) ranges in metres of the kinds of items.
ITEMS = {
    "box": ((0.3, 0.9), (0.3, 0.9), (0.3, 1.0)),
    "desk": ((1.2, 1.6), (0.6, 0.8), (0.72, 0.78)),
    "cabinet": ((0.8, 1.2), (0.4, 0.6), (1.6, 2.1)),
    "pallet": ((0.8, 1.2), (0.8, 1.2), (0.4, 1.3)),
}
BOARD = ((1.2, 2.5), (0.02, 0.04), (1.0, 2.2))
PARTITION = ((2.0, 4.0), (0.08, 0.12), (2.2, 2.6))
# Boards lean on a wall with their foot this far out.
BOARD_FOOT_M = (0.1, 0.35)
# Tries to place each item before giving it up.
TRIES = 25


def _cuts_off(free_before, free_after, near) -> bool:
    """Whether an item takes walkable cells away from anywhere but its own surroundings
    `near` (which happens when it closes a door or a passage)."""
    return bool((free_before & ~free_after & ~near).any())


def _against_wall(walls: list[Element], width: float, floor_z: float, rng):
    """(foot, R_B_O): a point on the floor at the foot of a random wall and a frame with x
    along the wall, y into the wall, z up; None where the wall is too short."""
    wall = walls[int(rng.integers(len(walls)))]
    n = wall.plane[:3]
    u = np.cross(UP, n)
    u /= np.linalg.norm(u)
    along = wall.polygon @ u
    lo, hi = along.min() + width / 2, along.max() - width / 2
    if hi <= lo:
        return None
    foot = -wall.plane[3] * n + rng.uniform(lo, hi) * u
    foot[2] = floor_z
    return foot, np.column_stack([u, -n, UP])


def _free_standing(grid: occupancy.Grid, free: np.ndarray, size, floor_z, yaws, rng):
    """(centre, R_B_O) on a random one of the `free` cells (flat indices), turned square to the
    walls or at random."""
    xy = grid.centre(free[int(rng.integers(len(free)))])
    yaw = yaws[int(rng.integers(len(yaws)))] + rng.choice([0.0, 0.0, rng.uniform(0, np.pi)])
    return np.array([*xy, floor_z + size[2] / 2]), Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()


def furnish(elements: list[Element], floor_z: float, grid: occupancy.Grid, inside_mask: np.ndarray,
            kinds: tuple[str, ...], cfg: AsBuiltConfig, clearance: float, rng: np.random.Generator) -> list[Element]:
    """Clutter, boards and partitions for the storey, as elements (none has a BIM face)."""
    walls = [e for e in elements if e.kind == "wall" and abs(e.plane[2]) < 0.1]
    occupied = occupancy.obstacles(grid, triangulate(elements), floor_z)
    floor_area = float(inside_mask.sum()) * grid.cell**2
    yaws = sorted({round(float(np.arctan2(w.plane[1], w.plane[0])), 6) for w in walls}) or [0.0]
    plan = [("partition", PARTITION)] * cfg.partitions \
        + [("board", BOARD)] * int(round(cfg.boards_per_m2 * floor_area)) \
        + [(kind, ITEMS[kind]) for kind in rng.choice(kinds, size=int(round(cfg.clutter_per_m2 * floor_area)))]
    walkable, distance = occupancy.free_space(occupied, inside_mask, grid.cell, clearance)
    reach = clearance + 2 * grid.cell
    added: list[Element] = []
    items_occupied = np.zeros_like(occupied)
    for index, (kind, ranges) in enumerate(plan):
        free = np.flatnonzero(inside_mask & ~occupied)
        for _ in range(TRIES):
            size = np.array([rng.uniform(*r) for r in ranges])
            on_wall = kind == "board" or (kind in ("cabinet", "desk") and rng.random() < 0.7)
            if on_wall:
                frame = _against_wall(walls, size[0], floor_z, rng)
                if frame is None:
                    continue
                foot, R = frame
                # A board stands with its foot out and its top on the wall; furniture stands
                # upright with its back 2 cm off the wall.
                gap = rng.uniform(*BOARD_FOOT_M) if kind == "board" else 0.02
                tilt = np.arcsin(np.clip((gap - size[1]) / size[2], 0.0, 0.5)) if kind == "board" else 0.0
                R = Rotation.from_rotvec(-tilt * R[:, 0]).as_matrix() @ R
                out = -frame[1][:, 1]
                centre = foot + gap * out + R @ [0.0, -size[1] / 2, size[2] / 2]
            elif len(free):
                centre, R = _free_standing(grid, free, size, floor_z, yaws, rng)
            else:
                break
            item = box_elements(f"{kind}/{index}", "partition" if kind == "partition" else
                                "board" if kind == "board" else "clutter", centre, size, R)
            footprint = occupancy.obstacles(grid, triangulate(item), floor_z)
            # Against a wall the footprint shares the wall's cells; elsewhere it must be clear.
            # Either way no part of it may stand outside.
            if (footprint & ~inside_mask & ~occupied).any() or (footprint & (items_occupied if on_wall else occupied)).any():
                continue
            trial_distance = occupancy.add_obstacle(distance, footprint, grid.cell, reach)
            trial_walkable = occupancy.walkable(trial_distance, inside_mask, clearance)
            near = occupancy.add_obstacle(np.full(distance.shape, np.inf), footprint, grid.cell, reach) <= reach
            if _cuts_off(walkable, trial_walkable, near):
                continue
            occupied, distance, walkable = occupied | footprint, trial_distance, trial_walkable
            items_occupied |= footprint
            added.extend(item)
            break
    return added
