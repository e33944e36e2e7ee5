"""Initial alignment of S to B and the observability of the extrinsic.

The user aligns as the paper's users do: a `T_B_S` guess with its uncertainty, or a few seed
pairs "plane detected in S <-> BIM face" solved by plane registration (rotation from the
normals in closed form, then Gauss-Newton on the plane-to-BIM residuals with the guess as a
prior, so that fewer than three independent normals never make the system singular).

A plane-to-BIM residual, seen as a function of a left perturbation (w, v) of `T_B_S` about
B's origin, moves the normal by `w x n` and the offset by `-n . v` alone. So the information
the matched faces give is `sum(I - n n^T)` on rotation and `sum(n n^T)` on translation, and a
direction is unobservable where that sum has (almost) no weight.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from bimgraph.backend.graph import E, L, X, FactorBuilder, cov_T_B_S, pose3, sigmas_cov
from bimgraph.config import BackendConfig
from bimgraph.errors import ConfigError, InputError
from bimgraph.geometry import least_rotation, make_pose, plane_to_frame, rotation_angle_deg, rotation_from_correlation

# seed pairs turning T_B_S further than this many rotation sigmas of the user's alignment are refused
_SEED_SIGMAS = 5.0
_WEAK = 1e6  # variance factor of the prior in the directions the seeds observe
# (the same in a graph whose seeds come at a later keyframe: until then, widened 1e6, the
# extrinsic's information was 1e-11 of the first pose's, and iSAM2 found it singular; at 1e2
# a hundredth of the prior's information counts where the seeds observe)
_WEAK_START = 1e2


@dataclass
class Alignment:
    """`T_B_S` and its 6x6 covariance (gtsam Pose3 tangent: rotation, then translation);
    `gravity_aligned` when S has z up, as B has. `seeds`: plane detections (keyframe index,
    plane index) the user paired with BIM faces (face ids), which the graph takes as matched;
    the covariance then holds none of their information (`seeded_start`)."""

    T_B_S: np.ndarray
    cov: np.ndarray
    unobservable: list[dict] = field(default_factory=list)
    gravity_aligned: bool = False
    seeds: dict[tuple[int, int], str] = field(default_factory=dict)
    # (with seeds: the largest sigmas, rotation in rad and translation in m, of the alignment
    # the user gave, which the directions no face observes keep)
    given_sigmas: tuple[float, float] | None = None

    def largest_sigmas(self) -> tuple[float, float]:
        """The largest sigmas (rad, m) of the alignment as the user gave it."""
        if self.given_sigmas is not None:
            return self.given_sigmas
        return float(np.sqrt(np.diag(self.cov)[:3].max())), float(np.sqrt(np.diag(self.cov)[3:].max()))

    @classmethod
    def from_sigmas(cls, T_B_S: np.ndarray, rot_deg: float, trans_m: float) -> "Alignment":
        return cls(np.asarray(T_B_S, dtype=float), sigmas_cov(np.radians(rot_deg), trans_m))


def unobservable_directions(normals_B: np.ndarray, min_angle_deg: float, gravity: bool = False) -> list[dict]:
    """Directions of `T_B_S` (rotation axes and translations, in B) that faces with these
    normals do not fix: where fewer than enough normals leave the plane orthogonal to the
    direction by at least `min_angle_deg`. With `gravity` (a gravity-aligned S), rotations
    about horizontal axes are fixed by the front-end's up direction."""
    normals_B = np.asarray(normals_B, dtype=float).reshape(-1, 3)
    weight = np.sin(np.radians(min_angle_deg)) ** 2
    info_t = normals_B.T @ normals_B
    info_r = len(normals_B) * np.eye(3) - info_t + (np.diag([1.0, 1.0, 0.0]) if gravity else 0.0)
    out = []
    for kind, info in (("rotation", info_r), ("translation", info_t)):
        values, vectors = np.linalg.eigh(info)
        for value, axis in zip(values, vectors.T):
            if value < weight:
                axis = axis * np.sign(axis[np.argmax(np.abs(axis))])
                out.append({"kind": kind, "axis_B": [float(a) for a in axis]})
    return out


def _tangent_directions(T_B_S: np.ndarray, directions: list[dict]):
    """Each direction (rotation axis or translation in B) as a vector of T_B_S's right tangent."""
    Ad = pose3(T_B_S).inverse().AdjointMap()  # left perturbation in B -> right perturbation
    for direction in directions:
        rotation = direction["kind"] == "rotation"
        xi_B = np.zeros(6)
        xi_B[(0 if rotation else 3):(3 if rotation else 6)] = direction["axis_B"]
        yield rotation, Ad @ xi_B


