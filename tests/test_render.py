"""The depth renderer against an independent numpy ray caster, and the depth noise model."""

import numpy as np
import pytest

from depth_scenes import CAMERA, look_at, room, viewpoints

from bimgraph.config import DepthNoiseConfig
from bimgraph.sim.render import DepthRenderer, add_depth_noise, pixel_rays

SMALL = CAMERA.model_copy(update=dict(width=160, height=120, fx=131.25, fy=131.25, cx=79.5, cy=59.5))


def reference_cast(vertices, triangles, ids, camera, T_B_C):
    """Nearest hit of every pixel ray by Moller-Trumbore over all triangles, in float64."""
    dirs = (pixel_rays(camera) @ T_B_C[:3, :3].T).reshape(-1, 3)
    origin = T_B_C[:3, 3]
    best_t = np.full(len(dirs), np.inf)
    best_id = np.full(len(dirs), -1)
    for tri, face_id in zip(triangles, ids):
        a, b, c = vertices[tri]
        e1, e2 = b - a, c - a
        p = np.cross(dirs, e2)
        det = p @ e1
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origin - a
        u = (p @ s) * inv
        q = np.cross(s, e1)
        v = (dirs @ q) * inv
        t = (q @ e2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < best_t)
        best_t[hit] = t[hit]
        best_id[hit] = face_id
    shape = (camera.height, camera.width)
    return np.where(np.isfinite(best_t), best_t, 0.0).reshape(shape), best_id.reshape(shape)


def test_depth_and_ids_match_independent_ray_caster():
    scene = room()
    vertices, triangles, ids = scene.arrays()
    renderer = DepthRenderer(vertices, triangles, ids)
    for T_B_C in viewpoints(np.random.default_rng(1), 4):
        depth, face = renderer.render(SMALL, T_B_C)
        ref_depth, ref_face = reference_cast(vertices, triangles, ids, SMALL, T_B_C)
        assert depth.shape == (SMALL.height, SMALL.width) and face.dtype.kind == "i"
        # Pixels exactly on an edge between two faces may go either way.
        agree = face == ref_face
        assert agree.mean() > 0.995
        assert np.abs(depth - ref_depth)[agree].max() < 2e-5
        assert (face >= 0).all()  # a closed room: every ray hits


def test_depth_is_z_on_the_plane_of_the_seen_face():
    scene = room()
    renderer = DepthRenderer(*scene.arrays())
    T_B_C = look_at((2.0, 1.0, 1.5), (6.0, 3.0, 1.2))
    depth, face = renderer.render(CAMERA, T_B_C)
    points_B = (pixel_rays(CAMERA) * depth[..., None]) @ T_B_C[:3, :3].T + T_B_C[:3, 3]
    planes = np.array([scene.planes_B[i] for i in face.ravel()]).reshape(*face.shape, 4)
    residual = np.einsum("hwk,hwk->hw", points_B, planes[..., :3]) + planes[..., 3]
    assert np.abs(residual).max() < 2e-5
    assert {6, 7, 8} <= set(np.unique(face))  # both east sections and the step's riser


def test_far_from_origin_coordinates_keep_precision():
    scene = room()
    vertices, triangles, ids = scene.arrays()
    shift = np.array([250_000.0, 5_600_000.0, 300.0])  # UTM-like georeferencing
    T_B_C = look_at((2.0, 2.0, 1.5), (6.0, 1.0, 1.0))
    near, _ = DepthRenderer(vertices, triangles, ids).render(SMALL, T_B_C)
    T_far = T_B_C.copy()
    T_far[:3, 3] += shift
    far, _ = DepthRenderer(vertices + shift, triangles, ids).render(SMALL, T_far)
    assert np.abs(far - near).max() < 1e-3


def test_empty_scene_and_incidence():
    empty = DepthRenderer(np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros(0, int))
    depth, face = empty.render(SMALL, np.eye(4))
    assert not depth.any() and (face == -1).all()
    scene = room()
    # Looking straight at the west wall from 2 m: incidence is the ray's angle to the axis.
    T_B_C = look_at((2.0, 2.0, 1.3), (0.0, 2.0, 1.3))
    depth, face, cos_inc = DepthRenderer(*scene.arrays()).render(SMALL, T_B_C, with_incidence=True)
    rays = pixel_rays(SMALL)
    expected = 1.0 / np.linalg.norm(rays, axis=-1)
    on_west = face == 3
    assert on_west.mean() > 0.5
    assert np.abs(cos_inc - expected)[on_west].max() < 1e-6


