"""As-built deviations: the offset/tilt maths against direct geometry and numerical
derivatives, taking a face's own factor out against re-solving a real gtsam graph without it,
the status rules, and the report's lists on synthetic scenes with known answers."""

from dataclasses import replace
from functools import partial

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from bimgraph.backend.graph import joint_covariance
from bimgraph.backend.marginals import JointMarginals
from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.estimate import (
    Deviation,
    classify,
    deviation_terms,
    face_deviation,
    plane_to_bim_residual,
)
from bimgraph.deviations.graph import observed_plane
from bimgraph.deviations.visibility import expected_view_counts
from bimgraph.geometry import plane_to_frame
from deviation_scenes import GUIDS, T_S_A, T_S_B, WALLS, as_built_plane, camera_looking, face, observed, rectangle, room
from factors.plane import local_plane_factor, plane_prior_factor, plane_to_bim_factor

CFG = DeviationConfig()
K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])


def direct_terms(f, plane_A, T_S_A_, T_S_B_):
    """(offset, tilt components) straight from the landmark mapped into B by gtsam."""
    T_A_B = gtsam.Pose3(T_S_A_).between(gtsam.Pose3(T_S_B_))
    plane_B = gtsam.OrientedPlane3(plane_A).transform(T_A_B).planeCoefficients()
    B_F = gtsam.Unit3(np.asarray(f.normal, dtype=float)).basis()
    return np.array([-(plane_B[:3] @ np.asarray(f.centre) + plane_B[3]), *(B_F.T @ plane_B[:3])])


@pytest.mark.parametrize("name", list(WALLS))
@pytest.mark.parametrize("offset, tilt", [(0.0, 0.0), (0.06, 0.0), (-0.08, 1.5), (0.03, -3.0)])
def test_offset_and_tilt_match_the_geometry(name, offset, tilt):
    f = face(name)
    plane = observed(0, as_built_plane(f, offset, tilt))
    e, _ = plane_to_bim_residual(f, plane, T_S_B)
    y, _ = deviation_terms(e, f)
    np.testing.assert_allclose(y, direct_terms(f, plane.plane_A, T_S_A, T_S_B), atol=1e-12)
    dev = face_deviation(f, plane, T_S_B)
    # The offset is measured along the as-built normal, at the face centre.
    assert dev.offset_m == pytest.approx(offset * np.cos(np.radians(tilt)), abs=1e-12)
    assert dev.tilt_deg == pytest.approx(abs(tilt), abs=1e-9)


@pytest.mark.parametrize("name", ["south", "east"])
def test_jacobian_matches_numerical_derivatives(name):
    """d(offset, tilt)/d(E, X_anchor, L) through gtsam's own retractions."""
    f = face(name)
    plane = observed(0, as_built_plane(f, 0.07, 2.0))
    e, J = plane_to_bim_residual(f, plane, T_S_B)
    _, H = deviation_terms(e, f)
    analytic = H @ J

    E0, A0, L0 = gtsam.Pose3(T_S_B), gtsam.Pose3(T_S_A), gtsam.OrientedPlane3(plane.plane_A)

    def y(xi):
        E1, A1 = E0.retract(xi[:6]), A0.retract(xi[6:12])
        L1 = L0.retract(xi[12:])
        return direct_terms(f, L1.planeCoefficients(), A1.matrix(), E1.matrix())

    h = 1e-6
    numeric = np.stack([(y(h * np.eye(15)[i]) - y(-h * np.eye(15)[i])) / (2 * h) for i in range(15)], axis=1)
    np.testing.assert_allclose(analytic, numeric, atol=1e-7)
    assert np.abs(analytic).max() > 0.1  # not trivially zero


