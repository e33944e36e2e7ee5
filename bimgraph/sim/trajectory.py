"""The camera path: a person walking from waypoint to waypoint through the free space of a
storey, looking around as they go, sometimes turning once around on the spot.

Paths are shortest paths on the occupancy grid's free cells, weighted to keep away from walls,
so they go through doors and never through a wall; keyframes are picked from the dense path
every `keyframe_distance_m` of travel or `keyframe_angle_deg` of rotation. Pure computation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.csgraph import dijkstra
from scipy.spatial.transform import Rotation

from bimgraph.config import TrajectoryConfig
from bimgraph.errors import InputError
from bimgraph.geometry import make_pose
from bimgraph.sim.occupancy import Grid

# Camera at yaw = pitch = roll = 0 looks along +x of B, level: OpenCV axes x right (-y of B),
# y down (-z), z forward (+x).
R_B_C_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# The dense path turns on the spot in steps of this angle.
TURN_STEP_DEG = 2.0
# The walking direction is smoothed over this distance, so that the view does not snap at
# the grid's 45-degree corners.
HEADING_SMOOTHING_M = 1.0
# Waypoints are picked from this many candidate cells at a time.
_WAYPOINT_BLOCK = 1024


@dataclass
class Trajectory:
    stamps: np.ndarray  # N
    T_B_C: np.ndarray  # N x 4 x 4
    distance_m: float  # travelled between the first and last keyframe


def camera_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """R_B_C of a camera heading `yaw` about B's z, looking `pitch` up, rolled `roll` (radians)."""
    R_yaw = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
    R_head = Rotation.from_euler("xz", [pitch, roll]).as_matrix()  # about C's x, then its z
    return R_yaw @ R_B_C_LEVEL @ R_head


class _Planner:
    """Shortest paths over the free cells, costlier near obstacles."""

    def __init__(self, free: np.ndarray, distance: np.ndarray, clearance: float, cell: float):
        self.cells = np.argwhere(free)
        node = -np.ones(free.shape, dtype=int)
        node[tuple(self.cells.T)] = np.arange(len(self.cells))
        self.node = node
        rows, cols, weights = [], [], []
        for di, dj in [(1, 0), (0, 1), (1, 1), (1, -1)]:
            a = self.cells
            b = a + [di, dj]
            ok = (b[:, 0] >= 0) & (b[:, 0] < free.shape[0]) & (b[:, 1] >= 0) & (b[:, 1] < free.shape[1])
            a, b = a[ok], b[ok]
            nb = node[b[:, 0], b[:, 1]]
            ok = nb >= 0
            a, b, nb = a[ok], b[ok], nb[ok]
            d_mid = 0.5 * (distance[tuple(a.T)] + distance[tuple(b.T)])
            rows.append(node[tuple(a.T)])
            cols.append(nb)
            weights.append(cell * np.hypot(di, dj) * (1.0 + clearance / d_mid))
        n = len(self.cells)
        self.graph = sparse.coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                                       shape=(n, n)).tocsr()
        self.cell = cell
        self.longest = float(self.graph.sum())

    def path(self, start: int, goal: int) -> np.ndarray:
        """Cells (K x 2) from node `start` to node `goal`."""
        # The search stops at a cost bound, doubled until it reaches the goal: legs go to a
        # near waypoint, and searching the whole storey for each took 0.2 s on a floor of 128
        # rooms. No path costs less than the straight line (every weight is at least the
        # step's length); none costs more than every edge together.
        bound = 2.0 * self.cell * float(np.hypot(*(self.cells[goal] - self.cells[start]))) + self.cell
        while True:
            cost, pred = dijkstra(self.graph, directed=False, indices=start, return_predecessors=True, limit=bound)
            if np.isfinite(cost[goal]) or bound >= self.longest:
                break
            bound *= 2.0
        if pred[goal] < 0 and goal != start:
            return self.cells[[start]]
        nodes = [goal]
        while nodes[-1] != start:
            nodes.append(pred[nodes[-1]])
        return self.cells[nodes[::-1]]