def lock_directions(alignment: Alignment, directions: list[dict], sigma_rot_rad: float, sigma_trans_m: float) -> np.ndarray:
    """The alignment's covariance with the given directions of `T_B_S` (as from
    `unobservable_directions`) pinned to sigma: what no face can ever observe stays where the
    user put it, instead of following model errors."""
    info = np.linalg.inv(alignment.cov)
    for rotation, u in _tangent_directions(alignment.T_B_S, directions):
        info += np.outer(u, u) / (sigma_rot_rad if rotation else sigma_trans_m) ** 2
    cov = np.linalg.inv(info)
    return 0.5 * (cov + cov.T)


def levelled(alignment: Alignment, sigma_tilt_rad: float) -> Alignment:
    """With S and B both z-up, `T_B_S` is a turn about z: the guess loses its tilt, and the
    tilt is held to the front-end's gravity error. (A hand alignment's error is mostly yaw
    and position; its tilt error would otherwise bias every wall's measured tilt.)"""
    R = alignment.T_B_S[:3, :3]
    T_B_S = make_pose(Rotation.from_rotvec([0.0, 0.0, np.arctan2(R[1, 0], R[0, 0])]).as_matrix(), alignment.T_B_S[:3, 3])
    # levelled, S's x and y axes are the tilt axes: the first two of the right tangent
    info = np.linalg.inv(alignment.cov)
    info[[0, 1], [0, 1]] += 1.0 / sigma_tilt_rad**2
    cov = np.linalg.inv(info)
    return replace(alignment, T_B_S=T_B_S, cov=0.5 * (cov + cov.T), gravity_aligned=True)


def unlocked_covariance(alignment: Alignment, directions: list[dict]) -> np.ndarray:
    """What to add to an estimate's covariance so that locked directions report the initial
    alignment's uncertainty again (they were held, not measured)."""
    sigma_rot, sigma_trans = alignment.largest_sigmas()
    extra = np.zeros((6, 6))
    for rotation, u in _tangent_directions(alignment.T_B_S, directions):
        extra += np.outer(u, u) * (sigma_rot if rotation else sigma_trans) ** 2
    return extra


def prior_beside_seeds(prior: Alignment, unobservable: list[dict], weak: float = _WEAK) -> np.ndarray:
    """The covariance of `prior` as it stands beside seed pairs that leave `unobservable`
    unobserved: it speaks only there (at its largest sigmas), so that it biases nothing the
    seeds observe (where its variance is `weak` times its own)."""
    return lock_directions(Alignment(prior.T_B_S, prior.cov * weak), unobservable, *prior.largest_sigmas())


def seeded_start(prior: Alignment, seeded: Alignment, seeds: dict[tuple[int, int], str]) -> Alignment:
    """What a graph whose `seeds` (detection -> face) are matched from the start begins with:
    the registration's `T_B_S` (`seeded`, from `align_from_seeds`), under the prior beside the
    seeds alone. The seeds' own information comes in with their plane-to-BIM factors; held in
    the start's covariance as well, it counted twice (offices 1-2 seeded with their first
    keyframe's walls ended with NEES 11.7 and 8.3), and a seed on a wall built off plan kept
    pulling the extrinsic after the robust alignment had let the wall go."""
    return Alignment(seeded.T_B_S, prior_beside_seeds(prior, seeded.unobservable, _WEAK_START), seeded.unobservable,
                     seeded.gravity_aligned, dict(seeds), prior.largest_sigmas())


def _rotation_from_normals(normals_S: np.ndarray, normals_B: np.ndarray, R_prior: np.ndarray, gravity: bool) -> np.ndarray:
    """R_B_S with R n_S ~ n_B (Kabsch); with parallel normals, the prior turned by the least
    rotation that takes its prediction of the first normal onto the observed one. With
    `gravity` (S and B both z-up), a turn about z: two walls' pairs swapped fit a rotation
    exactly, one that turns the world over."""
    if gravity:
        (sx, sy), (bx, by) = normals_S[:, :2].T, normals_B[:, :2].T
        sin, cos = float(np.sum(sx * by - sy * bx)), float(np.sum(sx * bx + sy * by))
        if np.hypot(sin, cos) < 1e-9:  # (only level planes: no heading in them)
            return R_prior
        return Rotation.from_rotvec([0.0, 0.0, np.arctan2(sin, cos)]).as_matrix()
    R = rotation_from_correlation(normals_S.T @ normals_B)
    if R is not None:
        return R
    return least_rotation(R_prior @ normals_S[0], normals_B[0]) @ R_prior


