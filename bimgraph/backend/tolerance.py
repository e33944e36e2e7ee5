"""How closely the walls the alignment keeps follow the plan, measured from the data: variance
component estimation (Förstner 1979; Koch, "Parameter Estimation and Hypothesis Testing in
Linear Models", 1999, ch. 3.6) over the plane-to-BIM factors. Pure maths, no graph.

The configured as-built tolerance (`noise.bim_offset_m`, `noise.bim_normal_deg`) is what a
sound wall may stray from plan. A building whose sound walls sit closer than that (the plan
holds to millimetres, or the drawing was traced from the built walls) wastes what its walls
could say about the poses and about every other wall's deviation. The residuals of the kept
factors tell: split into the offset at the face centre and the two tilt components, each
factor's squared whitened residual over its redundancy (the share of its information the rest
of the graph does not repeat) measures that group's variance factor. The estimate is robust
(a median: GNC keeps walls built off plan by less than its threshold) and an upper confidence
bound, so that a handful of walls cannot talk the tolerance down; and it only ever tightens
the configured one, since a wall beyond it is a deviation, for GNC to judge, not evidence of a
looser building.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom, chi2

# The components of a factor's residual in deviation coordinates, `(offset, tilt_1, tilt_2)`
# (`factors.plane.face_tolerance_coordinates`): group 0 is the offset, group 1 the tilt.
_GROUPS = (np.array([0]), np.array([1, 2]))


def redundancy(A: np.ndarray, e: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One factor's `(squared residuals, redundancy)` per group (offset, tilt). `A` (3 x n)
    and `e` (3) are the factor's Jacobian and residual whitened in deviation coordinates, `cov`
    the joint marginal covariance of its keys in the graph that includes it. The redundancy
    matrix is `I - A cov A^T`; its diagonal, the share of each component not determined by the
    rest of the graph, sums over a group to that group's degrees of freedom."""
    R = np.eye(3) - A @ cov @ A.T
    e2, r = np.asarray(e, dtype=float) ** 2, np.diag(R)
    return np.array([e2[g].sum() for g in _GROUPS]), np.array([r[g].sum() for g in _GROUPS])


def variance_factors(terms: list[tuple[np.ndarray, np.ndarray]], confidence: float,
                     min_redundancy: float = 0.05) -> np.ndarray:
    """Upper `confidence` bounds of the (offset, tilt) variance factors from the factors'
    `redundancy` terms. Each factor's `e^2 / r` is the variance factor times a chi-square
    variable of the group's dimension over that dimension; the median of these, divided by the
    chi-square median, estimates it whatever a minority of walls built just inside GNC's
    threshold add (a sum of squares would follow them), and the order statistic that bounds
    the median from above at `confidence` (binomial) makes it an upper bound. Factors the rest
    of the graph barely checks (`r` below `min_redundancy` per component) say nothing; a group
    with fewer than three that do keeps its factor of 1."""
    out = np.ones(2)
    for g, dim in enumerate(len(group) for group in _GROUPS):
        q = np.sort([s[g] / r[g] for s, r in terms if r[g] > min_redundancy * dim])
        if len(q) < 3:
            continue
        k = min(int(binom.ppf(confidence, len(q), 0.5)), len(q) - 1)
        out[g] = q[k] * dim / chi2.ppf(0.5, dim)
    return out


def tightened(tolerance: tuple[float, float], factors: np.ndarray, configured: tuple[float, float],
              floor: tuple[float, float]) -> tuple[float, float]:
    """The tolerance `(normal rad, offset m)` scaled by the square roots of the variance
    `factors` (offset, tilt), kept between `floor` and the `configured` tolerance."""
    normal = float(np.clip(tolerance[0] * np.sqrt(factors[1]), floor[0], configured[0]))
    offset = float(np.clip(tolerance[1] * np.sqrt(factors[0]), floor[1], configured[1]))
    return normal, offset
