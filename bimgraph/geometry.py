"""Pure maths on poses and planes, in numpy. No I/O, no gtsam.

Poses are 4x4 homogeneous matrices named by their frames: `T_A_B` maps points from B into A.
Planes are arrays `(nx, ny, nz, d)` with `|n| = 1` and `n . x + d = 0` (gtsam's OrientedPlane3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros((4, 4))  # (np.eye costs more than the rest: poses are made per keyframe and landmark)
    T[:3, :3] = R
    T[:3, 3] = t
    T[3, 3] = 1.0
    return T


def inverse(T_A_B: np.ndarray) -> np.ndarray:
    """T_B_A from T_A_B, without a general matrix inverse."""
    R = T_A_B[:3, :3]
    return make_pose(R.T, -R.T @ T_A_B[:3, 3])


def pose_from_tum(values) -> np.ndarray:
    """`tx ty tz qx qy qz qw` (TUM order, Hamilton quaternion) to a 4x4 pose."""
    v = np.asarray(values, dtype=float)
    # spelled out: scipy's Rotation costs 10x more, and the backend parses a pose per keyframe
    x, y, z, w = (v[3:7] / np.sqrt(v[3:7] @ v[3:7])).tolist()
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    return make_pose(R, v[:3])


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """A 4x4 pose to `tx ty tz qx qy qz qw`, with qw >= 0 so that files are canonical."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([T[:3, 3], q])


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """Pose from a 6-vector (rotation vector, translation), rotation applied first: the
    ordering of gtsam's Pose3 tangent space, with translation not coupled to rotation."""
    return make_pose(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])


def normalise_plane(plane) -> np.ndarray:
    """Scale all four coefficients so that |n| = 1 (gtsam normalises n but not d)."""
    p = np.asarray(plane, dtype=float)
    return p / np.linalg.norm(p[:3])


def plane_to_frame(plane_A: np.ndarray, T_A_B: np.ndarray) -> np.ndarray:
    """The plane given in A expressed in B (`OrientedPlane3.transform(T_A_B)`)."""
    n_A, d_A = plane_A[:3], plane_A[3]
    R, t = T_A_B[:3, :3], T_A_B[:3, 3]
    return np.concatenate([R.T @ n_A, [d_A + n_A @ t]])


def plane_from_frame(plane_B: np.ndarray, T_A_B: np.ndarray) -> np.ndarray:
    """The plane given in B expressed in A (inverse of `plane_to_frame`)."""
    return plane_to_frame(plane_B, inverse(T_A_B))


def normal_angle_deg(n1: np.ndarray, n2: np.ndarray):
    """Angle between two unit normals in degrees; oriented, so opposite normals give 180.
    `n1` may be a stack of normals (N x 3): then an array, an angle for each."""
    angle = np.degrees(np.arccos(np.clip(np.dot(n1, n2), -1.0, 1.0)))
    return float(angle) if np.ndim(angle) == 0 else angle


def point_plane_distance(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Signed distance of each point (N x 3, or 3) to the plane; positive on the normal's side."""
    return np.asarray(points) @ plane[:3] + plane[3]


def rotation_angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def rotation_from_correlation(H: np.ndarray) -> np.ndarray | None:
    """The rotation R maximising sum(b . R a) given `H = sum(a b^T)` (Kabsch); None when the
    vectors span less than a plane, so that a rotation about them is left free."""
    U, s, Vt = np.linalg.svd(H)
    if s[1] <= 1e-6 * max(s[0], 1e-12):
        return None
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def least_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        return np.eye(3)
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """3 x 2: two orthonormal in-plane directions; for a vertical plane the first is
    horizontal and the second points up. (Not gtsam's Unit3 basis: use that one for tangent
    spaces and covariances.)"""
    nx, ny, nz = (float(v) for v in normal)
    # Written out: np.cross costs more than the rest of the per-detection work.
    u = np.array([-ny, nx, 0.0]) if abs(nz) < 0.9 else np.array([-nz, 0.0, nx])
    u /= np.sqrt(u @ u)
    v = np.array([ny * u[2] - nz * u[1], nz * u[0] - nx * u[2], nx * u[1] - ny * u[0]])
    return np.column_stack([u, v])


def plane_frame(plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(origin, basis) of the plane's own 2-D frame: p = origin + basis @ xy, the origin
    being the plane's foot point."""
    plane = np.asarray(plane, dtype=float)
    return -plane[3] * plane[:3], plane_basis(plane[:3])


def plane_shape(plane: np.ndarray, polygon, holes=()):
    """A planar 3-D polygon with holes as a shapely Polygon in the plane's 2-D frame
    (`plane_frame`); `buffer(0)` repairs holes that touch the outline (doors at floor level)."""
    import shapely

    origin, basis = plane_frame(plane)
    return shapely.Polygon((np.asarray(polygon, dtype=float) - origin) @ basis,
                           [(np.asarray(h, dtype=float) - origin) @ basis for h in holes]).buffer(0)


def sigmas_in_B(T_B_S: np.ndarray, covariance) -> tuple[np.ndarray, np.ndarray]:
    """The one-sigma rotation (rad) and position (m) of `T_B_S` along B's axes, from its
    covariance in gtsam's right tangent (whose axes are S's); NaN where it has no figure (None).
    Of one pose (4x4, 6x6: two 3-vectors) or of a stack of them (n x 4 x 4, n x 6 x 6)."""
    cov = np.asarray(covariance, dtype=float)  # (None becomes NaN)
    R = np.asarray(T_B_S)[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    return tuple(np.sqrt(np.diagonal(R @ cov[..., block, block] @ Rt, axis1=-2, axis2=-1))
                 for block in (slice(0, 3), slice(3, 6)))
