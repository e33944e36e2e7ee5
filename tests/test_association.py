"""Association on hand-made planes and faces: the SLAM side's gate and the BIM side's gate,
filters, ambiguity and revision."""

import gtsam
import numpy as np
import pytest

from bimgraph.backend import BimAssociator, FaceIndex
from bimgraph.backend.associate_slam import Observation, Stacked, mahalanobis_to_landmarks
from bimgraph.backend.landmarks import Landmark, LandmarkTable
from bimgraph.config import BackendConfig
from bimgraph.geometry import exp_se3, inverse, normalise_plane, plane_from_frame, plane_to_frame
from factors import local_plane_error


@pytest.fixture(scope="module")
def cfg():
    return BackendConfig()


def test_slam_gate_is_the_plane_factor_residual():
    """The vectorised Mahalanobis distance equals the one built from the factor's residual
    and Jacobian in `factors`."""
    rng = np.random.default_rng(2)
    table = LandmarkTable()
    T_S_C = exp_se3(rng.normal(size=6) * 0.5)
    for j in range(4):
        T_S_A = exp_se3(rng.normal(size=6) * 0.5)
        plane_A = normalise_plane(rng.normal(size=4))
        cov_A = np.diag(rng.uniform(1e-5, 1e-3, 3))
        table.add(Landmark(j, j, plane_A, cov_A, T_S_A))
    observations = [Observation(i, normalise_plane(plane_from_frame(table[i].plane_S, inverse(T_S_C)) + rng.normal(size=4) * 0.02),
                                np.diag(rng.uniform(1e-4, 3e-4, 3)), np.zeros((0, 3))) for i in range(2)]
    pairs = (np.repeat([0, 1], 4), np.tile(np.arange(4), 2))
    d2 = mahalanobis_to_landmarks(Stacked.of(observations), T_S_C, table, pairs)
    for i, j, d2_ij in zip(*pairs, d2):
        lm, obs = table[j], observations[i]
        e, (_, _, H_L) = local_plane_error(gtsam.Pose3(T_S_C), gtsam.Pose3(lm.T_S_A), gtsam.OrientedPlane3(lm.plane_A),
                                           obs.plane_C, jacobians=True)
        S = H_L @ lm.cov_A @ H_L.T + obs.cov
        assert d2_ij == pytest.approx(e @ np.linalg.solve(S, e), rel=1e-9)


def test_ambiguous_faces_wait_for_the_extent():
    """Two nearly coplanar faces (2 cm apart, side by side) and a landmark without extent: no
    match (ambiguous) until its extent tells them apart."""
    from bimgraph.backend.associate_bim import PlaneInB
    from bimgraph.bim.planemap import BimFace, PlaneMap

    def face(name, x0, y):
        poly = [(x0, y, 0.0), (x0 + 4, y, 0.0), (x0 + 4, y, 3.0), (x0, y, 3.0)]
        return BimFace(id=name, wall_guid=name, normal=(0, 1, 0), offset=-y, polygon=poly)

    cfg = BackendConfig().bim_association
    plane_map = PlaneMap(faces=[face("a", 0.0, 0.0), face("b", 4.3, 0.02)])
    bim = BimAssociator(FaceIndex(plane_map, cfg), cfg)
    plane = np.array([0.0, 1.0, 0.0, -0.01])
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-4])
    assert bim.match([PlaneInB(0, plane, cov, np.zeros((0, 3)), 4.0)]) == []
    extent = np.array([[5.0, 0.01, 0.5], [7.5, 0.01, 0.5], [7.5, 0.01, 2.5], [5.0, 0.01, 2.5]])
    assert [m.face for m in bim.match([PlaneInB(0, plane, cov, extent, 5.0)])] == ["b"]


def test_a_wall_seen_whole_matches_its_face_around_a_door():
    """A door at the foot of a wall is a notch in its face's outline; the landmark of the
    wall seen whole spans the doorway, and its centre lies in it (site 1's 3 m wall with a
    door in the middle: matched once the filters take each face's convex hull)."""
    from bimgraph.backend.associate_bim import PlaneInB
    from bimgraph.bim.planemap import BimFace, PlaneMap

    cfg = BackendConfig().bim_association
    u_shape = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 0.0, 2.1), (2.0, 0.0, 2.1), (2.0, 0.0, 0.0),
               (3.0, 0.0, 0.0), (3.0, 0.0, 3.2), (0.0, 0.0, 3.2)]
    faces = FaceIndex(PlaneMap(faces=[BimFace(id="a", wall_guid="a", normal=(0, 1, 0), offset=0.0, polygon=u_shape)]), cfg)
    extent = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 0.0, 3.2], [0.0, 0.0, 3.2]])
    plane = np.array([0.0, 1.0, 0.0, 0.0])
    matches = BimAssociator(faces, cfg).match([PlaneInB(0, plane, np.diag([1e-6] * 4), extent, 9.6)])
    assert [m.face for m in matches] == ["a"]


