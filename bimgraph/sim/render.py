"""Depth and face-id images of triangle meshes by ray casting, and the depth sensor's noise.

`DepthRenderer` builds one Open3D `RaycastingScene` and renders z-depth (metres, 0 = no
return) and the id of the triangle seen at each pixel (-1 = none) for a pinhole camera at
`T_B_C` (OpenCV axes). `add_depth_noise` turns an ideal depth image into a sensor-like one.
Pure computation: no files.
"""

from __future__ import annotations

import numpy as np

from bimgraph.config import DepthNoiseConfig
from bimgraph.sequence.format import Camera


def pixel_rays(camera: Camera) -> np.ndarray:
    """H x W x 3 ray directions in C with unit z, so that a point at z-depth z is z * ray."""
    u = (np.arange(camera.width) - camera.cx) / camera.fx
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    rays = np.ones((camera.height, camera.width, 3))
    rays[..., 0] = u[None, :]
    rays[..., 1] = v[:, None]
    return rays


class DepthRenderer:
    """Ray caster for a fixed set of triangles in frame B, each carrying an integer id."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, ids: np.ndarray):
        import open3d as o3d

        vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        self.ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        if len(self.ids) != len(triangles):
            raise ValueError(f"{len(self.ids)} ids for {len(triangles)} triangles")
        if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
            raise ValueError("triangle indices out of range")
        # Open3D casts in float32: work around a local origin so that far-from-zero building
        # coordinates (georeferenced IFC) keep millimetre precision.
        self.origin_B = vertices.mean(axis=0) if len(vertices) else np.zeros(3)
        v_local = (vertices - self.origin_B).astype(np.float32)
        a, b, c = (vertices[triangles[:, i]] for i in range(3))
        normals = np.cross(b - a, c - a)
        lengths = np.linalg.norm(normals, axis=1, keepdims=True)
        self.normals_B = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(triangles):
            self._scene.add_triangles(o3d.core.Tensor(v_local), o3d.core.Tensor(triangles.astype(np.uint32)))
        self._o3d = o3d

    def render(self, camera: Camera, T_B_C: np.ndarray, with_incidence: bool = False):
        """z-depth (H x W float, metres, 0 = no hit) and triangle id (H x W int, -1 = none).

        With `with_incidence`, also the cosine of the angle between each pixel's ray and the
        surface normal it hits (H x W, 0 where nothing is hit), for grazing-angle dropouts.
        """
        rays_C = pixel_rays(camera)
        R_B_C, t_B_C = T_B_C[:3, :3], T_B_C[:3, 3]
        dirs_B = rays_C @ R_B_C.T
        rays = np.empty((camera.height, camera.width, 6), dtype=np.float32)
        rays[..., :3] = t_B_C - self.origin_B
        rays[..., 3:] = dirs_B
        hit = self._scene.cast_rays(self._o3d.core.Tensor(rays))
        # Rays have unit z in C, so the hit distance along them is the z-depth.
        t = hit["t_hit"].numpy().astype(float)
        prim = hit["primitive_ids"].numpy().astype(np.int64)
        found = np.isfinite(t)
        depth = np.where(found, t, 0.0)
        ids = np.full(depth.shape, -1, dtype=np.int64)
        ids[found] = self.ids[prim[found]]
        if not with_incidence:
            return depth, ids
        cos_incidence = np.zeros(depth.shape)
        n_B = self.normals_B[prim[found]]
        d_B = dirs_B[found]
        cos_incidence[found] = np.abs(np.einsum("ij,ij->i", n_B, d_B)) / np.linalg.norm(d_B, axis=1)
        return depth, ids, cos_incidence


def add_depth_noise(depth: np.ndarray, cfg: DepthNoiseConfig, rng: np.random.Generator,
                    cos_incidence: np.ndarray | None = None) -> np.ndarray:
    """A sensor-like copy of an ideal z-depth image: a systematic error drawn once for the
    frame (depth scale, smooth distortion over the image), Gaussian per-pixel noise growing
    with depth, quantisation, random holes, grazing-angle holes (when `cos_incidence` is
    given) and range limits. Deterministic for a given generator state; 0 stays 0 (no return)."""
    depth = np.asarray(depth, dtype=float)
    hit = depth > 0
    noisy = depth + rng.standard_normal(depth.shape) * cfg.sigma(depth)
    if cfg.scale_sigma > 0 or cfg.tilt_sigma_per_m > 0 or cfg.curvature_sigma_per_m > 0:
        noisy += systematic_depth_error(depth, cfg, rng)
    if cfg.quantum_m > 0:
        noisy = np.round(noisy / cfg.quantum_m) * cfg.quantum_m
    keep = hit & (noisy >= cfg.min_range_m) & (noisy <= cfg.max_range_m)
    keep &= rng.random(depth.shape) >= cfg.dropout_probability
    if cos_incidence is not None:
        angle = np.degrees(np.arccos(np.clip(cos_incidence, 0.0, 1.0)))
        span = max(cfg.grazing_end_deg - cfg.grazing_start_deg, 1e-9)
        p_drop = np.clip((angle - cfg.grazing_start_deg) / span, 0.0, 1.0)
        keep &= rng.random(depth.shape) >= p_drop
    return np.where(keep, noisy, 0.0)


def distortion_basis(height: int, width: int) -> np.ndarray:
    """5 x H x W smooth fields over the image, each at most 1 in magnitude: tilt across and
    down, saddle, astigmatism, bowl (in coordinates that run from -1 to 1 across the image)."""
    x = np.linspace(-1.0, 1.0, width)[None, :]
    y = np.linspace(-1.0, 1.0, height)[:, None]
    x, y = np.broadcast_arrays(x, y)
    return np.stack([x, y, x * y, 0.5 * (x * x - y * y), 0.5 * (x * x + y * y)])


def systematic_depth_error(depth: np.ndarray, cfg: DepthNoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """The part of an RGB-D sensor's depth error that does not average out over a plane: a
    scale error, and a smooth field over the image that grows as z^2 (a disparity error:
    stereo and structured-light depth is z = f b / disparity, so a disparity bias gives
    z^2 / (f b) of depth). Drawn once per frame.

    Magnitudes are modelled on: Smisek et al. 2011 and Herrera et al. 2012 (Kinect: smooth,
    low-order residual depth distortion over the image after calibration, growing with
    depth); Teichman et al. 2013 (CLAMS: PrimeSense depth off by a depth-dependent factor,
    largest toward the image corners); Fiedler and Mueller 2012 (Kinect depth drifts with
    the sensor's temperature); Intel's RealSense D400 datasheet (absolute depth error up to
    2 % at 2 m). The defaults (0.3 % scale, 2 mm at 1 m per tilt term) are at the small end
    of these, for a calibrated, warmed-up sensor; they make planes fitted to the depth err by
    a few tenths of a degree and about a centimetre at 2-4 m, as plane fits to real RGB-D
    depth do. The curvature terms are kept small (0.2 mm at 1 m): at 1.5 mm they bent walls
    enough at range for the extractor, which grows regions against the pixel noise model, to
    split them (1.8 planes per element instead of 1.05, measured). Real sensors' patterns are
    partly fixed per device; here they are drawn independently per frame."""
    scale = rng.standard_normal() * cfg.scale_sigma
    coefficients = rng.standard_normal(5) * np.repeat([cfg.tilt_sigma_per_m, cfg.curvature_sigma_per_m], [2, 3])
    field = np.tensordot(coefficients, distortion_basis(*depth.shape), axes=1)
    return depth * scale + depth * depth * field