def room_graph(deviating: str, offset: float, drop_factor_of: str | None = None):
    """Two keyframes in the room seeing all four as-built walls (noise-free), a weak prior on
    the extrinsic and a Cauchy-robust plane-to-BIM factor per wall; solved by LM."""
    E = gtsam.symbol("e", 0)
    T_B_C = [camera_looking((3.0, 2.0, 1.25), 10.0), camera_looking((2.5, 1.8, 1.4), 200.0)]
    T_S_C = [T_S_B @ T for T in T_B_C]
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(T_S_C[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
    graph.add(gtsam.BetweenFactorPose3(X(0), X(1), gtsam.Pose3(np.linalg.inv(T_S_C[0]) @ T_S_C[1]),
                                       gtsam.noiseModel.Isotropic.Sigma(6, 0.05)))
    graph.add(gtsam.PriorFactorPose3(E, gtsam.Pose3(T_S_B), gtsam.noiseModel.Diagonal.Sigmas([0.03] * 3 + [0.2] * 3)))
    obs_noise = gtsam.noiseModel.Diagonal.Sigmas([0.01, 0.01, 0.01])
    bim_noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
                                               gtsam.noiseModel.Diagonal.Sigmas([0.005, 0.005, 0.01]))
    factors = {}
    for j, name in enumerate(WALLS):
        f = face(name)
        plane_B = as_built_plane(f, offset if name == deviating else 0.0)
        z = [plane_to_frame(plane_B, T) for T in T_B_C]
        graph.add(plane_prior_factor(z[0], obs_noise, L(j)))
        graph.add(local_plane_factor(z[1], obs_noise, X(1), X(0), L(j)))
        factors[name] = plane_to_bim_factor(f.plane, bim_noise, E, X(0), L(j))
        if name != drop_factor_of:
            graph.add(factors[name])
        values.insert(L(j), gtsam.OrientedPlane3(z[0]))
    values.insert(X(0), gtsam.Pose3(T_S_C[0]))
    values.insert(X(1), gtsam.Pose3(T_S_C[1]))
    values.insert(E, gtsam.Pose3(T_S_B))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return graph, result, E, factors


def test_own_factor_taken_out_equals_resolving_without_it():
    graph, result, E, factors = room_graph("east", 0.06)
    marginals = gtsam.Marginals(graph, result)
    j = list(WALLS).index("east")
    with_factor = observed_plane(partial(joint_covariance, marginals), result, E, X(0), L(j), n_keyframes=2, face_id="east-face",
                                 bim_factor=factors["east"])
    dev = face_deviation(face("east"), with_factor, result.atPose3(E).matrix())

    graph2, result2, _, _ = room_graph("east", 0.06, drop_factor_of="east")
    without = observed_plane(partial(joint_covariance, gtsam.Marginals(graph2, result2)), result2, E, X(0), L(j), n_keyframes=2)
    ref = face_deviation(face("east"), without, result2.atPose3(E).matrix())

    assert dev.offset_m == pytest.approx(0.06, abs=1e-3)
    # Equal up to the change of the Cauchy weights between the two solutions.
    assert dev.offset_m == pytest.approx(ref.offset_m, abs=5e-5)
    assert dev.offset_sigma_m == pytest.approx(ref.offset_sigma_m, rel=0.03)
    assert dev.tilt_sigma_deg == pytest.approx(ref.tilt_sigma_deg, rel=0.03)
    # Kept in, the face's own factor pulls the measurement toward the plan (here by 5 mm) and
    # claims a smaller uncertainty than the evidence gives.
    naive = face_deviation(face("east"), observed_plane(partial(joint_covariance, marginals), result, E, X(0), L(j), 2), result.atPose3(E).matrix())
    assert naive.offset_m < 0.057
    assert naive.offset_sigma_m < dev.offset_sigma_m


def test_joint_covariance_keeps_the_requested_order():
    graph, result, E, _ = room_graph("east", 0.0)
    marginals = gtsam.Marginals(graph, result)
    cov = joint_covariance(marginals, [E, X(0), L(1)])
    np.testing.assert_allclose(cov[:6, :6], marginals.marginalCovariance(E), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(cov[12:, 12:], marginals.marginalCovariance(L(1)), rtol=1e-9, atol=1e-15)


def test_a_face_only_the_plan_constrains_is_not_measurable():
    """A landmark pinned by its plane-to-BIM factor alone carries no evidence of its own."""
    f = face("south")
    plane = observed(0, f.plane, sigma=0.01)
    # A factor explaining all of the landmark's information (A^T A = Sigma_L^-1), and nothing
    # else uncertain.
    A = np.zeros((3, 15))
    A[:, 12:] = np.linalg.cholesky(np.linalg.inv(plane.cov[12:, 12:])).T
    cov = np.zeros_like(plane.cov)
    cov[12:, 12:] = plane.cov[12:, 12:]
    pinned = replace(plane, cov=cov, bim_factor=(A, np.zeros(3)))
    dev = face_deviation(f, pinned, T_S_B)
    assert not dev.measurable
    assert classify(dev, 50, CFG) == "not_enough_evidence"


@pytest.mark.parametrize("dev, n, status", [
    (Deviation(0.06, 0.001, 0.1, 0.05), 10, "deviating"),
    (Deviation(-0.06, 0.001, 0.1, 0.05), 10, "deviating"),
    (Deviation(0.005, 0.001, 2.0, 0.1), 10, "deviating"),
    (Deviation(0.01, 0.002, 0.1, 0.05), 10, "within_tolerance"),
    (Deviation(-0.011, 0.004, 0.2, 0.1), 10, "within_tolerance"),
    (Deviation(-0.019, 0.004, 0.2, 0.1), 10, "not_enough_evidence"),  # inside, but not by 2 sigma (ISO 14253-1)
    (Deviation(0.005, 0.001, 0.35, 0.1), 10, "not_enough_evidence"),  # the tilt likewise
    (Deviation(0.06, 0.001, 0.1, 0.05), 2, "not_enough_evidence"),
    (Deviation(0.06, 0.03, 0.1, 0.05), 10, "not_enough_evidence"),
    (Deviation(0.10, 0.015, 0.1, 0.05), 10, "deviating"),  # uncertain, but far beyond tolerance
    (Deviation(0.01, 0.015, 0.1, 0.05), 10, "not_enough_evidence"),  # inside, but too uncertain to say so
    (Deviation(0.01, 0.002, 0.1, 0.9), 10, "not_enough_evidence"),
    (Deviation(0.025, 0.004, 0.1, 0.05), 10, "not_enough_evidence"),  # beyond, but not by 3 sigma
    (Deviation(0.03, 0.004, 0.1, 0.05), 10, "not_enough_evidence"),  # 2.5 sigma beyond: not sure enough
    (Deviation(0.0325, 0.004, 0.1, 0.05), 10, "deviating"),  # 3.1 sigma beyond
])
def test_status_rules(dev, n, status):
    assert classify(dev, n, CFG) == status


def test_status_follows_configured_tolerance():
    dev = Deviation(0.03, 0.002, 0.1, 0.05)
    assert classify(dev, 10, CFG) == "deviating"
    assert classify(dev, 10, DeviationConfig(tolerance_m=0.05)) == "within_tolerance"


def room_scene():
    """south: built 6 cm off, associated; east: 8 mm off, associated; north: never seen;
    west: 12 cm off, left unassociated by the graph; a 4 m^2 partition in the middle of the
    room; the floor; a small box side; a partition glimpsed in two keyframes. Every landmark
    is tightly estimated."""
    faces = {n: face(n) for n in WALLS}
    planes = [
        observed(0, as_built_plane(faces["south"], 0.06), face_id="south-face"),
        observed(1, as_built_plane(faces["east"], 0.008), face_id="east-face"),
        observed(2, as_built_plane(faces["west"], 0.12), extent_B=rectangle(0, 0.12, (0.5, 0.2), (3.5, 2.3)), area_m2=6.3),
        observed(3, np.array([1.0, 0.0, 0.0, -3.0]), extent_B=rectangle(0, 3.0, (1.0, 0.0), (3.0, 2.0)), area_m2=4.0),
        observed(4, np.array([0.0, 0.0, 1.0, 0.0]), extent_B=rectangle(2, 0.0, (0.5, 0.5), (5.5, 3.5)), area_m2=15.0),
        observed(5, np.array([0.0, 1.0, 0.0, -1.0]), extent_B=rectangle(1, 1.0, (1.7, 0.1), (2.3, 0.6)), area_m2=0.3),
        observed(6, np.array([1.0, 0.0, 0.0, -2.0]), extent_B=rectangle(0, 2.0, (1.0, 0.0), (3.0, 2.0)), area_m2=4.0,
                 n_keyframes=2),
    ]
    return room(), planes


def test_report_lists_every_case():
    plane_map, planes = room_scene()
    report = assess(plane_map, planes, T_S_B, CFG, expected_views={"north-face": 12, "south-face": 30})
    by_face = {f.face_id: f for f in report.faces}
    assert by_face["south-face"].status == "deviating"
    assert by_face["south-face"].deviation.offset_m == pytest.approx(0.06, abs=1e-3)
    assert by_face["south-face"].matched_by == "graph"
    assert by_face["east-face"].status == "within_tolerance"
    assert by_face["east-face"].deviation.offset_m == pytest.approx(0.008, abs=1e-3)
    assert by_face["west-face"].status == "deviating"
    assert by_face["west-face"].matched_by == "proximity"
    assert by_face["west-face"].deviation.offset_m == pytest.approx(0.12, abs=1e-3)
    assert by_face["north-face"].status == "possibly_not_built"
    assert by_face["north-face"].expected_keyframes == 12
    assert [u.landmark for u in report.unplanned] == [3]
    np.testing.assert_allclose(report.unplanned[0].plane_B, [1.0, 0.0, 0.0, -3.0], atol=1e-9)


def test_few_keyframes_or_large_sigma_is_not_enough_evidence():
    f = face("south")
    plane_map = room()
    few = assess(plane_map, [observed(0, as_built_plane(f, 0.06), face_id=f.id, n_keyframes=1)], T_S_B, CFG)
    vague = assess(plane_map, [observed(0, as_built_plane(f, 0.01), face_id=f.id, sigma=0.05)], T_S_B, CFG)
    assert few.faces[0].status == "not_enough_evidence"
    assert vague.faces[0].status == "not_enough_evidence"
    dev = vague.faces[0].deviation
    assert abs(dev.offset_m) + CFG.conformance_k * dev.offset_sigma_m > CFG.tolerance_m


def test_within_tolerance_only_inside_the_conformance_zone():
    """ISO 14253-1's decision rule: a face is within tolerance only where its offset lies
    inside the tolerance by k sigma. Measured 1.5 cm off at a sigma of 4 mm, it may well be
    built beyond 2 cm; 0.5 cm off, it is not."""
    f = face("south")

    def report(offset_m, cfg=CFG):
        return assess(room(), [observed(0, as_built_plane(f, offset_m), face_id=f.id)], T_S_B, cfg).faces[0]

    edge = report(0.015)
    assert edge.deviation.offset_sigma_m == pytest.approx(0.0042, abs=3e-4)
    assert edge.status == "not_enough_evidence"
    assert report(0.005).status == "within_tolerance"
    assert report(0.015, CFG.model_copy(update={"conformance_k": 0.0})).status == "within_tolerance"


def test_faces_seen_rarely_are_not_called_missing():
    plane_map, _ = room_scene()
    report = assess(plane_map, [], T_S_B, CFG, expected_views={"north-face": CFG.min_expected_keyframes - 1})
    assert report.faces == []
    report = assess(plane_map, [], T_S_B, CFG, expected_views={"north-face": CFG.min_expected_keyframes})
    assert [(f.face_id, f.status) for f in report.faces] == [("north-face", "possibly_not_built")]


def test_expected_in_view_by_ray_casting():
    """From near the west wall looking east, the east wall is in view and the west wall
    (behind) is not; a partition across the room hides the east wall."""
    T_B_C = np.stack([camera_looking((1.5, 2.0, 1.25), 0.0)] * 3)
    counts = expected_view_counts(room(), T_B_C, K, 640, 480, CFG)
    assert counts["east-face"] == 3
    assert counts["west-face"] == 0
    assert counts["north-face"] == 3  # its far end is in the image, seen at 60 degrees

    partition = BimFace(id="partition", wall_guid="0K1h3Qe3j8Nuv5bzvOkWdm", normal=(-1, 0, 0), offset=3.0,
                        polygon=[(3, 0, 0), (3, 4, 0), (3, 4, 2.5), (3, 0, 2.5)])
    plane_map = PlaneMap(faces=room().faces + [partition])
    counts = expected_view_counts(plane_map, T_B_C, K, 640, 480, CFG)
    assert counts["partition"] == 3
    assert counts["east-face"] == 0


def test_a_building_map_is_tested_near_the_walk_only_and_counted_whole():
    """The room among 40 copies of itself 10-400 m above (a building's map): the copies are
    out of range, counted 0; a partition whose corners and centre all lie 50 m off or more, but which crosses
    the room, still hides the east wall, and the counts of the room are those of the room
    alone with that partition."""
    T_B_C = np.stack([camera_looking((1.5, 2.0, 1.25), 0.0)] * 3)
    copies = [f.model_copy(update={"id": f"{f.id}-{k}"}) for k in range(1, 41) for f in
              (face(name, z0=10.0 * k) for name in WALLS)]
    partition = BimFace(id="partition", wall_guid="0K1h3Qe3j8Nuv5bzvOkWdm", normal=(-1, 0, 0), offset=3.0,
                        polygon=[(3, -150, 0), (3, 50, 0), (3, 50, 2.5), (3, -150, 2.5)])
    counts = expected_view_counts(PlaneMap(faces=room().faces + copies + [partition]), T_B_C, K, 640, 480, CFG)
    assert counts["partition"] == 3 and counts["east-face"] == 0
    assert len(counts) == 4 + 160 + 1 and all(counts[f.id] == 0 for f in copies)
    alone = expected_view_counts(PlaneMap(faces=room().faces + [partition]), T_B_C, K, 640, 480, CFG)
    assert alone == {face_id: n for face_id, n in counts.items() if face_id in alone}


def test_a_huge_face_is_sampled_coarser_not_without_bound():
    """A plane map in millimetres read as metres (a wall 13 km across) asked the grid for 24 GB.
    The grid is coarsened on such a face; the samples still stand for its whole area."""
    from bimgraph.deviations.visibility import _MAX_CELLS, sample_faces

    huge = BimFace(id="huge", wall_guid="0K1h3Qe3j8Nuv5bzvOkWdm", normal=(-1, 0, 0), offset=3000.0,
                   polygon=[(3000, 0, 0), (3000, 13000, 0), (3000, 13000, 2500), (3000, 0, 2500)])
    samples = sample_faces([huge, face("east")], 0.25)
    assert (samples.face == 0).sum() <= _MAX_CELLS
    assert samples.area_m2[samples.face == 0].sum() == pytest.approx(13000 * 2500, rel=0.01)
    # an ordinary face keeps the configured grid
    assert samples.area_m2[samples.face == 1][0] == 0.25**2


def test_a_face_near_the_end_of_the_range_is_in_view_and_one_beyond_is_not():
    """A 1 m panel facing the camera 4.7 m ahead (every sample within the 5 m range) is in
    view; moved 0.5 m farther it is not; a pose not known (NaN) sees nothing and takes
    nothing from the others."""
    assert CFG.visibility_max_range_m == 5.0

    def panel(x):
        return PlaneMap(faces=[BimFace(id="panel", wall_guid="0K1h3Qe3j8Nuv5bzvOkWdm", normal=(-1, 0, 0), offset=x,
                                       polygon=[(x, 1.5, 0.75), (x, 2.5, 0.75), (x, 2.5, 1.75), (x, 1.5, 1.75)])])

    T = camera_looking((1.5, 2.0, 1.25), 0.0)
    unknown = np.full((4, 4), np.nan)
    assert expected_view_counts(panel(6.2), np.stack([T, unknown, T]), K, 640, 480, CFG) == {"panel": 2}
    assert expected_view_counts(panel(6.7), np.stack([T]), K, 640, 480, CFG) == {"panel": 0}


def test_walls_of_another_storey_are_not_in_view_through_the_floor():
    """A camera in the room looks down toward a wall of the storey below: a map of walls alone
    gets a floor at each storey's elevation, which hides it (before, such walls of every
    other storey were listed as possibly not built); a map with slab faces is taken as it
    is, so the wall is seen through the slab's stairwell and hidden where the slab has none."""
    below = BimFace(id="below", wall_guid="0K1h3Qe3j8Nuv5bzvOkWdm", storey="basement", elevation=-3.0,
                    normal=(-1, 0, 0), offset=4.0, polygon=[(4, 0, -3), (4, 4, -3), (4, 4, 0), (4, 0, 0)])
    walls = [f.model_copy(update={"storey": "ground"}) for f in room().faces]
    pitch = np.radians(-40.0)  # down, about the camera's x axis
    tilt = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    T = camera_looking((1.5, 2.0, 1.25), 0.0)
    T[:3, :3] = T[:3, :3] @ tilt
    assert T[2, 2] < -0.5  # looking down
    T_B_C = np.stack([T] * 3)
    assert expected_view_counts(PlaneMap(faces=walls + [below]), T_B_C, K, 640, 480, CFG)["below"] == 0

    def floor(holes):
        return BimFace(id="floor", wall_guid="1hOSvn6df7F8_7GcBWlRGR", kind="slab_top", storey="ground", normal=(0, 0, 1),
                       offset=0.0, polygon=[(0, 0, 0), (6, 0, 0), (6, 4, 0), (0, 4, 0)], holes=holes)

    stairwell = [(2.5, 0.5, 0), (3.9, 0.5, 0), (3.9, 3.5, 0), (2.5, 3.5, 0)]
    assert expected_view_counts(PlaneMap(faces=walls + [below, floor([stairwell])]), T_B_C, K, 640, 480, CFG)["below"] == 3
    assert expected_view_counts(PlaneMap(faces=walls + [below, floor([])]), T_B_C, K, 640, 480, CFG)["below"] == 0


def test_a_face_in_view_never_observed_is_possibly_not_built():
    """Looking at the north wall from the room's south side for six keyframes, with landmarks
    for the other walls only."""
    plane_map, planes = room_scene()
    T_B_C = np.stack([camera_looking((3.0 + 0.1 * i, 0.8, 1.3), 90.0) for i in range(6)])
    expected = expected_view_counts(plane_map, T_B_C, K, 640, 480, CFG)
    assert expected["north-face"] == 6 and expected["south-face"] == 0
    report = assess(plane_map, planes, T_S_B, CFG, expected)
    (north,) = [f for f in report.faces if f.face_id == "north-face"]
    assert north.status == "possibly_not_built" and north.expected_keyframes == 6
    assert north.deviation is None


def test_one_landmark_measures_every_face_of_its_wall_plane():
    """The plan splits the south wall into two faces; the one landmark on it, associated with
    the first, measures the second too; a landmark not over a face does not."""
    halves = [BimFace(id=f"south-{i}", wall_guid=GUIDS["south"], normal=(0, 1, 0), offset=0.0,
                      polygon=[(x0, 0, 0), (x0 + 3, 0, 0), (x0 + 3, 0, 2.5), (x0, 0, 2.5)])
              for i, x0 in enumerate([0.0, 3.0])]
    far = BimFace(id="south-far", wall_guid=GUIDS["south"], normal=(0, 1, 0), offset=0.0,
                  polygon=[(20, 0, 0), (23, 0, 0), (23, 0, 2.5), (20, 0, 2.5)])
    plane_map = PlaneMap(faces=halves + [far])
    plane_B = as_built_plane(halves[0], 0.05)
    lm = observed(0, plane_B, face_id="south-0", extent_B=rectangle(1, 0.05, (0.5, 0.2), (5.5, 2.3)), area_m2=10.5)
    report = assess(plane_map, [lm], T_S_B, CFG)
    by_face = {f.face_id: f for f in report.faces}
    assert set(by_face) == {"south-0", "south-1"}
    assert by_face["south-1"].matched_by == "proximity" and by_face["south-1"].landmark == 0
    assert by_face["south-1"].deviation.offset_m == pytest.approx(0.05, abs=1e-3)
    assert report.unplanned == []


def test_a_landmark_does_not_measure_the_face_hidden_behind_its_own():
    """A furring wall 15 cm in front of a party wall's face (as in the Duplex sample model):
    the landmark on the furring's face measures it, not the party wall's face behind it,
    which it also passes the proximity tests of, whether the graph matched it to the furring
    or not; without the furring in the plan, it measures the party wall by proximity, as a
    wall built far off plan must be measured."""
    party = BimFace(id="party", wall_guid=GUIDS["south"], normal=(0, 1, 0), offset=0.0,
                    polygon=[(0, 0, 0), (6, 0, 0), (6, 0, 2.5), (0, 0, 2.5)])
    furring = BimFace(id="furring", wall_guid=GUIDS["north"], normal=(0, 1, 0), offset=-0.15,
                      polygon=[(0, 0.15, 0), (6, 0.15, 0), (6, 0.15, 2.5), (0, 0.15, 2.5)])
    plane_map = PlaneMap(faces=[party, furring])
    extent = rectangle(1, 0.15, (0.5, 0.2), (5.5, 2.3))
    matched = observed(0, as_built_plane(furring, 0.0), face_id="furring", extent_B=extent, area_m2=10.5)
    report = assess(plane_map, [matched], T_S_B, CFG)
    assert [f.face_id for f in report.faces] == ["furring"]
    assert report.faces[0].status == "within_tolerance"
    unmatched = observed(0, as_built_plane(furring, 0.0), extent_B=extent, area_m2=10.5)
    (measured,) = assess(plane_map, [unmatched], T_S_B, CFG).faces
    assert measured.face_id == "furring" and measured.matched_by == "proximity"
    (measured,) = assess(PlaneMap(faces=[party]), [unmatched], T_S_B, CFG).faces
    assert measured.face_id == "party" and measured.deviation.offset_m == pytest.approx(0.15, abs=1e-3)



def test_joint_marginals_at_once_equal_gtsams_one_by_one():
    """The offline estimator's joint marginals (one marginalisation onto all the keys asked
    about) are gtsam's, block for block and in the order asked, Cauchy weights included."""
    graph, result, E, _ = room_graph("east", 0.06)
    marginals = gtsam.Marginals(graph, result)
    keys = [E, X(0), X(1)] + [L(j) for j in range(len(WALLS))]
    joint = JointMarginals(graph, result, keys)
    for subset in ([E, X(0), L(1)], [L(2), E], [X(1), L(0), X(0)], keys[::-1]):
        np.testing.assert_allclose(joint(subset), joint_covariance(marginals, subset), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(joint.marginal(E), marginals.marginalCovariance(E), rtol=1e-9, atol=1e-15)


def test_a_glimpse_does_not_measure_a_face_a_well_seen_landmark_measures():
    """The west wall, built 12 cm off (too far for the graph's gate), has a landmark seen in 40
    keyframes and a two-keyframe glimpse 3 mm closer to plan: the first measures it, and
    neither is called unplanned."""
    west = face("west")
    planes = [observed(2, as_built_plane(west, 0.12), n_keyframes=40, extent_B=rectangle(0, 0.12, (0.5, 0.2), (3.5, 2.3)), area_m2=6.3),
              observed(7, as_built_plane(west, 0.117), n_keyframes=2, extent_B=rectangle(0, 0.117, (0.6, 0.2), (3.4, 2.3)), area_m2=5.9)]
    report = assess(room(), planes, T_S_B, CFG)
    (west_report,) = report.faces
    assert west_report.landmark == 2 and west_report.status == "deviating" and west_report.n_keyframes == 40
    assert report.unplanned == []


def test_a_plane_on_a_face_is_never_unplanned():
    """A second landmark on the south wall, which the graph measures by another, is that
    wall's, not a plane the model lacks."""
    south = face("south")
    planes = [observed(0, as_built_plane(south, 0.06), face_id="south-face"),
              observed(8, as_built_plane(south, 0.061), extent_B=rectangle(1, 0.061, (0.5, 0.2), (5.5, 2.3)), area_m2=10.5)]
    report = assess(room(), planes, T_S_B, CFG)
    assert [(f.face_id, f.landmark, f.matched_by) for f in report.faces] == [("south-face", 0, "graph")]
    assert report.unplanned == []


def test_one_unplanned_plane_seen_on_two_visits_is_listed_once():
    """Two landmarks of one partition across the room (two visits the SLAM association did
    not join) are one unplanned plane, with the better-seen one's plane and both's keyframes;
    a parallel partition a metre away is another."""
    partition = [observed(3, np.array([1.0, 0.0, 0.0, -3.0]), n_keyframes=14,
                          extent_B=rectangle(0, 3.0, (1.0, 0.0), (3.0, 2.0)), area_m2=4.0),
                 observed(5, np.array([1.0, 0.0, 0.0, -3.01]), n_keyframes=11,
                          extent_B=rectangle(0, 3.01, (1.2, 0.0), (3.1, 2.0)), area_m2=3.8),
                 observed(6, np.array([1.0, 0.0, 0.0, -4.0]), n_keyframes=5,
                          extent_B=rectangle(0, 4.0, (1.0, 0.0), (3.0, 2.0)), area_m2=4.0)]
    report = assess(room(), partition, T_S_B, CFG)
    assert [(u.landmark, u.n_keyframes) for u in report.unplanned] == [(3, 25), (6, 5)]
