"""Real-time plane extraction from one organised depth image (PEAC/CAPE style). No I/O.

The image is cut into square cells. Every cell gets a weighted least-squares plane in
inverse depth, `1/z = m . r` with `r = ((u - cx)/fx, (v - cy)/fy, 1)`, which is linear and
exact for planes: `m = -n / d`. All cells are fitted at once from per-cell sums (numpy, no
loop over pixels). Planar cells (residual consistent with the depth noise model) seed
regions that grow over neighbouring cells compatible with the region's current plane, with
the plane refitted on the region's pixels after each round; compatibility is tested against
the region plane, never cell to cell, so that slowly bending surfaces do not chain up.
A region is kept if it holds a 2x2 block of cells (one-cell-wide strips are cells straddling
an edge) and its whole residual still fits the noise model.

Inverse depth has variance sigma(z)^2 / z^4, so a region's normal equations `J m = h` give the
plane and its covariance `J^-1` directly from the depth noise model and the inliers; that
covariance is mapped into gtsam's OrientedPlane3 tangent space (Unit3 basis of n, then d).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import gtsam
import numpy as np

from bimgraph.config import DepthNoiseConfig, ExtractionConfig
from bimgraph.errors import ConfigError
from bimgraph.sequence.format import Camera


@dataclass
class DetectedPlane:
    """A plane in the camera frame: `n . x + d = 0`, n toward the camera (d > 0)."""

    n: np.ndarray
    d: float
    cov: np.ndarray  # 3x3, OrientedPlane3 tangent space: Unit3(n).basis() directions, then d
    polygon: np.ndarray  # K x 3 extent in C
    area: float  # m^2, sum of the inlier pixels' footprints on the plane
    centre: np.ndarray  # area-weighted centroid of the inliers, on the plane
    inliers: int  # number of depth pixels

    @property
    def plane(self) -> np.ndarray:
        return np.array([*self.n, self.d])


@dataclass
class Extraction:
    planes: list[DetectedPlane]
    cell_labels: np.ndarray  # rows x cols of cells, index into planes, -1 for none
    cell_size: int
    valid: np.ndarray  # H x W, pixels with usable depth

    @property
    def labels(self) -> np.ndarray:
        """H x W index into planes of each pixel's plane, -1 for none (computed on demand)."""
        c = self.cell_size
        rows, cols = self.cell_labels.shape
        labels = np.full(self.valid.shape, -1, dtype=np.int32)
        labels[: rows * c, : cols * c] = np.repeat(np.repeat(self.cell_labels, c, axis=0), c, axis=1)
        labels[~self.valid] = -1
        return labels