def test_an_observation_takes_the_nearest_section_of_a_long_facade():
    """A facade of 8 storeys, each cut in sections of 1-6 m, some U-shaped around a door (a
    section's box then lies nearer than its outline): the member an observation lies on is
    the one nearest to it, as measured against every member's outline."""
    from bimgraph.bim.planemap import BimFace, PlaneMap

    rng = np.random.default_rng(3)
    faces = []
    for storey in range(8):
        z0, x = 3.0 * storey, 0.0
        while x < 60.0:
            w = rng.uniform(1.0, 6.0)
            if w > 3.0:  # a door notch at the foot
                poly = [(x, 0, z0), (x + 1, 0, z0), (x + 1, 0, z0 + 2.1), (x + 2, 0, z0 + 2.1), (x + 2, 0, z0),
                        (x + w, 0, z0), (x + w, 0, z0 + 3.0), (x, 0, z0 + 3.0)]
            else:
                poly = [(x, 0, z0), (x + w, 0, z0), (x + w, 0, z0 + 3.0), (x, 0, z0 + 3.0)]
            faces.append(BimFace(id=f"s{storey}-{x:.2f}", wall_guid="w", normal=(0, 1, 0), offset=0.0, polygon=poly))
            x += w + rng.uniform(0.0, 0.3)
    index = FaceIndex(PlaneMap(faces=faces), BackendConfig().bim_association)
    (group,) = set(index.group.tolist())
    assert len(index.members[group]) == len(faces) > 100
    import shapely

    for point in np.c_[rng.uniform(-2, 62, 300), np.zeros(300), rng.uniform(-1, 25, 300)]:
        p = shapely.points(index.to_2d(index.rep[group], point[None])[0])
        nearest = index.ids[int(np.argmin(shapely.distance(index.outline, p)))]
        assert index.member_at(group, point) == nearest


def _one_wall(cfg):
    """One wall face (y = 0, normal +y, 4 m by 3 m) and a plane 5 cm before its centre turned
    by `deg` about `axis` (the plane, as a function)."""
    from bimgraph.bim.planemap import BimFace, PlaneMap

    poly = [(0.0, 0.0, 0.0), (4.0, 0.0, 0.0), (4.0, 0.0, 3.0), (0.0, 0.0, 3.0)]
    faces = FaceIndex(PlaneMap(faces=[BimFace(id="a", wall_guid="a", normal=(0, 1, 0), offset=0.0, polygon=poly)]), cfg)
    centre = np.array([2.0, 0.05, 1.5])

    def turned(axis, deg):
        n = gtsam.Rot3.Rodrigues(np.asarray(axis, dtype=float) * np.radians(deg)).matrix() @ np.array([0.0, 1.0, 0.0])
        return np.r_[n, -n @ centre]

    return faces, turned


def test_a_plane_leaning_out_of_plumb_is_no_wall():
    """The gate's as-built tolerance: a plane turned 3 degrees about the vertical, 5 cm off,
    may be its wall (built off its line, or the extrinsic's heading); one leaning 3 degrees out
    of plumb about its centre line (a board on the wall) is not."""
    from bimgraph.backend.associate_bim import PlaneInB

    cfg = BackendConfig().bim_association
    faces, turned = _one_wall(cfg)
    bim = BimAssociator(faces, cfg)
    extent = np.array([[0.5, 0.05, 0.5], [3.5, 0.05, 0.5], [3.5, 0.05, 2.5], [0.5, 0.05, 2.5]])
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-6])
    for axis, matched in (([0, 0, 1], True), ([1, 0, 0], False)):
        assert (len(bim.match([PlaneInB(0, turned(axis, 3.0), cov, extent, 6.0)])) == 1) is matched


