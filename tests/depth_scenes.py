"""Small triangle-mesh scenes with known planes, for the depth renderer and plane extractor tests.

A room 6 m x 4 m x 2.6 m in B (z up) whose walls deviate the way as-built walls do: the east
wall has a 6 cm step half way, the north wall kinks by 6 degrees, and a cabinet stands in
it. Every face has an id and an exact plane `(n, d)` in B with n pointing into the room.
"""

from __future__ import annotations

import numpy as np

from bimgraph.geometry import make_pose
from bimgraph.sequence.format import Camera

CAMERA = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)

_KINK_DEG = 6.0
_STEP_M = 0.06


class Scene:
    def __init__(self):
        self.vertices: list[np.ndarray] = []
        self.triangles: list[list[int]] = []
        self.ids: list[int] = []
        self.planes_B: dict[int, np.ndarray] = {}

    def quad(self, face_id: int, corners, inward_normal) -> None:
        """A planar quad (corners in order around it) facing `inward_normal`."""
        corners = np.asarray(corners, dtype=float)
        n = np.asarray(inward_normal, dtype=float)
        n /= np.linalg.norm(n)
        base = len(self.vertices)
        self.vertices.extend(corners)
        self.triangles += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        self.ids += [face_id, face_id]
        self.planes_B[face_id] = np.array([*n, -n @ corners[0]])

    def box(self, first_id: int, lo, hi) -> None:
        """An axis-aligned box; its faces point outwards (the free space around it)."""
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        self.quad(first_id, [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], (0, 0, 1))
        self.quad(first_id + 1, [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)], (0, -1, 0))
        self.quad(first_id + 2, [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], (0, 1, 0))
        self.quad(first_id + 3, [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)], (-1, 0, 0))
        self.quad(first_id + 4, [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)], (1, 0, 0))

    def arrays(self):
        return np.array(self.vertices), np.array(self.triangles), np.array(self.ids)


def room() -> Scene:
    """The deviating room. Walls reach 0.5 m past the corners so that no gap shows."""
    s, h, e = Scene(), 2.6, 0.5
    s.quad(0, [(-e, -e, 0), (6 + e, -e, 0), (6 + e, 4 + e, 0), (-e, 4 + e, 0)], (0, 0, 1))  # floor
    s.quad(1, [(-e, -e, h), (6 + e, -e, h), (6 + e, 4 + e, h), (-e, 4 + e, h)], (0, 0, -1))  # ceiling
    s.quad(2, [(-e, 0, -e), (6 + e, 0, -e), (6 + e, 0, h + e), (-e, 0, h + e)], (0, 1, 0))  # south
    s.quad(3, [(0, -e, -e), (0, 4 + e, -e), (0, 4 + e, h + e), (0, -e, h + e)], (1, 0, 0))  # west
    # North wall: straight to x = 3, then turned by the kink towards the room.
    s.quad(4, [(-e, 4, -e), (3, 4, -e), (3, 4, h + e), (-e, 4, h + e)], (0, -1, 0))
    k = np.radians(_KINK_DEG)
    end = np.array([3 + 3.5 * np.cos(k), 4 - 3.5 * np.sin(k)])
    s.quad(5, [(3, 4, -e), (*end, -e), (*end, h + e), (3, 4, h + e)], (-np.sin(k), -np.cos(k), 0))
    # East wall: at x = 6 for y < 2, stepped 6 cm into the room for y > 2, with its riser.
    s.quad(6, [(6, -e, -e), (6, 2, -e), (6, 2, h + e), (6, -e, h + e)], (-1, 0, 0))
    x2 = 6 - _STEP_M
    s.quad(7, [(x2, 2, -e), (x2, 4 + e, -e), (x2, 4 + e, h + e), (x2, 2, h + e)], (-1, 0, 0))
    s.quad(8, [(x2, 2, -e), (6, 2, -e), (6, 2, h + e), (x2, 2, h + e)], (0, -1, 0))
    s.box(10, (1.0, 0.0, 0.0), (1.8, 0.5, 1.2))  # a cabinet against the south wall
    return s


def look_at(eye, target, up=(0, 0, 1)) -> np.ndarray:
    """T_B_C of a camera at `eye` looking at `target`, image x right and y down."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


def viewpoints(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """Camera poses inside the room at 1.2-1.7 m, looking at random points of the walls."""
    poses = []
    for _ in range(count):
        eye = np.array([rng.uniform(1.0, 5.0), rng.uniform(1.0, 3.2), rng.uniform(1.2, 1.7)])
        target = np.array([rng.uniform(-0.5, 6.5), rng.uniform(-0.5, 4.5), rng.uniform(0.6, 1.8)])
        if np.linalg.norm(target[:2] - eye[:2]) < 1.0:
            target[:2] = eye[:2] + np.array([1.5, 0.0])
        poses.append(look_at(eye, target))
    return poses
