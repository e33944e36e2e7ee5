"""Graduated non-convexity with the Geman-McClure cost (Yang, Antonante, Tzoumas and Carlone,
"Graduated Non-Convexity for Robust Spatial Perception", RA-L 2020), for the plane-to-BIM
factors. Pure maths, no graph.

A plane-to-BIM factor says "this landmark is the planned face, within the as-built
tolerance". A wall built off plan breaks that; a fixed robust kernel (Cauchy) still lets it pull,
and which walls end up "right" depends on where the optimisation starts, i.e. on the walls seen
first. GNC starts from a surrogate of the Geman-McClure cost that is convex over every
residual (`mu` large: nearly least squares, where the walls consistent with each other
outvote a deviating one), and lowers `mu` step by step to the robust cost itself, re-weighting
between solves. Geman-McClure rather than truncated least squares: the start is the offline
round's estimate under the robust kernel, which may already follow a deviating wall, and TLS's
first surrogate all but ignores the residuals that are large there (measured: it keeps the
wrong wall).
"""

from __future__ import annotations

import numpy as np


def initial_mu(r2: np.ndarray, c2: float) -> float | None:
    """The surrogate's first `mu`, convex over all squared whitened residuals `r2` (the paper's
    `2 r_max^2 / c^2`); None if every residual is already below `c2`: nothing to decide."""
    r2_max = float(np.max(r2, initial=0.0))
    if r2_max <= c2:
        return None
    return 2.0 * r2_max / c2


def gm_weights(r2: np.ndarray, mu: float, c2: float) -> np.ndarray:
    """The weights that minimise the surrogate at `mu` for the residuals `r2`:
    `(mu c^2 / (r^2 + mu c^2))^2`."""
    return (mu * c2 / (np.asarray(r2, dtype=float) + mu * c2)) ** 2


def schedule(mu: float, step: float) -> list[float]:
    """`mu` divided by `step` until it reaches 1, the Geman-McClure cost itself."""
    out = [mu]
    while out[-1] > 1.0:
        out.append(max(out[-1] / step, 1.0))
    return out
