"""How closely the walls the alignment keeps follow the plan, measured from the data: variance
component estimation (Förstner 1979; Koch, "Parameter Estimation and Hypothesis Testing in
Linear Models", 1999, ch. 3.6) over the plane-to-BIM factors. Pure maths, no graph.

The configured as-built tolerance (`noise.bim_offset_m`, `noise.bim_normal_deg`) is what a
sound wall may stray from plan. A building whose sound walls sit closer than that (the plan
holds to millimetres, or the drawing was traced from the built walls) wastes what its walls
could say about the poses and about every other wall's deviation. The residuals of the kept
factors tell: split into the offset at the face centre and the two tilt components, each
component's squared whitened residual over its redundancy (the share of its information the
rest of the graph does not repeat) measures its group's variance factor. The estimate is robust
(a median: GNC keeps walls built off plan by less than its threshold), needs a few walls (one
or two cannot talk the tolerance down), may be taken as an upper confidence bound, and only
ever tightens the configured tolerance, since a wall beyond it is a deviation, for GNC to
judge, not evidence of a looser building.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom, chi2

# The components of a plane-to-BIM factor's residual in deviation coordinates, `(offset,
# tilt_1, tilt_2)` (`factors.plane.face_tolerance_coordinates`): the offset, and the two tilts.
FACE_GROUPS = (0, 1, 1)


def redundancy(A: np.ndarray, e: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One factor's squared residuals and redundancies, per component. `A` (3 x n) and `e` (3)
    are the factor's Jacobian and residual whitened in deviation coordinates, `cov` the joint
    marginal covariance of its keys in the graph that includes it. The redundancy matrix is
    `I - A cov A^T`; its diagonal is the share of each component that the rest of the graph
    does not determine, and the variance of that component's residual in units of the
    tolerance's."""
    R = np.eye(len(e)) - A @ cov @ A.T
    return np.asarray(e, dtype=float) ** 2, np.diag(R).copy()


def studentized(A: np.ndarray, e: np.ndarray, cov: np.ndarray, groups: tuple[int, ...] = FACE_GROUPS,
                min_redundancy: float = 0.05) -> np.ndarray | None:
    """Baarda's test statistics of one factor, one per component group (by default the
    offset, 1 dof, and the tilt, 2 dof): its residual as the rest of the graph predicts it,
    `d = R^-1 e`, over that prediction's covariance `R^-1`, with `R = I - A cov A^T` (`A`, `e`
    and `cov` as for `redundancy`). Chi-square with the group's dimension when the factor fits,
    however strongly it pulled the estimate toward itself. None where the rest of the graph
    barely checks the factor (an eigenvalue of `R` below `min_redundancy`)."""
    R = np.eye(len(e)) - A @ cov @ A.T
    R = 0.5 * (R + R.T)
    if np.linalg.eigvalsh(R)[0] < min_redundancy:
        return None
    P = np.linalg.inv(R)
    d = P @ e
    members = [np.flatnonzero(np.asarray(groups) == g) for g in range(max(groups) + 1)]
    return np.array([d[i] @ np.linalg.solve(P[np.ix_(i, i)], d[i]) for i in members])


def variance_factors(terms: list[tuple[np.ndarray, np.ndarray]], confidence: float,
                     groups: tuple[int, ...] = FACE_GROUPS, min_redundancy: float = 0.05,
                     min_samples: int = 1) -> np.ndarray:
    """Upper `confidence` bounds of the variance factors of the component `groups` (for each
    residual component, the index of its group; by default a face's offset, tilt) from the
    factors' `redundancy` terms; at `confidence` 0.5, the estimates themselves. Each
    component's `e^2 / r` is the variance factor times a chi-square variable of one degree of
    freedom, whatever its correlation with the others; the median of a group's, over the
    chi-square median, estimates the group's factor whatever a minority of walls built just
    inside GNC's threshold add (a sum of squares would follow them), and the order statistic
    that bounds the median from above at `confidence` (binomial) makes it an upper bound.
    Components the rest of the graph barely checks (`r` below `min_redundancy`) say nothing; a
    group with fewer than `min_samples` samples, or too few for the bound (the largest of n
    samples bounds the median at 1 - 0.5^n), keeps its factor of 1."""
    samples: list[list[float]] = [[] for _ in range(max(groups) + 1)]
    for squares, r in terms:
        for c, g in enumerate(groups):
            if r[c] > min_redundancy:
                samples[g].append(squares[c] / r[c])
    out = np.ones(len(samples))
    for g, q in enumerate(samples):
        if len(q) < min_samples or 1.0 - 0.5 ** len(q) < confidence:
            continue
        q = np.sort(q)
        k = min(int(binom.ppf(confidence, len(q), 0.5)), len(q) - 1)
        out[g] = q[k] / chi2.ppf(0.5, 1)
    return out


def tightened(tolerance: tuple[float, float], factors: np.ndarray, configured: tuple[float, float],
              floor: tuple[float, float]) -> tuple[float, float]:
    """The tolerance `(normal rad, offset m)` scaled by the square roots of the variance
    `factors` (offset, tilt), kept between `floor` and the `configured` tolerance."""
    normal = float(np.clip(tolerance[0] * np.sqrt(factors[1]), floor[0], configured[0]))
    offset = float(np.clip(tolerance[1] * np.sqrt(factors[0]), floor[1], configured[1]))
    return normal, offset
