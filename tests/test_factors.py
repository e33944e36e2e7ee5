"""The plane factors: analytic Jacobians against central differences, the C++ factors the
graph uses against the Python reference, robust kernels, and the geometry they encode."""

import gtsam
import numpy as np
import pytest

from bimgraph.geometry import normalise_plane, plane_to_frame
from factors import (
    local_plane_custom_factor,
    local_plane_error,
    local_plane_factor,
    plane_prior_error,
    plane_prior_factor,
    plane_to_bim_custom_factor,
    plane_to_bim_factor,
)

E, XA, L = 10, 20, 30


def random_pose(rng, scale=3.0):
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * scale)


def random_case(rng):
    """Two poses, a plane in the anchor and a measurement near the predicted plane."""
    T_W_i, T_W_a = random_pose(rng), random_pose(rng)
    plane_a = gtsam.OrientedPlane3(normalise_plane(rng.normal(size=4)))
    predicted = plane_a.transform(T_W_a.between(T_W_i)).planeCoefficients()
    z = normalise_plane(predicted + rng.normal(size=4) * 0.05)
    return T_W_i, T_W_a, plane_a, z


def numerical_jacobians(T_W_i, T_W_a, plane_a, z, h=1e-6):
    def f(args):
        return local_plane_error(*args, z)

    base = [T_W_i, T_W_a, plane_a]
    out = []
    for slot, dim in enumerate([6, 6, 3]):
        J = np.zeros((3, dim))
        for k in range(dim):
            delta = np.zeros(dim)
            delta[k] = h
            plus, minus = list(base), list(base)
            plus[slot] = base[slot].retract(delta)
            minus[slot] = base[slot].retract(-delta)
            J[:, k] = (f(plus) - f(minus)) / (2 * h)
        out.append(J)
    return out


@pytest.mark.parametrize("seed", range(20))
def test_analytic_jacobians_match_numerical(seed):
    rng = np.random.default_rng(seed)
    case = random_case(rng)
    _, analytic = local_plane_error(*case, jacobians=True)
    assert len(analytic) == 3
    for J, J_num in zip(analytic, numerical_jacobians(*case), strict=True):
        np.testing.assert_allclose(J, J_num, atol=1e-7)


@pytest.mark.parametrize("seed", range(10))
def test_predicted_plane_jacobian_matches_numerical(seed):
    """The whole 4x15 Jacobian of `predict_local_plane` (the association propagates
    covariances through it raw, not only through the residual's 3x4 projection)."""
    from factors.plane import predict_local_plane

    T_W_i, T_W_a, plane_a, _ = random_case(np.random.default_rng(200 + seed))
    _, J = predict_local_plane(T_W_i, T_W_a, plane_a, jacobian=True)
    base, h, columns = [T_W_i, T_W_a, plane_a], 1e-6, []
    for slot, dim in enumerate([6, 6, 3]):
        for k in range(dim):
            plus, minus = list(base), list(base)
            plus[slot] = base[slot].retract(np.eye(dim)[k] * h)
            minus[slot] = base[slot].retract(-np.eye(dim)[k] * h)
            columns.append((predict_local_plane(*plus) - predict_local_plane(*minus)) / (2 * h))
    np.testing.assert_allclose(J, np.column_stack(columns), atol=1e-7)