def waypoints(free: np.ndarray, distance: np.ndarray, grid: Grid, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Cells spread over the free space, at least `spacing` apart, drawn towards room middles."""
    cells = np.argwhere(free)
    weight = distance[tuple(cells.T)] ** 2
    order = rng.choice(len(cells), size=len(cells), replace=False, p=weight / weight.sum())
    radius = int(np.ceil(spacing / grid.cell))
    di, dj = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    disk = np.hypot(di, dj) * grid.cell < spacing
    blocked = np.zeros((free.shape[0] + 2 * radius, free.shape[1] + 2 * radius), dtype=bool)
    # each cell in that order is taken unless one taken before blocks it: the next one free is
    # looked for a block of cells at a time (one by one, the loop took 1.5 s over a floor of
    # 128 rooms)
    candidates, chosen, start = cells[order], [], 0
    while start < len(candidates):
        block = candidates[start:start + _WAYPOINT_BLOCK]
        free_now = ~blocked[block[:, 0] + radius, block[:, 1] + radius]
        if not free_now.any():
            start += len(block)
            continue
        first = int(np.argmax(free_now))
        i, j = block[first]
        chosen.append((i, j))
        blocked[i:i + 2 * radius + 1, j:j + 2 * radius + 1] |= disk
        start += first + 1
    return np.array(chosen)


def _resample(points: np.ndarray, step: float) -> np.ndarray:
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] < step:
        return points[[0, -1]] if s[-1] > 0 else points[:1]
    t = np.append(np.arange(0.0, s[-1] - step / 2, step), s[-1])
    return np.column_stack([np.interp(t, s, points[:, k]) for k in range(points.shape[1])])


def _smooth(points: np.ndarray, window: int) -> np.ndarray:
    """Moving average that fades out towards both ends, so that a leg still starts and ends
    exactly on its waypoints and consecutive legs join without a jump."""
    smoothed = ndimage.uniform_filter1d(points, window, axis=0, mode="nearest")
    k = np.arange(len(points))
    alpha = np.clip(np.minimum(k, len(points) - 1 - k) / max(window / 2, 1), 0.0, 1.0)[:, None]
    return (1 - alpha) * points + alpha * smoothed


def _turn(yaw_from: float, yaw_to: float) -> np.ndarray:
    """Yaw angles of an on-the-spot turn, the short way round, excluding `yaw_from`."""
    delta = (yaw_to - yaw_from + np.pi) % (2 * np.pi) - np.pi
    steps = int(np.ceil(abs(np.degrees(delta)) / TURN_STEP_DEG))
    return yaw_from + delta * np.arange(1, steps + 1) / max(steps, 1)


def plan_trajectory(free: np.ndarray, distance: np.ndarray, grid: Grid, floor_z: float, cfg: TrajectoryConfig,
                    n_keyframes: int, rng: np.random.Generator) -> Trajectory:
    """`n_keyframes` keyframe poses T_B_C walking through the free cells."""
    if not free.any():
        raise InputError("no free space to walk in: the storey has no enclosed room wide enough for the clearance")
    planner = _Planner(free, distance, cfg.clearance_m, grid.cell)
    stops = waypoints(free, distance, grid, cfg.waypoint_spacing_m, rng)
    stop_nodes = planner.node[tuple(stops.T)]
    phase = rng.uniform(0.0, 2 * np.pi, size=4)
    window = max(1, int(round(cfg.smoothing_m / grid.cell)))
    heading_window = max(1, int(round(HEADING_SMOOTHING_M / cfg.step_m)))

    # Dense samples: position xy, yaw, walked distance (drives the look-around), time.
    xy_all, yaw_all, s_all, t_all = [], [], [], []
    current = int(rng.integers(len(stops)))
    unvisited = set(range(len(stops))) - {current}
    keyframes: list[int] = []
    R_last = p_last = None
    s_walked, stamp, yaw = 0.0, 0.0, None
    cos_angle = np.cos(np.radians(cfg.keyframe_angle_deg))

    def emit(xy, yaw_value):
        nonlocal stamp, s_walked, R_last, p_last
        if xy_all:
            step = float(np.hypot(*(xy - xy_all[-1])))
            turn = abs((yaw_value - yaw_all[-1] + np.pi) % (2 * np.pi) - np.pi)
            s_walked += step
            stamp += max(step / cfg.speed_m_s, np.degrees(turn) / cfg.turn_rate_deg_s)
        xy_all.append(xy)
        yaw_all.append(yaw_value)
        s_all.append(s_walked)
        t_all.append(stamp)
        R, p = pose_at(len(xy_all) - 1)
        if R_last is None or np.linalg.norm(p - p_last) >= cfg.keyframe_distance_m or \
                (np.trace(R_last.T @ R) - 1) / 2 <= cos_angle:
            keyframes.append(len(xy_all) - 1)
            R_last, p_last = R, p

    def look(i):
        s = s_all[i]
        sweep = np.radians(cfg.sweep_deg) * np.sin(2 * np.pi * s / cfg.sweep_period_m + phase[0])
        pitch = np.radians(cfg.pitch_mean_deg + cfg.pitch_deg * np.sin(2 * np.pi * s / (0.71 * cfg.sweep_period_m) + phase[1]))
        roll = np.radians(cfg.roll_deg) * np.sin(2 * np.pi * s / (0.37 * cfg.sweep_period_m) + phase[2])
        mid, amp = (cfg.height_min_m + cfg.height_max_m) / 2, (cfg.height_max_m - cfg.height_min_m) / 2
        height = mid + amp * np.sin(2 * np.pi * s / (2.3 * cfg.sweep_period_m) + phase[3])
        return sweep, pitch, roll, height

    def pose_at(i):
        sweep, pitch, roll, height = look(i)
        R = camera_rotation(yaw_all[i] + sweep, pitch, roll)
        return R, np.array([*xy_all[i], floor_z + height])

    while len(keyframes) < n_keyframes:
        if not unvisited:
            unvisited = set(range(len(stops))) - {current}
            if not unvisited:
                raise InputError("the free space is too small for a walk: fewer than two waypoints")
        candidates = sorted(unvisited, key=lambda k: (np.hypot(*(stops[k] - stops[current])), k))[:3]
        goal = candidates[int(rng.integers(len(candidates)))]
        unvisited.discard(goal)
        cells = planner.path(stop_nodes[current], stop_nodes[goal])
        current = goal
        if len(cells) < 2:
            continue
        points = _resample(_smooth(grid.origin + cells * grid.cell, window), cfg.step_m)
        if len(points) < 2:
            continue
        d = np.gradient(points, axis=0)
        d = ndimage.uniform_filter1d(d, heading_window, axis=0, mode="nearest")
        headings = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        if yaw is not None:
            for y in _turn(yaw, headings[0]):
                emit(points[0], y)
        for xy, y in zip(points, headings):
            emit(xy, y)
        yaw = headings[-1]
        if rng.random() < cfg.spin_probability:
            direction = rng.choice([-1.0, 1.0])
            for y in yaw + direction * np.radians(np.arange(TURN_STEP_DEG, 360.0 + 1e-9, TURN_STEP_DEG)):
                emit(points[-1], y)
            yaw = yaw_all[-1]

    keyframes = keyframes[:n_keyframes]
    poses = np.array([make_pose(*pose_at(i)) for i in keyframes])
    stamps = np.array(t_all)[keyframes]
    travelled = float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())
    return Trajectory(stamps=stamps, T_B_C=poses, distance_m=travelled)
