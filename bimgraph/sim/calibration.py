"""Calibration of the planes sensor against the depth sensor, on the same simulated views.

Planes extracted from simulated depth are matched to the as-built element under most of
their pixels (ground-truth labels) and their errors measured; for each of them the planes
sensor draws detections of the same true plane seen from the same range and angle.
The two error distributions (normal angle, offset), compared by range, say whether
`ObserveConfig`'s noise matches what a plane fitted to the depth images gets.
Pure computation: no files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimgraph.config import ObserveConfig
from bimgraph.geometry import normal_angle_deg, plane_to_frame
from bimgraph.planes.extractor import Extraction
from bimgraph.sim.observe import perturb_plane

RANGE_BINS_M = ((0.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, 8.0))


@dataclass
class PlaneErrors:
    """One row per extracted plane matched to an as-built element."""

    range_m: np.ndarray  # distance of the plane's centre from the camera
    cos_view: np.ndarray  # cosine of the angle between the normal and the line of sight
    plane_C_true: np.ndarray  # N x 4, as-built plane in C
    normal_deg: np.ndarray  # extracted: angle to the true normal
    offset_m: np.ndarray  # extracted: d - true d

    def drawn(self, cfg: ObserveConfig, rng: np.random.Generator, draws: int) -> tuple[np.ndarray, np.ndarray]:
        """(normal angle deg, offset m) of `draws` planes-sensor detections of each row's view."""
        angles, offsets = [], []
        for r, c, true_C in zip(self.range_m, self.cos_view, self.plane_C_true):
            sigma_n, sigma_d = cfg.noise.sigmas(r, c)
            for _ in range(draws):
                noisy = perturb_plane(true_C, sigma_n, sigma_d, rng)
                angles.append(normal_angle_deg(noisy[:3], true_C[:3]))
                offsets.append(noisy[3] - true_C[3])
        return np.array(angles), np.array(offsets)


def match_errors(extractions: list[Extraction], truth_labels: list[np.ndarray], T_B_Cs: list[np.ndarray],
                 planes_B: np.ndarray, purity: float) -> PlaneErrors:
    """Errors of the extracted planes whose pixels lie on one as-built element for at least
    `purity` of them; `truth_labels` are the element index per pixel (-1 none), `planes_B`
    the as-built plane of each element."""
    rows = []
    for extraction, truth, T_B_C in zip(extractions, truth_labels, T_B_Cs):
        labels = extraction.labels
        for i, plane in enumerate(extraction.planes):
            under = truth[labels == i]
            under = under[under >= 0]
            if len(under) == 0:
                continue
            element = np.bincount(under).argmax()
            if np.mean(under == element) < purity:
                continue
            true_C = plane_to_frame(planes_B[element], T_B_C)
            if true_C[3] <= 0:
                continue
            r = float(np.linalg.norm(plane.centre))
            rows.append((r, abs(float(plane.n @ plane.centre)) / r, *true_C,
                         normal_angle_deg(plane.n, true_C[:3]), plane.d - true_C[3]))
    a = np.array(rows).reshape(-1, 8)
    return PlaneErrors(a[:, 0], a[:, 1], a[:, 2:6], a[:, 6], a[:, 7])


@dataclass
class BinStats:
    lo_m: float
    hi_m: float
    count: int
    depth: dict  # "normal_deg" / "offset_cm" -> (median, p90) of the extracted planes
    planes: dict  # the same for the planes sensor's draws

    def ratios(self) -> dict:
        """planes sensor over depth, per statistic: 1 is perfect agreement."""
        return {k: tuple(p / max(d, 1e-12) for p, d in zip(self.planes[k], self.depth[k])) for k in self.depth}


def _median_p90(values: np.ndarray) -> tuple[float, float]:
    return float(np.median(values)), float(np.percentile(values, 90))


def compare(errors: PlaneErrors, cfg: ObserveConfig, rng: np.random.Generator, draws: int = 20,
            bins=RANGE_BINS_M) -> list[BinStats]:
    """Median and 90th percentile of |error| by range, extracted from depth against drawn by
    the planes sensor for the same views; the last entry pools all ranges."""
    angles, offsets = errors.drawn(cfg, rng, draws)
    ranges = np.repeat(errors.range_m, draws)
    out = []
    for lo, hi in [*bins, (bins[0][0], bins[-1][1])]:
        mine, theirs = (errors.range_m >= lo) & (errors.range_m < hi), (ranges >= lo) & (ranges < hi)
        if not mine.any():
            continue
        out.append(BinStats(lo, hi, int(mine.sum()),
                            {"normal_deg": _median_p90(errors.normal_deg[mine]),
                             "offset_cm": _median_p90(100 * np.abs(errors.offset_m[mine]))},
                            {"normal_deg": _median_p90(angles[theirs]),
                             "offset_cm": _median_p90(100 * np.abs(offsets[theirs]))}))
    return out
