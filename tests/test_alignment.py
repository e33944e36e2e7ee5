"""The initial alignment (seed pairs, levelling) and the directions of T_B_S that matched faces
leave unobservable."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimgraph.backend import Alignment, Backend, align_from_seeds, unobservable_directions
from bimgraph.backend.pipeline import seed_alignment
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig, Config
from bimgraph.geometry import exp_se3, inverse, make_pose, normalise_plane, plane_from_frame


@pytest.fixture(scope="module")
def cfg():
    return BackendConfig()


def test_unobservable_directions():
    assert unobservable_directions(np.eye(3), 10.0) == []
    two = unobservable_directions([[1, 0, 0], [0, 1, 0]], 10.0)
    assert two == [{"kind": "translation", "axis_B": [0.0, 0.0, 1.0]}]
    one = unobservable_directions([[1, 0, 0], [-1, 0, 0]], 10.0)
    assert {(u["kind"], tuple(np.abs(u["axis_B"]))) for u in one} == {
        ("rotation", (1.0, 0.0, 0.0)), ("translation", (0.0, 1.0, 0.0)), ("translation", (0.0, 0.0, 1.0))}
    # nearly parallel normals (5 deg apart) do not count as independent
    near = unobservable_directions([[1, 0, 0], [np.cos(0.087), np.sin(0.087), 0], [0, 0, 1]], 10.0)
    assert any(u["kind"] == "translation" for u in near)
    # a corridor's turn about its axis is a tilt: gravity observes it
    corridor = unobservable_directions([[1, 0, 0], [-1, 0, 0]], 10.0, gravity=True)
    assert {(u["kind"], tuple(np.abs(u["axis_B"]))) for u in corridor} == {
        ("translation", (0.0, 1.0, 0.0)), ("translation", (0.0, 0.0, 1.0))}


def test_align_from_seeds(cfg):
    rng = np.random.default_rng(4)
    T_B_S = exp_se3(np.r_[rng.normal(size=3) * 0.3, rng.normal(size=3) * 2])
    planes_B = np.array([[1, 0, 0, -2.0], [0, 1, 0, 1.0], [0, -1, 0, 3.0], [0, 0, 1, 0.0]])
    planes_S = np.array([plane_from_frame(p, inverse(T_B_S)) for p in planes_B])
    prior = Alignment.from_sigmas(T_B_S @ exp_se3(np.r_[0, 0, 0.05, 0.3, 0.2, 0.1]), 5.0, 0.5)
    full = align_from_seeds(planes_S, planes_B, cfg, prior)
    np.testing.assert_allclose(full.T_B_S, T_B_S, atol=1e-6)
    assert full.unobservable == []
    # two parallel walls: x, z and the rotation about y are left to the prior, and reported
    corridor = align_from_seeds(planes_S[1:3], planes_B[1:3], cfg, prior)
    assert {u["kind"] for u in corridor.unobservable} == {"rotation", "translation"}
    assert corridor.T_B_S[1, 3] == pytest.approx(T_B_S[1, 3], abs=0.02)
    assert np.sqrt(corridor.cov[3:, 3:].max()) > 0.1  # still the prior's uncertainty somewhere


def test_levelled_alignment_keeps_heading_and_pins_tilt():
    """Gravity-aligned S and z-up B: the hand alignment loses its tilt and keeps its heading
    and position; the tilt's uncertainty drops to the gravity error, the rest stays."""
    from bimgraph.backend.alignment import levelled

    yaw, tilt = np.radians(30.0), np.radians(1.5)
    T_B_S = make_pose(Rotation.from_rotvec([tilt, 0.0, 0.0]).as_matrix() @ Rotation.from_rotvec([0, 0, yaw]).as_matrix(),
                      np.array([3.0, -2.0, 1.2]))
    level = levelled(Alignment.from_sigmas(T_B_S, 2.0, 0.2), np.radians(0.1))
    R = level.T_B_S[:3, :3]
    np.testing.assert_allclose(R[:, 2], [0, 0, 1], atol=1e-12)
    assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(yaw, abs=np.radians(0.05))
    np.testing.assert_allclose(level.T_B_S[:3, 3], T_B_S[:3, 3])
    sigmas = np.sqrt(np.diag(level.cov))
    np.testing.assert_allclose(np.degrees(sigmas[:2]), 0.1, rtol=0.01)
    assert np.degrees(sigmas[2]) == pytest.approx(2.0)
    np.testing.assert_allclose(sigmas[3:], 0.2)
    assert level.gravity_aligned