def align_from_seeds(planes_S: np.ndarray, planes_B: np.ndarray, cfg: BackendConfig,
                     prior: Alignment | None = None, centres_B: np.ndarray | None = None,
                     labels: list[str] | None = None, seen: list[tuple[np.ndarray, np.ndarray | None]] | None = None,
                     prior_given: bool = False) -> Alignment:
    """`T_B_S` from seed pairs (plane in S, BIM face plane in B, with the faces' centres if
    known), its covariance, and the directions the seeds leave unobservable (which keep the
    prior's uncertainty). `seen`: per pair, the pose `T_S_C` of the keyframe that detected the
    plane and the detection's covariance (None: the default), which the covariance then
    carries; without it the planes count as exact. A gravity-aligned prior makes it a turn about
    z. ConfigError where a pair's normals stay more than `seed_max_angle_deg` apart once turned
    (the pairs disagree: one is wrong; a single pair: its plane and face tilt differently),
    naming it by its `labels` entry; with `prior_given` (the user's alignment, not a default),
    also where the seeds turn `T_B_S` further from it than `_SEED_SIGMAS` of its rotation's
    sigma (one pair naming the wall opposite its plane turned a run 180 deg, 13 m off)."""
    planes_S, planes_B = np.asarray(planes_S, float).reshape(-1, 4), np.asarray(planes_B, float).reshape(-1, 4)
    if len(planes_S) == 0 or len(planes_S) != len(planes_B):
        raise InputError(f"seed alignment needs pairs of planes, got {len(planes_S)} and {len(planes_B)}")
    if prior is None:
        prior = Alignment.from_sigmas(np.eye(4), 180.0, 100.0)
    R = _rotation_from_normals(planes_S[:, :3], planes_B[:, :3], prior.T_B_S[:3, :3], prior.gravity_aligned)
    angles = np.degrees(np.arccos(np.clip(np.sum((planes_S[:, :3] @ R.T) * planes_B[:, :3], axis=1), -1.0, 1.0)))
    if angles.max() > cfg.seed_max_angle_deg:
        worst = int(np.argmax(angles))
        name = labels[worst] if labels else f"pair {worst}"
        raise ConfigError(f"seed {name}: its plane lies {angles[worst]:.0f} deg from its face once the seeds are turned onto "
                         f"the plan{' about the vertical' if prior.gravity_aligned else ''} (at most "
                         f"{cfg.seed_max_angle_deg:g}, backend.seed_max_angle_deg): "
                         + ("the pairs disagree, one of them is not that plane and face" if len(angles) > 1 else
                            "that plane is not that face (one tilts more than the other)"))
    sigma_deg = np.degrees(prior.largest_sigmas()[0])
    if prior_given and (turn_deg := rotation_angle_deg(R.T @ prior.T_B_S[:3, :3])) > _SEED_SIGMAS * sigma_deg:
        raise ConfigError(f"the --seed pairs turn T_B_S {turn_deg:.0f} deg from the initial alignment, "
                          f"{turn_deg / sigma_deg:.0f} times its sigma_rot_deg ({sigma_deg:.3g}): a pair names the "
                          "wrong plane or face (the wall opposite?), or the alignment is wrong or its sigma too small")
    # offsets: d_B = d_S - n_B . t, regularised toward the prior where the normals say nothing
    n_B = planes_S[:, :3] @ R.T
    info_t = n_B.T @ n_B + 1e-6 * np.eye(3)
    t = np.linalg.solve(info_t, n_B.T @ (planes_S[:, 3] - planes_B[:, 3]) + 1e-6 * prior.T_B_S[:3, 3])
    guess = make_pose(R, t)

    unobservable = unobservable_directions(planes_B[:, :3], cfg.unobservable_min_angle_deg)
    build = FactorBuilder(cfg)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(build.extrinsic_prior(prior.T_B_S, prior_beside_seeds(prior, unobservable)))
    values.insert(E, pose3(guess).inverse())
    # Each seed plane as its keyframe saw it (fixed at its pose in S), under the detection's
    # covariance: at the floor instead, one pair of an office walk, a plane 4.8 m off with its
    # offset 7 cm (2 sigma) out, gave an alignment 9 cm off that claimed 2.6 cm, whose prior
    # then made the robust alignment keep a wall built 2.4 cm off plan (3.0 cm, NEES 28).
    for j, (plane_S, plane_B) in enumerate(zip(planes_S, planes_B)):
        T_S_C, cov = seen[j] if seen is not None else (np.eye(4), np.zeros((3, 3)))
        plane_C = plane_to_frame(plane_S, T_S_C)
        graph.add(build.first_pose(j, T_S_C))
        values.insert(X(j), pose3(T_S_C))
        graph.add(build.anchor_observation(j, plane_C, build.observation_cov(cov)))
        graph.add(build.bim(j, j, plane_B, None if centres_B is None else centres_B[j]))
        values.insert(L(j), gtsam.OrientedPlane3(plane_C))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    T_S_B = result.atPose3(E)
    cov_E = gtsam.Marginals(graph, result).marginalCovariance(E)
    return Alignment(T_S_B.inverse().matrix(), cov_T_B_S(T_S_B, cov_E), unobservable, prior.gravity_aligned)

