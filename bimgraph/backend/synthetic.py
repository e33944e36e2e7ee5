"""A small synthetic world for the backend's tests and benchmark: a grid of box rooms (each
wall side a face of the plane map), a camera walking room by room, plane observations with
noise, and a drifting front-end. Exact ground truth, no rendering; the simulator
(`bimgraph simulate`) is the realistic one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.backend.alignment import Alignment
from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.geometry import exp_se3, inverse, make_pose, plane_to_frame, pose_to_tum
from bimgraph.sequence.format import Keyframe, PlaneObservation

# camera axes (x right, y down, z forward) for a camera looking along +x of B with z up
_R_B_C0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass
class Scene:
    plane_map: PlaneMap
    keyframes: list[Keyframe]
    truth: dict[tuple[int, int], str | None]  # (keyframe, observation) -> face id
    T_B_S: np.ndarray
    T_B_C: list[np.ndarray]
    initial: Alignment


def room_faces(rooms_x: int, rooms_y: int, size=(5.0, 4.0), height=3.0, wall=0.2, only_y_walls=False) -> list[BimFace]:
    faces = []
    w, d = size
    for ix in range(rooms_x):
        for iy in range(rooms_y):
            x0, y0 = ix * (w + wall), iy * (d + wall)
            x1, y1 = x0 + w, y0 + d
            sides = [("S", (0, 1, 0), [(x0, y0), (x1, y0)]), ("N", (0, -1, 0), [(x1, y1), (x0, y1)])]
            if not only_y_walls:
                sides += [("W", (1, 0, 0), [(x0, y1), (x0, y0)]), ("E", (-1, 0, 0), [(x1, y0), (x1, y1)])]
            for name, n, ((ax, ay), (bx, by)) in sides:
                poly = [(ax, ay, 0.0), (bx, by, 0.0), (bx, by, height), (ax, ay, height)]
                offset = -float(np.dot(n, poly[0]))
                faces.append(BimFace(id=f"r{ix}{iy}{name}", wall_guid=f"w{ix}{iy}{name}", normal=n, offset=offset,
                                     polygon=poly))
    return faces


def _observe(face: BimFace, T_B_C: np.ndarray, rng, normal_sigma: float, offset_sigma: float, window: float):
    """The face seen from the camera: its plane in C with noise, and the part of it within
    `window` metres (horizontally) of the point the camera looks at."""
    plane_C = plane_to_frame(face.plane, T_B_C)
    if plane_C[3] <= 0.3:
        return None
    centre_C = np.asarray(face.centre) @ T_B_C[:3, :3] - T_B_C[:3, :3].T @ T_B_C[:3, 3]
    if centre_C[2] <= 0 or np.degrees(np.arctan2(np.linalg.norm(centre_C[:2]), centre_C[2])) > 55 or plane_C[3] > 7:
        return None
    poly_B = np.asarray(face.polygon)
    along = poly_B[1] - poly_B[0]
    length = np.linalg.norm(along)
    along /= length
    foot = T_B_C[:3, 3] - face.plane[:3] * (face.plane[:3] @ T_B_C[:3, 3] + face.plane[3])
    s = np.clip((foot - poly_B[0]) @ along, 0, length)
    a, b = max(0.0, s - window), min(length, s + window)
    if b - a < 0.5:
        return None
    corners_B = np.array([poly_B[0] + a * along, poly_B[0] + b * along, poly_B[0] + b * along + poly_B[3] - poly_B[0],
                          poly_B[0] + a * along + poly_B[3] - poly_B[0]])
    corners_C = (corners_B - T_B_C[:3, 3]) @ T_B_C[:3, :3]
    noisy_n = Rotation.from_rotvec(rng.normal(size=3) * normal_sigma).apply(plane_C[:3])
    noisy = np.array([*noisy_n, plane_C[3] + rng.normal() * offset_sigma])
    cov = np.diag([normal_sigma**2, normal_sigma**2, offset_sigma**2])
    return PlaneObservation(n=tuple(noisy[:3]), d=float(noisy[3]), cov=cov.tolist(),
                            polygon=[tuple(p) for p in corners_C], area=float((b - a) * np.linalg.norm(poly_B[3] - poly_B[0])))


def make_scene(n_keyframes: int = 200, rooms=(2, 2), seed: int = 0, only_y_walls: bool = False,
               normal_sigma_deg: float = 0.5, offset_sigma_m: float = 0.01, drift_rot_deg: float = 0.05,
               drift_trans_m: float = 0.003, initial_error=(2.0, 0.15), floor: bool = True) -> Scene:
    """Rooms of 5 x 4 m; the camera circles in each room (turning to face every wall), then
    moves to the next, `n_keyframes` in all. `only_y_walls` makes a corridor-like world whose
    faces all have normals +-y."""
    rng = np.random.default_rng(seed)
    faces = room_faces(*rooms, only_y_walls=only_y_walls)
    plane_map = PlaneMap(faces=faces)
    n_rooms = rooms[0] * rooms[1]
    per_room = max(1, n_keyframes // n_rooms)
    T_B_S = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), np.array([2.0, 1.0, 0.0]))
    T_S_B = inverse(T_B_S)
    rot_sigma, trans_sigma = np.radians(drift_rot_deg), drift_trans_m
    keyframes, truth, T_B_C_true = [], {}, []
    T_S_C_frontend = None
    previous_true = None
    for k in range(n_keyframes):
        room = min(k // per_room, n_rooms - 1)
        ix, iy = room // rooms[1], room % rooms[1]
        if ix % 2:
            iy = rooms[1] - 1 - iy  # snake
        centre = np.array([ix * 5.2 + 2.5, iy * 4.2 + 2.0, 1.5])
        phase = 2 * np.pi * (k % per_room) / per_room
        position = centre + np.array([1.2 * np.cos(phase), 0.9 * np.sin(phase), 0.1 * np.sin(3 * phase)])
        yaw = phase * 1.5 + 0.3 * np.sin(5 * phase)
        R_B_C = Rotation.from_euler("zx", [yaw, np.radians(-5.0)]).as_matrix() @ _R_B_C0
        T_B_C = make_pose(R_B_C, position)
        T_B_C_true.append(T_B_C)
        T_S_C_true = T_S_B @ T_B_C
        if T_S_C_frontend is None:
            T_S_C_frontend = T_S_C_true
        else:
            step = inverse(previous_true) @ T_S_C_true
            noise = exp_se3(np.concatenate([rng.normal(size=3) * rot_sigma, rng.normal(size=3) * trans_sigma]))
            T_S_C_frontend = T_S_C_frontend @ step @ noise
        previous_true = T_S_C_true
        planes = []
        for face in faces:
            if not face.id.startswith(f"r{ix}{iy}"):
                continue  # walls hide the other rooms
            obs = _observe(face, T_B_C, rng, np.radians(normal_sigma_deg), offset_sigma_m, 2.0)
            if obs is not None:
                truth[(k, len(planes))] = face.id
                planes.append(obs)
        if floor:  # the floor, not in the plane map
            plane_C = plane_to_frame(np.array([0.0, 0.0, 1.0, 0.0]), T_B_C)
            planes.append(PlaneObservation(n=tuple(plane_C[:3]), d=float(plane_C[3]),
                                           cov=np.diag([np.radians(normal_sigma_deg) ** 2] * 2 + [offset_sigma_m**2]).tolist()))
            truth[(k, len(planes) - 1)] = None
        cov = np.diag([rot_sigma**2] * 3 + [trans_sigma**2] * 3)
        keyframes.append(Keyframe(index=k, stamp=0.1 * k, T_S_C=tuple(pose_to_tum(T_S_C_frontend)),
                                  cov=cov.tolist(), planes=planes))
    err = exp_se3(np.array([0, 0, np.radians(initial_error[0]), initial_error[1], -initial_error[1] * 0.5, 0.0]))
    initial = Alignment.from_sigmas(T_B_S @ err, 2.0, 0.2)
    return Scene(plane_map, keyframes, truth, T_B_S, T_B_C_true, initial)