def test_extrinsic_covariance_maps_are_the_numerical_ones():
    """`extrinsic_cov_E` (T_B_S's covariance to E = T_S_B's) and `cov_T_B_S` (back): each
    is J C J^T with J the numerical Jacobian of the inverse in gtsam's right-perturbation
    tangent; and one undoes the other."""
    from bimgraph.backend.graph import cov_T_B_S, extrinsic_cov_E

    rng = np.random.default_rng(7)
    T_B_S = random_pose(rng)
    A = rng.normal(size=(6, 6))
    cov = A @ A.T + 0.1 * np.eye(6)
    T_S_B = T_B_S.inverse()
    J = np.column_stack([(T_S_B.localCoordinates(T_B_S.retract(step).inverse())
                          - T_S_B.localCoordinates(T_B_S.retract(-step).inverse())) / 2e-6 for step in np.eye(6) * 1e-6])
    np.testing.assert_allclose(extrinsic_cov_E(T_B_S.matrix(), cov), J @ cov @ J.T, rtol=1e-6, atol=1e-9)
    K = np.linalg.inv(J)  # (the inverse's Jacobian at T_S_B)
    np.testing.assert_allclose(cov_T_B_S(T_S_B, cov), K @ cov @ K.T, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(cov_T_B_S(T_S_B, extrinsic_cov_E(T_B_S.matrix(), cov)), cov, rtol=1e-9, atol=1e-12)


def values_of(T_W_i, T_W_a, plane_a):
    values = gtsam.Values()
    values.insert(E, T_W_i)
    values.insert(XA, T_W_a)
    values.insert(L, plane_a)
    return values


@pytest.mark.parametrize("make_cpp, make_py", [(local_plane_factor, local_plane_custom_factor),
                                               (plane_to_bim_factor, plane_to_bim_custom_factor)])
@pytest.mark.parametrize("seed", range(10))
def test_cpp_factor_agrees_with_python_reference(make_cpp, make_py, seed):
    rng = np.random.default_rng(100 + seed)
    case = random_case(rng)
    values = values_of(*case[:3])
    noise = gtsam.noiseModel.Diagonal.Sigmas([0.02, 0.03, 0.05])
    cpp, py = make_cpp(case[3], noise, E, XA, L), make_py(case[3], noise, E, XA, L)
    np.testing.assert_allclose(cpp.unwhitenedError(values), local_plane_error(*case), atol=1e-12)
    A_cpp, b_cpp = cpp.linearize(values).jacobian()
    A_py, b_py = py.linearize(values).jacobian()
    np.testing.assert_allclose(A_cpp, A_py, atol=1e-9)
    np.testing.assert_allclose(b_cpp, b_py, atol=1e-9)


def test_robust_kernel_on_both_factors():
    rng = np.random.default_rng(7)
    case = random_case(rng)
    values = values_of(*case[:3])
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
                                            gtsam.noiseModel.Isotropic.Sigma(3, 0.01))
    gaussian = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    cpp_robust = plane_to_bim_factor(case[3], robust, E, XA, L)
    py_robust = plane_to_bim_custom_factor(case[3], robust, E, XA, L)
    cpp_gauss = plane_to_bim_factor(case[3], gaussian, E, XA, L)
    assert cpp_robust.error(values) == pytest.approx(py_robust.error(values), rel=1e-12)
    # a large residual is down-weighted: Cauchy's rho grows like log, the Gaussian's like r^2
    assert cpp_robust.error(values) < 0.1 * cpp_gauss.error(values)


def test_plane_to_bim_residual_is_the_landmark_mapped_into_B():
    rng = np.random.default_rng(3)
    T_S_B, T_S_Ca = random_pose(rng), random_pose(rng)
    plane_B = normalise_plane([0.0, 1.0, 0.0, -4.0])
    T_Ca_B = np.linalg.inv(T_S_Ca.matrix()) @ T_S_B.matrix()
    plane_Ca = plane_to_frame(plane_B, np.linalg.inv(T_Ca_B))  # the face seen from the anchor
    e = local_plane_error(T_S_B, T_S_Ca, gtsam.OrientedPlane3(plane_Ca), plane_B)
    np.testing.assert_allclose(e, 0.0, atol=1e-12)
    # 5 cm off along the normal shows as 5 cm in the offset part
    moved = plane_Ca + np.r_[0, 0, 0, 0.05]
    e = local_plane_error(T_S_B, T_S_Ca, gtsam.OrientedPlane3(moved), plane_B)
    np.testing.assert_allclose(e, [0, 0, -0.05], atol=1e-12)