def test_seed_pairs_that_disagree_are_refused(cfg):
    """Two walls' pairs swapped: a rotation fits them exactly, one that turns the world over
    (a run went on with T_B_S 87 m below the floor). With S gravity-aligned, the seeds are a
    turn about z, which cannot swap two walls: refused, naming the pair that does not fit.
    Consistent pairs still fit, with the turn."""
    from bimgraph.errors import ConfigError

    T_B_S = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [5.0, -3.0, 0.0])
    planes_B = np.array([[0.0, -1.0, 0.0, 4.0], [-1.0, 0.0, 0.0, 6.0]])  # north wall y = 4, east wall x = 6
    planes_S = np.array([plane_from_frame(p, inverse(T_B_S)) for p in planes_B])
    prior = Alignment.from_sigmas(np.eye(4), 180.0, 100.0)
    prior.gravity_aligned = True
    good = align_from_seeds(planes_S, planes_B, cfg, prior, labels=["0:0:N", "0:1:E"])
    np.testing.assert_allclose(good.T_B_S[:3, :3], T_B_S[:3, :3], atol=1e-6)
    with pytest.raises(ConfigError, match=r"seed 0:1:N: its plane lies \d+ deg from its face .* the pairs disagree"):
        align_from_seeds(planes_S, planes_B[::-1], cfg, prior, labels=["0:0:E", "0:1:N"])
    floor_S = plane_from_frame(np.array([0.0, 0.0, 1.0, 0.0]), inverse(T_B_S))
    with pytest.raises(ConfigError, match=r"seed 0:2:N: its plane lies 90 deg .* that plane is not that face"):
        align_from_seeds(floor_S[None], planes_B[:1], cfg, prior, labels=["0:2:N"])  # (one pair: nothing to disagree with)


def test_seed_alignment_carries_the_detections_noise(cfg):
    """The seed planes were taken as exact: an office walk's pair, one plane 4.8 m off with its
    offset 7 cm out (2 sigma of its detection), gave an alignment 9 cm off that claimed 2.6 cm,
    and the run ended 3.0 cm off with NEES 28 (0.4 cm, NEES 0.6 now)."""
    rng = np.random.default_rng(2)
    T_B_S = exp_se3(np.r_[0, 0, 0.4, 1.0, -2.0, 0.3])
    planes_B = np.array([[1, 0, 0, -2.0], [0, 1, 0, 1.0], [0, 0, 1, 0.0]])
    planes_S = np.array([plane_from_frame(p, inverse(T_B_S)) for p in planes_B])
    prior = Alignment.from_sigmas(T_B_S, 5.0, 0.5)
    T_S_C = [exp_se3(np.r_[rng.normal(size=3) * 0.5, rng.normal(size=3)]) for _ in planes_S]
    noisy = np.diag([np.radians(1.0) ** 2, np.radians(1.0) ** 2, 0.05 ** 2])  # (normal 1 deg, offset 5 cm)
    exact = align_from_seeds(planes_S, planes_B, cfg, prior)
    seen = align_from_seeds(planes_S, planes_B, cfg, prior, seen=[(T, noisy) for T in T_S_C])
    np.testing.assert_allclose(seen.T_B_S, T_B_S, atol=1e-6)  # (noise-free planes: the same estimate)
    sigma_exact, sigma_seen = np.sqrt(np.diag(exact.cov)[3:]), np.sqrt(np.diag(seen.cov)[3:])
    assert (sigma_seen > 0.045).all() and (sigma_seen > 1.5 * sigma_exact).all()  # the detections' 5 cm too
    # a keyframe's pose in S moves the plane it saw, not the alignment
    np.testing.assert_allclose(align_from_seeds(planes_S, planes_B, cfg, prior, seen=[(np.eye(4), None)] * 3).T_B_S,
                               T_B_S, atol=1e-6)


def test_seed_pairs_count_once(cfg):
    """Seed pairs start the graph matched, and the start's covariance holds none of their
    information: it held the registration's, so their detections and their faces' tolerance
    counted twice (offices 1-2 seeded with their first keyframe's walls: NEES 11.7 and 8.3
    offline; 4.9 and 2.0 now)."""
    scene = make_scene(20, rooms=(2, 2), seed=3)
    kf = scene.keyframes[3].model_copy(update={"index": 0})  # (the first to see two walls)
    seeds = [(0, i, scene.truth[3, i]) for i in range(len(kf.planes)) if scene.truth[3, i]]
    assert len(seeds) == 2
    start = seed_alignment([kf], scene.plane_map, seeds, Config(), scene.initial)
    assert start.seeds == {(k, i): face for k, i, face in seeds}
    normals_B = np.array([scene.plane_map.faces[scene.plane_map.index[face]].plane[:3] for _, _, face in seeds])
    # (a translation along each seeded face's normal: what the seeds observe best)
    for n_B in normals_B:
        u = np.r_[np.zeros(3), scene.initial.T_B_S[:3, :3].T @ n_B]
        assert u @ start.cov @ u > 50 * 0.2**2  # (the sequence's own alignment: 20 cm)
    backend = Backend(scene.plane_map, cfg, start)
    first = backend.process(kf)
    assert {(a.observation, a.face) for a in first.associations if a.face} >= {(i, face) for _, i, face in seeds}
    # the seeds' information is in the graph once: the extrinsic after keyframe 0 is as sure as
    # the registration of the seeds alone (where it was surer, by counting them twice)
    faces = [scene.plane_map.faces[scene.plane_map.index[face]] for _, _, face in seeds]
    planes_S = [plane_from_frame(normalise_plane(kf.planes[i].plane), kf.pose) for _, i, _ in seeds]
    seeded = align_from_seeds(np.array(planes_S), np.array([f.plane for f in faces]), cfg, scene.initial,
                              np.array([f.centre for f in faces]), seen=[(kf.pose, kf.planes[i].cov) for _, i, _ in seeds])
    for n_B in normals_B:
        u = np.r_[np.zeros(3), first.T_B_S[:3, :3].T @ n_B]
        assert u @ first.cov_T_B_S @ u == pytest.approx(u @ seeded.cov @ u, rel=0.25)

