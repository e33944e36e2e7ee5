"""The depth sensor's tilt variable: its closed-form sensitivity against planes refitted to the
simulator's tilted depth, the tie against the prediction it stands for, the online estimator
with it, and a run that turns it on."""

import gtsam
import numpy as np
import pytest
from synthetic_sequence import write_sequence

from bimgraph.backend import Backend, run_offline
from bimgraph.backend.depth_tilt import DepthTilt
from bimgraph.backend.graph import MOVED_ANCHOR, TILT, X
from bimgraph.backend.pipeline import run as run_pipeline
from bimgraph.backend.results import load_summary
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig, Config
from bimgraph.evaluation.metrics import extrinsic_error, extrinsic_nees
from bimgraph.evaluation.runs import run_summary
from bimgraph.geometry import normalise_plane
from bimgraph.sequence.format import Camera
from bimgraph.sim.render import distortion_basis
from factors import anchor_step, predict_local_plane, tilt_link_factor, tilt_sensitivity

TILT_SIGMA = 0.002
# (TUM RGB-D's freiburg1 camera: its principal point is off the image's centre)
CAMERA = Camera(width=640, height=480, fx=517.3, fy=516.5, cx=318.6, cy=255.3)


def fit_plane(points: np.ndarray, n_ref: np.ndarray) -> np.ndarray:
    centre = points.mean(axis=0)
    n = np.linalg.svd(points - centre)[2][2]
    n = n if n @ n_ref > 0 else -n
    return np.array([*n, -n @ centre])


def refit_sensitivity(plane_C: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """d(n, d)/d(t1, t2) by central differences of a plane fitted to the pixels (every 8th) it
    covers, their depth tilted as the simulator tilts it (`systematic_depth_error`)."""
    v, u = np.mgrid[0:CAMERA.height:8, 0:CAMERA.width:8]
    rays = np.stack([(u - CAMERA.cx) / CAMERA.fx, (v - CAMERA.cy) / CAMERA.fy, np.ones(u.shape)], axis=-1)
    facing = rays @ plane_C[:3] < -1e-3
    z = -plane_C[3] / (rays @ plane_C[:3])
    basis = distortion_basis(CAMERA.height, CAMERA.width)[:2, ::8, ::8]
    G = np.zeros((4, 2))
    for i in range(2):
        fits = [fit_plane((rays * (z + s * basis[i] * z * z)[..., None])[facing], plane_C[:3]) for s in (eps, -eps)]
        G[:, i] = (fits[0] - fits[1]) / (2 * eps)
    return G


@pytest.mark.parametrize("plane_C", [
    [0, 0, -1, 3.0],  # a wall ahead
    [-0.8, 0, -0.6, 2.0],  # a side wall, obliquely
    [0, -1, 0, 1.4],  # the floor (y down)
    [0.3, -0.5, -0.81, 2.5],
])
def test_sensitivity_matches_a_refit_of_the_simulators_tilted_depth(plane_C):
    plane_C = normalise_plane(np.array(plane_C, dtype=float))
    G = tilt_sensitivity(plane_C, DepthTilt(CAMERA, TILT_SIGMA).dm_dtau)
    G_refit = refit_sensitivity(plane_C)
    assert np.abs(G - G_refit).max() < 1e-3 * np.abs(G_refit).max()


def _case(rng):
    """A keyframe's pose, a landmark's anchor pose and its plane in the anchor, which the
    keyframe sees in front of it (d > 0)."""
    T_S_C = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.5), rng.normal(size=3))
    T_S_A = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.5), rng.normal(size=3))
    n_C = normalise_plane(np.array([*rng.normal(size=2) * 0.4, -1.0, 0.0]))[:3]
    plane_S = gtsam.OrientedPlane3(np.array([*n_C, 2.5])).transform(T_S_C.inverse())
    return T_S_C, T_S_A, plane_S.transform(T_S_A)


@pytest.mark.parametrize("seed", range(5))
def test_the_link_moves_the_predicted_plane_as_the_tilt_does(seed):
    """With the moved anchor at `anchor * Exp(K tau)` the link holds, and the plane predicted
    from it has moved by `G tau` (to first order: a central difference); the anchor's own
    observation likewise."""
    rng = np.random.default_rng(seed)
    tilt = DepthTilt(CAMERA, TILT_SIGMA)
    T_S_C, T_S_A, plane_A = _case(rng)
    tau = rng.normal(size=2) * 1e-6
    for T_S_K in (T_S_C, T_S_A):
        plane_K, J = predict_local_plane(T_S_K, T_S_A, plane_A, jacobian=True)
        K = anchor_step(plane_K, J[:, 6:12], tilt.dm_dtau)
        moved = [predict_local_plane(T_S_K, T_S_A.retract(s * K @ tau), plane_A) for s in (1, -1)]
        G = tilt_sensitivity(plane_K, tilt.dm_dtau)
        assert np.allclose((moved[0] - moved[1]) / 2, G @ tau, rtol=1e-4, atol=1e-12)

        link = tilt_link_factor(X(1), MOVED_ANCHOR(0), TILT(7), T_S_A, K, tilt.link_noise)
        values = gtsam.Values()
        values.insert(X(1), T_S_A)
        values.insert(TILT(7), tau * 1e3)
        values.insert(MOVED_ANCHOR(0), T_S_A.retract(K @ tau * 1e3))
        unmoved = gtsam.Values(values)
        unmoved.update(MOVED_ANCHOR(0), T_S_A)
        assert link.error(values) < 1e-12 * link.error(unmoved)