def test_a_landmark_no_face_could_take_costs_no_joint_marginal():
    """The BIM association reads a landmark's joint marginal (the costly part) only if some
    face within the normal angle passes the geometric filters: a plane across the wall, or
    one far beyond its ends, is no candidate whatever its covariance."""
    from bimgraph.backend.associate_bim import candidate

    cfg = BackendConfig().bim_association
    faces, turned = _one_wall(cfg)
    bim = BimAssociator(faces, cfg)
    extent = np.array([[0.5, 0.05, 0.5], [3.5, 0.05, 0.5], [3.5, 0.05, 2.5], [0.5, 0.05, 2.5]])
    assert bim.may_match(turned([0, 0, 1], 0.0), extent, 6.0)
    assert not bim.may_match(turned([0, 0, 1], 90.0), extent, 6.0)
    assert not bim.may_match(turned([0, 0, 1], 0.0), extent + [10.0, 0.0, 0.0], 6.0)

    def no_joint(keys):
        raise AssertionError("joint marginal read")

    T_S_B = gtsam.Pose3()
    lm = Landmark(0, 0, turned([0, 0, 1], 90.0), np.eye(3) * 1e-6, np.eye(4), extent_A=extent, area=6.0)
    assert candidate(lm, T_S_B, no_joint, bim) is None
    lm.plane_A = turned([0, 0, 1], 0.0)
    assert candidate(lm, T_S_B, lambda keys: np.eye(15) * 1e-8, bim).landmark == 0


def test_a_match_leaning_out_of_plumb_is_revised():
    """A matched landmark that leans 2.7 deg out of its face's plumb (a board on the wall) loses
    the match; one leaning 2 deg (a wall built out of plumb) or turned 2.9 deg about the vertical
    keeps it."""
    from bimgraph.backend.matches import revision_reason

    cfg = BackendConfig().bim_association
    faces, turned = _one_wall(cfg)
    assert revision_reason(turned([1, 0, 0], 2.7), faces, "a", cfg).startswith("leaning")
    assert revision_reason(turned([1, 0, 0], 2.0), faces, "a", cfg) is None
    assert revision_reason(turned([0, 0, 1], 2.9), faces, "a", cfg) is None


def test_a_match_off_by_what_the_extrinsic_allows_is_kept():
    """A landmark 30 cm before its face loses the match, unless the extrinsic's uncertainty
    alone allows that offset `revision_offset_sigmas` times (asked for only then)."""
    from bimgraph.backend.matches import revision_reason

    cfg = BackendConfig().bim_association
    faces, _ = _one_wall(cfg)
    plane_B = np.array([0.0, 1.0, 0.0, -0.30])
    asked = []

    def sigma(value):
        return lambda: asked.append(value) or value

    assert revision_reason(plane_B, faces, "a", cfg).startswith("offset")
    assert revision_reason(plane_B, faces, "a", cfg, sigma(0.05)).startswith("offset")
    assert revision_reason(plane_B, faces, "a", cfg, sigma(0.15)) is None
    assert revision_reason(plane_B + [0, 0, 0, 0.1], faces, "a", cfg, sigma(1.0)) is None
    assert asked == [0.05, 0.15]  # not for an offset within `revision_offset_m`


def test_a_normal_the_gate_still_takes_keeps_its_match():
    """A landmark turned 5 deg about the vertical from its face loses the match, unless the
    BIM gate with its covariance as it stands still takes the face (asked for only then)."""
    from bimgraph.backend.matches import revision_reason

    cfg = BackendConfig().bim_association
    faces, turned = _one_wall(cfg)
    asked = []

    def gated(value):
        return lambda: asked.append(value) or value

    assert revision_reason(turned([0, 0, 1], 5.0), faces, "a", cfg).startswith("normal")
    assert revision_reason(turned([0, 0, 1], 5.0), faces, "a", cfg, gated=gated(False)).startswith("normal")
    assert revision_reason(turned([0, 0, 1], 5.0), faces, "a", cfg, gated=gated(True)) is None
    assert revision_reason(turned([0, 0, 1], 2.0), faces, "a", cfg, gated=gated(False)) is None
    assert asked == [False, True]  # not for a normal within `revision_normal_deg`