@pytest.fixture
def ideal():
    scene = room()
    T_B_C = look_at((1.5, 2.0, 1.4), (6.0, 2.5, 1.2))
    return DepthRenderer(*scene.arrays()).render(CAMERA, T_B_C, with_incidence=True)


def test_noise_statistics_match_the_model(ideal):
    depth, _, cos_inc = ideal
    # The per-pixel part alone: the systematic part is checked below.
    cfg = DepthNoiseConfig(dropout_probability=0.0, grazing_start_deg=89.0, grazing_end_deg=90.0).without_systematic()
    noisy = add_depth_noise(depth, cfg, np.random.default_rng(0))
    both = (noisy > 0) & (depth > 0)
    assert both.mean() > 0.9
    z_err = (noisy - depth)[both] / cfg.sigma(depth[both])
    assert abs(z_err.mean()) < 0.02
    assert abs(z_err.std() - 1.0) < 0.02
    # Every value is a whole number of 16-bit PNG units.
    units = noisy / cfg.quantum_m
    assert np.abs(units - np.round(units)).max() < 1e-6


def test_systematic_error_is_a_per_frame_scale_and_a_smooth_field_growing_as_z_squared():
    """With the per-pixel part off, flat images at 1 m and 3 m noised from the same generator
    state give err(z) = z s + z^2 f(u, v): s must be one number per frame, f a quadratic over
    the image, and their spread over frames the configured one."""
    cfg = DepthNoiseConfig(sigma_a_m=0.0, sigma_b_per_m=0.0, quantum_m=0.0, dropout_probability=0.0)
    shape = (48, 64)
    assert np.array_equal(add_depth_noise(np.full(shape, 2.0), cfg.without_systematic(), np.random.default_rng(0)), np.full(shape, 2.0))
    y, x = np.meshgrid(np.linspace(-1, 1, shape[0]), np.linspace(-1, 1, shape[1]), indexing="ij")
    quadratic = np.stack([np.ones_like(x), x, y, x * y, x * x, y * y], axis=-1).reshape(-1, 6)
    scales, corners = [], []
    for seed in range(400):
        err1 = add_depth_noise(np.full(shape, 1.0), cfg, np.random.default_rng(seed)) - 1.0
        err3 = add_depth_noise(np.full(shape, 3.0), cfg, np.random.default_rng(seed)) - 3.0
        field = (err3 - 3 * err1) / 6
        scale = err1 - field
        assert np.ptp(scale) < 1e-12
        coef = np.linalg.lstsq(quadratic, field.ravel(), rcond=None)[0]
        assert np.abs(quadratic @ coef - field.ravel()).max() < 1e-12
        scales.append(scale[0, 0])
        corners.append(field[-1, -1])
    assert np.std(scales) == pytest.approx(cfg.scale_sigma, rel=0.1)
    # At 1 m the corner's error is scale and field: together the configured systematic sigma.
    assert np.std(np.array(scales) + corners) == pytest.approx(cfg.systematic_sigma(1.0), rel=0.1)


def test_holes_and_range_limits(ideal):
    depth, _, cos_inc = ideal
    cfg = DepthNoiseConfig(dropout_probability=0.05, max_range_m=4.0)
    noisy = add_depth_noise(depth, cfg, np.random.default_rng(0), cos_incidence=cos_inc)
    assert noisy[noisy > 0].max() <= 4.0
    near_frontal = (depth > 0) & (depth < 3.5) & (cos_inc > np.cos(np.radians(60)))
    assert abs((noisy[near_frontal] == 0).mean() - 0.05) < 0.01
    # Along the south wall: its far part is seen beyond the grazing limit.
    scene = room()
    along = look_at((0.5, 0.3, 1.4), (6.0, 0.6, 1.3))
    depth, _, cos_inc = DepthRenderer(*scene.arrays()).render(CAMERA, along, with_incidence=True)
    noisy = add_depth_noise(depth, cfg, np.random.default_rng(0), cos_incidence=cos_inc)
    grazing = cos_inc < np.cos(np.radians(cfg.grazing_end_deg))
    assert grazing.sum() > 1000 and not noisy[grazing].any()


def test_noise_is_deterministic(ideal):
    depth, _, cos_inc = ideal
    cfg = DepthNoiseConfig()
    a = add_depth_noise(depth, cfg, np.random.default_rng(7), cos_incidence=cos_inc)
    b = add_depth_noise(depth, cfg, np.random.default_rng(7), cos_incidence=cos_inc)
    c = add_depth_noise(depth, cfg, np.random.default_rng(8), cos_incidence=cos_inc)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