def tilted_keyframes(scene, sigma: float, seed: int):
    """The scene's keyframes with every plane of a keyframe moved by one tilt drawn for it, and
    each covariance grown by the tilt's share (as the plane extractor's systematic floor
    grows it): each plane alone stays consistent with its covariance."""
    rng = np.random.default_rng(seed)
    dm_dtau = DepthTilt(CAMERA, sigma).dm_dtau
    out = []
    for kf in scene.keyframes:
        tau = rng.normal(size=2) * sigma
        planes = []
        for p in kf.planes:
            G = tilt_sensitivity(np.array([*p.n, p.d]), dm_dtau)
            moved = normalise_plane(np.array([*p.n, p.d]) + G @ tau)
            G_tangent = np.vstack([gtsam.Unit3(moved[:3]).basis().T @ G[:3], G[3:]])
            cov = np.array(p.cov) + sigma**2 * G_tangent @ G_tangent.T
            planes.append(p.model_copy(update={"n": tuple(moved[:3]), "d": float(moved[3]), "cov": cov.tolist()}))
        out.append(kf.model_copy(update={"planes": planes}))
    return out


def final_extrinsic(scene, keyframes, tilt):
    backend = Backend(scene.plane_map, BackendConfig(), scene.initial, tilt=tilt)
    result = [backend.process(kf) for kf in keyframes][-1]
    return backend, result


@pytest.mark.parametrize("mode", ["online", "offline"])
def test_the_tilt_variable_takes_out_the_error_a_keyframes_planes_share(mode):
    """Planes tilted together per keyframe (4 mm per m^2 at the image's border): taken as
    independent, the extrinsic's heading is off by several of its sigmas; with the tilt
    variable, closer and honest (measured on seeds 0-9 online: heading RMS 0.39 -> 0.23 deg,
    mean NEES 5.0 -> 0.7; offline, seeds 0-5: 0.35 -> 0.23 deg, 4.0 -> 1.7)."""
    sigma, errors, nees = 0.004, {False: [], True: []}, {False: [], True: []}
    for seed in range(6):
        scene = make_scene(200, rooms=(2, 2), seed=seed, normal_sigma_deg=0.1, offset_sigma_m=0.003)
        keyframes = tilted_keyframes(scene, sigma, seed)
        for with_tilt in (False, True):
            tilt = DepthTilt(CAMERA, sigma) if with_tilt else None
            if mode == "online":
                result = final_extrinsic(scene, keyframes, tilt)[1]
            else:
                result = run_offline(keyframes, scene.plane_map, BackendConfig(), scene.initial, tilt=tilt)
            errors[with_tilt].append(extrinsic_error(result.T_B_S, scene.T_B_S)[0])
            nees[with_tilt].append(extrinsic_nees(result.T_B_S, result.cov_T_B_S, scene.T_B_S))
    rms = {key: np.sqrt(np.mean(np.square(value))) for key, value in errors.items()}
    assert rms[True] < 0.75 * rms[False]
    assert np.mean(nees[True]) < 2.0 and np.mean(nees[False]) > 3.0


def test_a_negligible_tilt_leaves_the_estimate_as_without_it():
    """With a tilt sigma far below the planes' own, the moved anchors are the anchors: the same
    estimate, and every keyframe with planes has its tilt variable."""
    scene = make_scene(120, rooms=(2, 2), seed=1)
    plain, without = final_extrinsic(scene, scene.keyframes, None)
    backend, with_tilt = final_extrinsic(scene, scene.keyframes, DepthTilt(CAMERA, 1e-7))
    # (iSAM2's estimate depends on its path, and the anchor's own observation is a plane prior
    # without the tilt, a plane factor from the moved anchor with it)
    deg, cm = extrinsic_error(with_tilt.T_B_S, without.T_B_S)
    assert deg < 0.02 and cm < 0.1
    assert [a.landmark for a in with_tilt.associations] == [a.landmark for a in without.associations]
    values = backend.graph.estimate()
    assert all(values.exists(TILT(kf.index)) == bool(kf.planes) for kf in scene.keyframes)
    assert values.exists(MOVED_ANCHOR(0)) and not plain.graph.estimate().exists(MOVED_ANCHOR(0))


def test_a_run_models_the_tilt_for_planes_from_depth_and_says_so(tmp_path):
    """`bimgraph run` gives a `sensor: depth` sequence the tilt variable, online and offline,
    and its summary and printout say so; a planes sequence, or the setting off: none."""
    write_sequence(tmp_path / "depth", 40, rooms=(1, 1), sensor="depth")
    write_sequence(tmp_path / "planes", 40, rooms=(1, 1))
    off = Config.model_validate({"backend": {"noise": {"depth_tilt": False}}})
    for seq, mode, cfg, expected in [("depth", "online", Config(), Config().depth_noise.tilt_sigma_per_m),
                                     ("depth", "offline", Config(), Config().depth_noise.tilt_sigma_per_m),
                                     ("planes", "online", Config(), None),
                                     ("depth", "online", off, None)]:
        out = tmp_path / f"{seq}-{mode}-{cfg is off}"
        run_pipeline(tmp_path / seq, out, mode=mode, config=cfg)
        assert load_summary(out / "summary.json").depth_tilt_sigma_per_m == expected
        assert ("depth tilt" in dict(run_summary(out))) == (expected is not None)