def test_offset_sigma_jacobian_is_the_numerical_one():
    """The offset's standard deviation from the extrinsic's covariance, per tangent direction
    of T_B_S, against a central difference of the offset itself."""
    from bimgraph.backend.matches import offset_sigma

    rng = np.random.default_rng(0)
    T_B_S = exp_se3(np.r_[rng.normal(size=3), rng.normal(size=3) * 5])
    n = rng.normal(size=3)
    plane_S, centre_B = np.r_[n / np.linalg.norm(n), 1.3], rng.normal(size=3) * 4

    def offset(xi):
        plane_B = plane_to_frame(plane_S, inverse(T_B_S @ exp_se3(xi)))
        return plane_B[:3] @ centre_B + plane_B[3]

    gradient = np.array([(offset(step) - offset(-step)) / 2e-7 for step in np.eye(6) * 1e-7])
    # a correlated covariance, as the extrinsic's is: a sign wrong in either block shows
    A = rng.normal(size=(6, 6))
    cov = A @ A.T + 0.1 * np.eye(6)
    assert offset_sigma(plane_S, inverse(T_B_S), centre_B, cov) == pytest.approx(np.sqrt(gradient @ cov @ gradient), rel=1e-6)


def test_same_plane_d2_of_two_landmarks():
    """Two landmarks as one plane: zero for one wall seen from two anchors, and an offset
    apart by 3 sigma (of either landmark's offset, or of an anchor's position along the
    normal) scores 9; one anchor for both takes the 3-key layout."""
    from bimgraph.backend.associate_slam import same_plane_d2

    rng = np.random.default_rng(2)
    wall_S = normalise_plane(np.r_[1.0, 0.2, 0.0, -3.0])
    T_S_A1, T_S_A2 = exp_se3(rng.normal(size=6)), exp_se3(rng.normal(size=6))
    plane_1, plane_2 = plane_to_frame(wall_S, T_S_A1), plane_to_frame(wall_S, T_S_A2)
    shifted_2 = plane_2 + np.r_[0, 0, 0, 0.03]
    cov = np.eye(18) * 1e-12
    assert same_plane_d2(plane_1, T_S_A1, plane_2, T_S_A2, cov + np.eye(18) * 1e-4) == pytest.approx(0.0, abs=1e-9)
    for index in (14, 17):  # offset of landmark 2, of landmark 1
        c = cov.copy()
        c[index, index] = 0.01**2
        assert same_plane_d2(plane_1, T_S_A1, shifted_2, T_S_A2, c) == pytest.approx(9.0, rel=1e-3)
    # anchor 1's position along the wall normal (gtsam's translation is in the anchor's frame)
    c = cov.copy()
    u = np.r_[np.zeros(3), T_S_A1[:3, :3].T @ wall_S[:3]]
    c[:6, :6] += np.outer(u, u) * 0.01**2
    assert same_plane_d2(plane_1, T_S_A1, shifted_2, T_S_A2, c) == pytest.approx(9.0, rel=1e-3)
    one_anchor = np.eye(12) * 1e-12
    one_anchor[11, 11] = 0.01**2
    assert same_plane_d2(plane_1, T_S_A1, plane_1 + np.r_[0, 0, 0, 0.03], T_S_A1, one_anchor) == pytest.approx(9.0, rel=1e-3)


def test_behind_finds_the_parallel_planes_on_the_wall_side():
    """`matches.behind`: of landmarks parallel to one (a partition 1 m before x = 3, facing -x),
    those whose planes lie within the gap range on the side their normals turn away from (the
    wall side), not those before it, turned away from it, or merged."""
    from bimgraph.backend.matches import behind

    table = LandmarkTable()
    facing_minus_x = [np.r_[-1.0, 0.0, 0.0, 2.0],  # the partition, at x = 2
                      np.r_[-1.0, 0.0, 0.0, 3.0],  # 1 m behind it: the wall
                      np.r_[-1.0, 0.0, 0.0, 2.04],  # 4 cm behind: too near
                      np.r_[-1.0, 0.0, 0.0, 1.5],  # before it
                      normalise_plane(np.r_[-1.0, 0.9, 0.0, 3.0]),  # behind, turned 42 deg
                      np.r_[-1.0, 0.0, 0.0, 2.5],  # 0.5 m behind, merged away
                      np.r_[-1.0, 0.0, 0.0, 6.0]]  # 4 m behind: beyond the range
    for j, plane_S in enumerate(facing_minus_x):
        table.add(Landmark(j, j, plane_S, np.eye(3) * 1e-4, np.eye(4)))
    table.active[5] = False
    def within(j, max_gap_m=2.0):
        return [k for k, gap in behind(table[j], table, np.cos(np.radians(20.0)), 0.05).items() if gap <= max_gap_m]

    assert within(0) == [1]
    assert within(1) == []
    assert within(3) == [0, 1, 2]
    assert behind(table[0], table, np.cos(np.radians(20.0)), 0.05) == pytest.approx({1: 1.0, 6: 4.0})