class PlaneExtractor:
    """Holds the per-camera constants; `extract(depth)` runs on one z-depth image (metres)."""

    def __init__(self, camera: Camera, cfg: ExtractionConfig, noise: DepthNoiseConfig):
        self.camera, self.cfg, self.noise = camera, cfg, noise
        c = cfg.cell_size_px
        self.rows, self.cols = camera.height // c, camera.width // c
        if self.rows < 2 or self.cols < 2:
            raise ConfigError(f"planes.cell_size_px: cells of {c} px leave fewer than 2x2 cells in the camera's "
                              f"{camera.width}x{camera.height} image")
        # Pixel offsets from each cell's centre: small numbers, so float32 sums stay exact enough.
        self._local = np.arange(c, dtype=np.float32) - (c - 1) / 2.0
        centre_u = np.arange(self.cols) * c + (c - 1) / 2.0
        centre_v = np.arange(self.rows) * c + (c - 1) / 2.0
        self._rx0 = np.broadcast_to((centre_u - camera.cx) / camera.fx, (self.rows, self.cols)).ravel()
        self._ry0 = np.broadcast_to(((centre_v - camera.cy) / camera.fy)[:, None], (self.rows, self.cols)).ravel()
        # Sums along one cell's row piece of c pixels, as one small matrix product each:
        # weights 1, du, du^2 for the valid mask; 1, du for 1/z; 1 for 1/z^2.
        self._row_weights = np.stack([np.ones(c), self._local, self._local**2], axis=1).astype(np.float32)

    # -- per-cell sums and fits ---------------------------------------------------------

    def _cell_sums(self, depth: np.ndarray) -> np.ndarray:
        """10 sums per cell: 1, du, dv, du^2, du dv, dv^2 over valid pixels, then q, du q, dv q, q^2,
        with q = 1/z and (du, dv) the pixel's offset from the cell centre."""
        c, cfg = self.cfg.cell_size_px, self.cfg
        z = depth[: self.rows * c, : self.cols * c].astype(np.float32)
        valid = (z > cfg.min_depth_m) & (z < cfg.max_depth_m)
        q = np.zeros_like(z)
        np.divide(1.0, z, out=q, where=valid)
        shape = (self.rows, c, self.cols)  # cell row, pixel row inside the cell, cell column
        W = self._row_weights
        mask_rows = (valid.reshape(-1, c).astype(np.float32) @ W).reshape(*shape, 3).astype(np.float64)
        q_rows = (q.reshape(-1, c) @ W[:, :2]).reshape(*shape, 2).astype(np.float64)
        qq_rows = (np.square(q).reshape(-1, c) @ W[:, 0]).reshape(shape).astype(np.float64)
        dv = self._local.astype(np.float64)[None, :, None]
        n, su, suu = (mask_rows[..., k].sum(axis=1) for k in range(3))
        sv, svv, suv = (mask_rows[..., 0] * dv).sum(axis=1), (mask_rows[..., 0] * dv**2).sum(axis=1), (mask_rows[..., 1] * dv).sum(axis=1)
        sq, suq, svq = q_rows[..., 0].sum(axis=1), q_rows[..., 1].sum(axis=1), (q_rows[..., 0] * dv).sum(axis=1)
        return np.stack([n, su, sv, suu, suv, svv, sq, suq, svq, qq_rows.sum(axis=1)]).reshape(10, -1)

    def _cell_systems(self, sums: np.ndarray):
        """Per cell: G = sum r r^T, h = sum r q (debiased), sum q^2 - in normalised coordinates."""
        f = np.array([self.camera.fx, self.camera.fy])
        n, su, sv, suu, suv, svv, sq, suq, svq, sqq = sums
        rx0, ry0 = self._rx0, self._ry0
        # r = (du/fx + rx0, dv/fy + ry0, 1): shift the local sums to the image's coordinates.
        sx = su / f[0] + rx0 * n
        sy = sv / f[1] + ry0 * n
        sxx = suu / f[0] ** 2 + 2 * rx0 * su / f[0] + rx0**2 * n
        syy = svv / f[1] ** 2 + 2 * ry0 * sv / f[1] + ry0**2 * n
        sxy = suv / (f[0] * f[1]) + rx0 * sv / f[1] + ry0 * su / f[0] + rx0 * ry0 * n
        G = np.stack([np.stack([sxx, sxy, sx], -1), np.stack([sxy, syy, sy], -1), np.stack([sx, sy, n], -1)], -2)
        h = np.stack([suq / f[0] + rx0 * sq, svq / f[1] + ry0 * sq, sq], -1)
        with np.errstate(divide="ignore", invalid="ignore"):
            z_mean = n / sq
        # E[1/(z + e)] = 1/z + sigma^2 / z^3: remove that bias, which is many standard
        # deviations of a large plane's offset at close range.
        sigma = self.noise.sigma(z_mean)
        bias = np.nan_to_num(sigma**2 / z_mean**3)
        h_debiased = h - bias[:, None] * np.stack([sx, sy, n], -1)
        return G, h, h_debiased, sqq, z_mean, sigma

    # -- the extraction ---------------------------------------------------------------

    def extract(self, depth: np.ndarray) -> Extraction:
        cfg, c = self.cfg, self.cfg.cell_size_px
        if depth.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"depth image is {depth.shape[1]}x{depth.shape[0]}, camera is {self.camera.width}x{self.camera.height}")
        sums = self._cell_sums(depth)
        count = sums[0]
        G, h_raw, h, sqq, z_mean, sigma = self._cell_systems(sums)
        ncell = len(count)
        fitted = count >= cfg.cell_min_valid_fraction * c * c
        m_cell = np.zeros((ncell, 3))
        det = np.linalg.det(G[fitted])
        ok = np.flatnonzero(fitted)[det > 1e-12 * count[fitted] ** 3]
        fitted[:] = False
        fitted[ok] = True
        m_cell[ok] = np.linalg.solve(G[ok], h[ok][..., None])[..., 0]
        # Inverse-depth residual against the noise model's variance sigma^2 / z^4.
        sse = sqq[ok] - np.einsum("ni,ni->n", m_cell[ok], 2 * h_raw[ok] - h[ok])
        mse_ratio = np.full(ncell, np.inf)
        mse_ratio[ok] = sse / count[ok] * z_mean[ok] ** 4 / sigma[ok] ** 2
        planar = fitted & (mse_ratio <= cfg.max_mse_ratio)
        weight = np.where(planar, z_mean**4 / np.maximum(sigma, 1e-12) ** 2, 0.0)
        # Point at each cell's centre ray, on its own plane: for offsets and footprints.
        r_mean = np.zeros((ncell, 3))
        r_mean[fitted] = np.stack([G[fitted, 0, 2], G[fitted, 1, 2], count[fitted]], -1) / count[fitted, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            p_mean = r_mean / np.einsum("ni,ni->n", r_mean, m_cell)[:, None]
        norm = np.linalg.norm(m_cell, axis=1, keepdims=True)
        n_cell = -np.divide(m_cell, norm, out=np.zeros_like(m_cell), where=norm > 0)
        cells = _Cells(G, h_raw, h, sqq, weight, m_cell, n_cell, r_mean, np.where(fitted[:, None], p_mean, 0.0), count, planar)
        regions = self._segment(cells, mse_ratio)
        labels_cell = np.full(ncell, -1)
        planes, kept = [], []
        for region in regions:
            plane = self._describe(cells, region)
            if plane is not None and plane.area >= cfg.min_area_m2:
                labels_cell[region] = len(planes)
                planes.append(plane)
                kept.append(region)
        for plane, region in zip(planes, kept):
            plane.polygon = self._outline(region, plane)
        valid = (depth > cfg.min_depth_m) & (depth < cfg.max_depth_m)
        return Extraction(planes, labels_cell.reshape(self.rows, self.cols), c, valid)

    def _segment(self, cells: "_Cells", mse_ratio: np.ndarray) -> list[np.ndarray]:
        """Seeded region growing on the cell grid; returns each region's cell indices."""
        cfg = self.cfg
        shape = (self.rows, self.cols)
        planar = np.flatnonzero(cells.planar)
        # One matrix product tests every planar cell against a plane m_R: columns give
        # w (m_R - m)^T G (m_R - m) less its constant, the normals' cosine, the offset less d_R.
        G, m, w = cells.G[planar], cells.m[planar], cells.w[planar]
        Gm = np.einsum("nij,nj->ni", G, m)
        table = np.hstack([w[:, None] * G.reshape(-1, 9), -2 * w[:, None] * Gm, cells.n[planar], cells.p[planar]])
        chi2_const = w * np.einsum("ni,ni->n", Gm, m)
        cos_max = np.cos(np.radians(cfg.grow_max_angle_deg))
        V = np.zeros((18, 3))

        def compatible(m_R: np.ndarray, free: np.ndarray) -> np.ndarray:
            n_R, d_R = _plane_of(m_R)
            V[:9, 0], V[9:12, 0], V[12:15, 1], V[15:18, 2] = np.outer(m_R, m_R).ravel(), m_R, n_R, n_R
            chi2, cos, offset = (table @ V).T
            ok = (chi2 + chi2_const <= cfg.grow_max_chi2) & (cos >= cos_max) & (np.abs(offset + d_R) <= cfg.grow_max_offset_m)
            grid = np.zeros(len(cells.planar), dtype=np.uint8)
            grid[planar[ok]] = 1
            grid &= free
            return grid.reshape(shape)

        support = self._support(cells)
        free = cells.planar.astype(np.uint8)
        seedable = cells.planar & (support >= cfg.seed_min_support)
        order = np.lexsort((mse_ratio, -support))  # most supported, then flattest cells first
        regions = []
        for seed in order[seedable[order]]:
            if not (seedable[seed] and free[seed]):
                continue
            region = np.array([seed])
            m_R = cells.m[seed]
            for _ in range(cfg.grow_iterations):
                grid = compatible(m_R, free)
                grid.flat[seed] = 1
                _, lab = cv2.connectedComponents(grid, connectivity=4)
                grown = np.flatnonzero(lab.ravel() == lab.flat[seed])
                m_R = _solve(cells, grown)
                if np.array_equal(grown, region):
                    break
                region = grown
            if len(region) >= cfg.min_cells and self._has_block(region):
                free[region] = 0
                regions.append(region)
            # Seeding again inside a region that failed would grow much the same region.
            seedable[region] = False
        return regions

    def _has_block(self, region: np.ndarray) -> bool:
        """Whether the region holds a 2x2 block of cells: a one-cell-wide strip is a chamfer of
        cells that straddle an edge or a step, each fitting it well enough, not a surface."""
        grid = np.zeros(self.rows * self.cols, dtype=bool)
        grid[region] = True
        grid = grid.reshape(self.rows, self.cols)
        return bool((grid[1:, 1:] & grid[:-1, 1:] & grid[1:, :-1] & grid[:-1, :-1]).any())

    def _support(self, cells: "_Cells") -> np.ndarray:
        """Number of 4-neighbours of each planar cell that would join its plane."""
        shape = (self.rows, self.cols)
        idx = np.arange(len(cells.planar)).reshape(shape)
        support = np.zeros(len(cells.planar), dtype=int)
        pairs = [(idx[:, :-1], idx[:, 1:]), (idx[:-1, :], idx[1:, :])]
        for a, b in pairs:
            a, b = a.ravel(), b.ravel()
            both = cells.planar[a] & cells.planar[b]
            a, b = a[both], b[both]
            ok = self._pair_ok(cells, a, b) & self._pair_ok(cells, b, a)
            np.add.at(support, a[ok], 1)
            np.add.at(support, b[ok], 1)
        return support

    def _pair_ok(self, cells: "_Cells", a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Cell b against the plane of cell a, for many pairs at once."""
        cfg = self.cfg
        dm = cells.m[a] - cells.m[b]
        chi2 = cells.w[b] * np.einsum("ni,nij,nj->n", dm, cells.G[b], dm)
        cos = np.einsum("ni,ni->n", cells.n[a], cells.n[b])
        return (chi2 <= cfg.grow_max_chi2) & (cos >= np.cos(np.radians(cfg.grow_max_angle_deg)))

    def _describe(self, cells: "_Cells", region: np.ndarray) -> DetectedPlane | None:
        cam = self.camera
        J, hJ = _normal_equations(cells, region)
        m_R = np.linalg.solve(J, hJ)
        # Chamfers along edges are made of cells each fitting well enough: judge the whole.
        sse = np.einsum("n,n->", cells.w[region], cells.sqq[region] - 2 * cells.h_raw[region] @ m_R) + m_R @ J @ m_R
        if sse / cells.count[region].sum() > self.cfg.max_mse_ratio:
            return None
        n, d = _plane_of(m_R)
        # Tangent-space covariance: d n = -d (I - n n^T) d m, d d = d^2 n^T d m.
        B = gtsam.Unit3(n).basis()
        jac = np.vstack([-d * B.T, d * d * n[None, :]])
        cov = jac @ np.linalg.inv(J) @ jac.T
        z = 1.0 / (cells.r[region] @ m_R)
        if (z <= 0).any():
            return None
        footprint = cells.count[region] * z**3 / (cam.fx * cam.fy * d)
        area = float(footprint.sum())
        centre = (footprint[:, None] * cells.r[region] * z[:, None]).sum(axis=0) / area
        centre -= (n @ centre + d) * n
        # The sensor's systematic error does not average out over the pixels: add it.
        range_m = float(np.linalg.norm(centre))
        sigma_n, sigma_d = self.cfg.systematic.sigmas(range_m, abs(float(n @ centre)) / range_m)
        cov = 0.5 * (cov + cov.T) + np.diag([sigma_n**2, sigma_n**2, sigma_d**2])
        return DetectedPlane(n, d, cov, np.zeros((0, 3)), area, centre, int(cells.count[region].sum()))

    def _outline(self, region: np.ndarray, plane: DetectedPlane) -> np.ndarray:
        """The outer outline of the region's cells, simplified, cast from the image onto the plane."""
        c = self.cfg.cell_size_px
        r, q = np.divmod(region, self.cols)
        sub = np.zeros((r.max() - r.min() + 1, q.max() - q.min() + 1), dtype=np.uint8)
        sub[r - r.min(), q - q.min()] = 1
        mask = np.repeat(np.repeat(sub, c, axis=0), c, axis=1)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=(int(q.min()) * c, int(r.min()) * c))
        outline = max(contours, key=cv2.contourArea)
        outline = cv2.approxPolyDP(outline, self.cfg.polygon_tolerance_px, True)[:, 0, :].astype(float)
        cam = self.camera
        rays = np.column_stack([(outline[:, 0] - cam.cx) / cam.fx, (outline[:, 1] - cam.cy) / cam.fy, np.ones(len(outline))])
        denom = rays @ plane.n
        keep = denom < -1e-6  # rays that meet the plane in front of the camera
        return rays[keep] * (-plane.d / denom[keep])[:, None]


@dataclass
class _Cells:
    G: np.ndarray  # per cell sum r r^T (normalised image coordinates)
    h_raw: np.ndarray  # per cell sum r / z
    h: np.ndarray  # the same, debiased
    sqq: np.ndarray  # per cell sum 1 / z^2
    w: np.ndarray  # inverse variance of 1/z at the cell's depth, 0 for non-planar cells
    m: np.ndarray  # per cell plane, m = -n / d
    n: np.ndarray  # its unit normal
    r: np.ndarray  # mean ray of the cell's valid pixels
    p: np.ndarray  # the point of the cell's own plane on that ray
    count: np.ndarray
    planar: np.ndarray


def _normal_equations(cells: _Cells, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J m = h of the weighted inverse-depth fit over the region's pixels; J^-1 is m's covariance."""
    return np.einsum("n,nij->ij", cells.w[region], cells.G[region]), np.einsum("n,ni->i", cells.w[region], cells.h[region])


def _solve(cells: _Cells, region: np.ndarray) -> np.ndarray:
    return np.linalg.solve(*_normal_equations(cells, region))


def _plane_of(m: np.ndarray) -> tuple[np.ndarray, float]:
    """(n, d) with d > 0 from the inverse-depth plane m = -n / d."""
    norm = float(np.linalg.norm(m))
    return -m / norm, 1.0 / norm


def extract_planes(depth: np.ndarray, camera: Camera, cfg: ExtractionConfig, noise: DepthNoiseConfig) -> Extraction:
    """One-off convenience; build a `PlaneExtractor` once to run on many frames."""
    return PlaneExtractor(camera, cfg, noise).extract(depth)
