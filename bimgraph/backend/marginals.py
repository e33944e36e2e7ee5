"""Joint marginal covariances among a set of variables of a batch graph, all at once. No I/O.

The offline estimator and the robust alignment ask for hundreds of small joint marginals per
solve (each landmark with its anchor and the extrinsic). gtsam's `Marginals` builds a joint
Bayes net through the tree for every such request; here the graph, linearised at the estimate,
is marginalised onto all the variables asked about in one elimination, and that marginal's
information is inverted densely. Every joint marginal among them is then a block of one matrix
(measured on a 600-keyframe site walk: 186 landmarks' joints with anchor and extrinsic 5.4 s
one by one, 0.25 s at once; the same numbers to 1e-12). The inverse is dense in the variables
asked about, so its cost grows with their cube: 0.3 s for site 2's 1446 dimensions, about 3 s
for 4000 (some 400 landmarks with their anchors), where gtsam's one at a time would take as long.
"""

from __future__ import annotations

import functools

import gtsam
import numpy as np
from scipy.linalg import cho_factor, cho_solve


def column_blocks(keys, values: gtsam.Values) -> dict[int, slice]:
    """Each key's columns in a dense matrix over `keys`, in the order given, each as wide as its
    variable's tangent in `values`."""
    zero = values.zeroVectors()
    starts = np.concatenate([[0], np.cumsum([zero.at(key).size for key in keys])])
    return {key: slice(int(a), int(b)) for key, a, b in zip(keys, starts, starts[1:])}


class JointMarginals:
    """`joint(keys)`: the joint marginal covariance of `keys`, blocks in the order given, for
    any keys among those this was made for; the marginalisation runs at the first request."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys):
        self._graph, self._values = graph, gtsam.Values(values)  # (the caller may change its own)
        self._keys = sorted(set(keys))

    @functools.cached_property
    def _covariance(self) -> tuple[np.ndarray, dict[int, slice]]:
        marginal = self._graph.linearize(self._values).marginal(gtsam.KeyVector(self._keys))
        # the dense information's rows are the keys in ascending order, each its tangent's width
        information, _ = marginal.hessian()
        covariance = cho_solve(cho_factor(information), np.eye(len(information)))
        return 0.5 * (covariance + covariance.T), column_blocks(self._keys, self._values)

    def __call__(self, keys: list[int]) -> np.ndarray:
        cov, blocks = self._covariance
        rows = np.concatenate([np.arange(blocks[key].start, blocks[key].stop) for key in keys])
        return cov[np.ix_(rows, rows)]

    def marginal(self, key: int) -> np.ndarray:
        return self([key])
