"""Synthetic inputs with known answers for the deviation tests: one 6 x 4 m room, its four
wall faces as planned, and landmarks built from as-built planes of known offset and tilt."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.deviations.estimate import JOINT_DIM, ObservedPlane
from bimgraph.geometry import make_pose, plane_from_frame, plane_to_frame

HEIGHT = 2.5
# Room x in [0, 6], y in [0, 4]; normals point into the room.
WALLS = {
    "south": ((0, 1, 0), 0.0, [(0, 0), (6, 0)]),
    "east": ((-1, 0, 0), 6.0, [(6, 0), (6, 4)]),
    "north": ((0, -1, 0), 4.0, [(6, 4), (0, 4)]),
    "west": ((1, 0, 0), 0.0, [(0, 4), (0, 0)]),
}
GUIDS = {"south": "2O2Fr$t4X7Zf8NOew3FLOH", "east": "1hOSvn6df7F8_7GcBWlRGQ",
         "north": "0ljFzd$Mv0ARRrzD5_PhzE", "west": "3Wk7_bYxz1lvdbcNw$cb1j"}

T_S_B = make_pose(Rotation.from_euler("zyx", [35.0, 1.0, -2.0], degrees=True).as_matrix(), [1.2, -0.7, 0.3])
T_S_A = make_pose(Rotation.from_euler("zyx", [-60.0, 3.0, 80.0], degrees=True).as_matrix(), [2.0, 1.0, 1.4])


def face(name: str, z0: float = 0.0) -> BimFace:
    n, d, ((x0, y0), (x1, y1)) = WALLS[name]
    return BimFace(id=f"{name}-face", wall_guid=GUIDS[name], wall_name=f"Wall {name}", storey="Level 0",
                   normal=n, offset=d,
                   polygon=[(x0, y0, z0), (x1, y1, z0), (x1, y1, z0 + HEIGHT), (x0, y0, z0 + HEIGHT)])


def room() -> PlaneMap:
    return PlaneMap(source="test room", faces=[face(n) for n in WALLS])


def as_built_plane(f: BimFace, offset_m: float, tilt_deg: float = 0.0) -> np.ndarray:
    """The face moved `offset_m` along its normal and leaning by `tilt_deg` about its
    horizontal axis through the centre."""
    n = np.asarray(f.normal, dtype=float)
    axis = np.cross([0.0, 0.0, 1.0], n)
    n_built = Rotation.from_rotvec(np.radians(tilt_deg) * axis / np.linalg.norm(axis)).apply(n)
    point = np.asarray(f.centre) + offset_m * n
    return np.array([*n_built, -n_built @ point])


def observed(landmark: int, plane_B: np.ndarray, sigma: float = 1e-3, n_keyframes: int = 10,
             face_id: str | None = None, extent_B=(), area_m2: float = 0.0) -> ObservedPlane:
    """A landmark that saw `plane_B` over `extent_B` (points in B), anchored at `T_S_A`, with
    an isotropic joint covariance `sigma^2` (radians and metres alike)."""
    plane_S = plane_from_frame(plane_B, T_S_B)
    extent_S = np.asarray(extent_B, dtype=float).reshape(-1, 3) @ T_S_B[:3, :3].T + T_S_B[:3, 3]
    return ObservedPlane(landmark=landmark, plane_A=plane_to_frame(plane_S, T_S_A), T_S_A=T_S_A,
                         cov=np.eye(JOINT_DIM) * sigma**2, n_keyframes=n_keyframes, face_id=face_id,
                         extent_S=extent_S, area_m2=area_m2)


def rectangle(axis: int, value: float, lo, hi) -> np.ndarray:
    """Corners of an axis-aligned rectangle on the plane `x[axis] = value`, spanning `lo` to
    `hi` in the two other coordinates."""
    others = [i for i in range(3) if i != axis]
    corners = []
    for a, b in [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]:
        p = np.zeros(3)
        p[axis], p[others[0]], p[others[1]] = value, a, b
        corners.append(p)
    return np.array(corners)


def camera_looking(position, yaw_deg: float) -> np.ndarray:
    """T_B_C of an upright camera (OpenCV axes) at `position` looking along the yaw."""
    yaw = np.radians(yaw_deg)
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, forward)
    return make_pose(np.stack([right, down, forward], axis=1), position)