def test_plane_to_bim_factors_recover_the_extrinsic():
    """Three orthogonal faces observed from one anchor fix T_S_B; LM on the C++ factors finds it."""
    rng = np.random.default_rng(11)
    T_S_B = random_pose(rng, 2.0)
    T_S_Ca = random_pose(rng, 2.0)
    faces_B = [normalise_plane(p) for p in ([1, 0, 0, -1], [0, 1, 0, 2], [0, 0, 1, 0.5])]
    T_Ca_B = T_S_Ca.between(T_S_B).matrix()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(XA, T_S_Ca, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    values.insert(XA, T_S_Ca)
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    for j, plane_B in enumerate(faces_B):
        plane_Ca = plane_to_frame(plane_B, np.linalg.inv(T_Ca_B))
        graph.add(plane_prior_factor(plane_Ca, gtsam.noiseModel.Isotropic.Sigma(3, 1e-4), L + j))
        graph.add(plane_to_bim_factor(plane_B, noise, E, XA, L + j))
        values.insert(L + j, gtsam.OrientedPlane3(plane_Ca))
    graph.add(gtsam.PriorFactorPose3(E, T_S_B, gtsam.noiseModel.Isotropic.Sigma(6, 10.0)))
    values.insert(E, T_S_B.retract(np.r_[0.05, -0.03, 0.04, 0.3, -0.2, 0.25]))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    np.testing.assert_allclose(result.atPose3(E).matrix(), T_S_B.matrix(), atol=1e-5)


def test_plane_prior_factor():
    """Its residual is `plane_prior_error` whitened by the noise; its Jacobian, at the
    measurement, the numerical one of that (with a correlated covariance, as observations'
    are, so that a transposed whitening shows); away from it, `LinearContainerFactor` keeps
    that Jacobian (the documented approximation)."""
    rng = np.random.default_rng(5)
    z = normalise_plane(rng.normal(size=4))
    A_ = rng.normal(size=(3, 3)) * 0.01
    cov = A_ @ A_.T + np.diag([1e-4, 4e-4, 9e-4])
    noise = gtsam.noiseModel.Gaussian.Covariance(cov)
    factor = plane_prior_factor(z, noise, L)
    measured = gtsam.OrientedPlane3(z)

    def whitened(delta):
        return noise.R() @ plane_prior_error(measured.retract(delta), z)

    numerical = np.column_stack([(whitened(step) - whitened(-step)) / 2e-6 for step in np.eye(3) * 1e-6])
    at = gtsam.Values()
    at.insert(L, measured)
    A, b = factor.linearize(at).jacobian()
    np.testing.assert_allclose(A, numerical, atol=1e-6)
    np.testing.assert_allclose(b, 0.0, atol=1e-12)

    plane = measured.retract(np.array([0.01, -0.02, 0.03]))
    values = gtsam.Values()
    values.insert(L, plane)
    e = plane_prior_error(plane, z)
    np.testing.assert_allclose(e, [0.01, -0.02, 0.03], atol=1e-12)
    assert factor.error(values) == pytest.approx(0.5 * e @ np.linalg.solve(cov, e), rel=1e-9)
    np.testing.assert_allclose(factor.linearize(values).jacobian()[0], A, atol=1e-12)


def test_same_pose_and_anchor_key_is_refused():
    with pytest.raises(ValueError, match="different keys"):
        local_plane_factor([0, 0, 1, 1], gtsam.noiseModel.Unit.Create(3), XA, XA, L)


@pytest.mark.parametrize("seed", range(5))
def test_gravity_factor_measures_tilt_not_heading(seed):
    """The attitude factor of gravity-aligned sequences: residual = the keyframe's up
    direction against the front-end's, zero under any turn about S's z, about the tilt angle
    under a small tilt; its Jacobian (gtsam's, whitened) against central differences."""
    from bimgraph.backend.graph import X, FactorBuilder
    from bimgraph.config import BackendConfig

    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    factor = FactorBuilder(BackendConfig()).gravity(0, T.matrix())
    sigma = np.radians(BackendConfig().noise.gravity_deg)

    def error(pose):
        values = gtsam.Values()
        values.insert(X(0), pose)
        return factor.unwhitenedError(values)

    np.testing.assert_allclose(error(T), 0.0, atol=1e-12)
    np.testing.assert_allclose(error(gtsam.Pose3(gtsam.Rot3.Rz(rng.uniform(-3, 3)), np.zeros(3)) * T), 0.0, atol=1e-9)
    tilt = 0.01 * np.r_[np.cos(seed), np.sin(seed), 0.0]
    assert np.linalg.norm(error(gtsam.Pose3(gtsam.Rot3.Expmap(tilt), np.zeros(3)) * T)) == pytest.approx(0.01, rel=1e-3)

    at = T.retract(rng.normal(size=6) * 0.05)
    values = gtsam.Values()
    values.insert(X(0), at)
    A, _ = factor.linearize(values).jacobian()
    h = 1e-6
    numerical = np.column_stack([(error(at.retract(h * e)) - error(at.retract(-h * e))) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(A * sigma, numerical, atol=1e-7)


@pytest.mark.parametrize("seed", range(5))
def test_face_tolerance_is_about_the_face_centre(seed):
    """The plane-to-BIM noise: mapped to (offset at the face centre, two tilts), as the
    deviation report reads a residual, it is the configured tolerance, wherever the face lies
    from B's origin; and a plane turned about the face centre within the tolerance scores as
    little as one turned about the origin's foot does for a face through the origin; with a
    plumb tolerance, leaning out of plumb is scored by it."""
    from bimgraph.bim.planemap import BimFace
    from bimgraph.deviations.estimate import deviation_terms
    from factors import face_tolerance_cov

    rng = np.random.default_rng(seed)
    n = normalise_plane(np.r_[rng.normal(size=2), 0.0, 0.0])[:3]
    centre = rng.normal(size=3) * 15.0
    plane = np.r_[n, -n @ centre]
    basis = gtsam.Unit3(n).basis()
    face = BimFace(id="f/0", wall_guid="f", normal=tuple(n), offset=float(plane[3]),
                   polygon=[tuple(centre), tuple(centre + basis[:, 0]), tuple(centre + basis[:, 1])], area=1.0,
                   centre=tuple(centre))
    cov = face_tolerance_cov(basis, centre, 0.01, 0.02)
    _, H = deviation_terms(np.zeros(3), face)
    np.testing.assert_allclose(H @ cov @ H.T, np.diag([0.02**2, 0.01**2, 0.01**2]), atol=1e-12)
    # a built plane turned by 0.01 rad about a vertical axis through the face centre
    def score(cov, rotation):
        built_n = rotation @ n
        e = np.r_[basis.T @ built_n, plane[3] + built_n @ centre]
        return e @ np.linalg.solve(cov, e)

    assert score(cov, gtsam.Rot3.Rz(0.01).matrix()) == pytest.approx(1.0, rel=0.01)  # first order in the angle
    # with a plumb tolerance of its own: leaning 0.002 rad scores as turning 0.01 rad does
    cov = face_tolerance_cov(basis, centre, 0.01, 0.02, 0.002)
    horizontal = np.cross([0.0, 0.0, 1.0], n)
    assert score(cov, gtsam.Rot3.Rz(0.01).matrix()) == pytest.approx(1.0, rel=0.01)
    assert score(cov, gtsam.Rot3.Rodrigues(0.002 * horizontal).matrix()) == pytest.approx(1.0, rel=0.01)


@pytest.mark.parametrize("inclination_deg", [0.0, 45.0])
def test_face_tolerance_of_level_and_inclined_faces(inclination_deg):
    """With a plumb tolerance: a level face (a slab) tilts out of level by that sigma whichever
    way; a face inclined 45 deg turns about the vertical by the mean of the two variances."""
    from factors import face_tolerance_cov

    incl = np.radians(inclination_deg)
    n = np.array([np.sin(incl), 0.0, np.cos(incl)])
    centre = np.array([2.0, -3.0, 1.0])
    basis = gtsam.Unit3(n).basis()
    cov = face_tolerance_cov(basis, centre, 0.01, 0.02, 0.002)

    def score(rotation):
        built_n = rotation @ n
        e = np.r_[basis.T @ built_n, -n @ centre + built_n @ centre]
        return e @ np.linalg.solve(cov, e)

    if inclination_deg == 0.0:
        for axis in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]):
            axis = np.asarray(axis) / np.linalg.norm(axis)
            assert score(gtsam.Rot3.Rodrigues(0.002 * axis).matrix()) == pytest.approx(1.0, rel=0.01)
    else:
        turn = np.sqrt(0.5 * 0.01**2 + 0.5 * 0.002**2)  # the blended sigma of the turn about z
        # turning about z by a moves the normal by a sin(incl) along the horizontal direction
        assert score(gtsam.Rot3.Rz(turn / np.sin(incl)).matrix()) == pytest.approx(1.0, rel=0.02)
        horizontal = np.cross([0.0, 0.0, 1.0], n) / np.sin(incl)
        assert score(gtsam.Rot3.Rodrigues(0.002 * horizontal).matrix()) == pytest.approx(1.0, rel=0.01)
