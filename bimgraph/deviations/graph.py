"""What the deviation step needs from a solved gtsam graph, read in the layout `estimate`
expects: the joint marginal of (E, X_anchor, L) and the whitened linearisation of a
plane-to-BIM factor. No I/O."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import gtsam
import numpy as np

from bimgraph.backend.graph import E, L, X, bim_keys
from bimgraph.backend.landmarks import transform_points
from bimgraph.backend.marginals import JointMarginals
from bimgraph.deviations.estimate import ObservedPlane


def bim_factor_linearization(factor: gtsam.NonlinearFactor, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
    """`(A, e_w)`: the factor's Jacobian and error, whitened and robustly re-weighted as the
    optimiser sees them, so that its cost near `values` is `|e_w + A delta|^2`."""
    A, b = factor.linearize(values).jacobian()
    return A, -b


def observed_plane(joint: Callable[[list[int]], np.ndarray], values: gtsam.Values, key_E: int, key_anchor: int,
                   key_plane: int, n_keyframes: int, face_id: str | None = None,
                   bim_factor: gtsam.NonlinearFactor | None = None, extent_S: np.ndarray | None = None,
                   area_m2: float = 0.0) -> ObservedPlane:
    """An `ObservedPlane` for landmark `key_plane` anchored at `key_anchor` of a solved graph.
    `joint(keys)` gives the joint marginal covariance of `keys` in the order given (e.g. a
    `bimgraph.backend.marginals.JointMarginals`, or the iSAM2 wrapper's `joint`);
    `bim_factor` is the landmark's plane-to-BIM factor if the graph holds one (keys E,
    anchor, plane)."""
    return ObservedPlane(
        landmark=gtsam.Symbol(key_plane).index(),
        plane_A=values.atOrientedPlane3(key_plane).planeCoefficients(),
        T_S_A=values.atPose3(key_anchor).matrix(),
        cov=joint([key_E, key_anchor, key_plane]),
        n_keyframes=n_keyframes,
        face_id=face_id,
        bim_factor=None if bim_factor is None else bim_factor_linearization(bim_factor, values),
        extent_S=np.zeros((0, 3)) if extent_S is None else np.asarray(extent_S, dtype=float).reshape(-1, 3),
        area_m2=float(area_m2),
        keys=(key_E, key_anchor, key_plane),
        joint=joint,
    )


def observed_planes(landmarks: Sequence, values: gtsam.Values, joint: Callable[[list[int]], np.ndarray],
                    bim_factors: Mapping[int, gtsam.NonlinearFactor]) -> list[ObservedPlane]:
    """Every landmark of the backend (`bimgraph.backend.landmarks.Landmark`) as the deviation
    step reads it. `values` must hold E and every landmark and anchor; `bim_factors` maps a
    landmark id to its plane-to-BIM factor in the graph."""
    return [observed_plane(joint, values, E, X(lm.anchor), L(lm.id), len(lm.keyframes), lm.face,
                           bim_factors.get(lm.id), transform_points(lm.T_S_A, lm.extent_A), lm.area)
            for lm in landmarks]


def observed_planes_isam2(graph, landmarks: Sequence, solve: Callable | None = None) -> tuple[list[ObservedPlane], np.ndarray]:
    """The same from the backend's online `IncrementalGraph` (its `isam`, `batch` and
    `bim_index`), and the `T_S_B` they are measured with. Each face's own plane-to-BIM factor
    is taken out by a linear step from a minimum of the whole graph, which iSAM2's estimate is
    not (its relinearisation threshold leaves it short: on a site walk a sound face read -10.7
    cm at iSAM2's estimate, -5.2 at the minimum, -5.3 re-solved without its factor): so the
    graph is first solved from there by `solve(graph, values)` (a `BatchSolver`), if given.
    The joint marginals of every landmark at once (`JointMarginals`: iSAM2's one landmark at a
    time took 8 s for the 211 landmarks of a 600-keyframe site walk)."""
    factors = graph.isam.getFactorsUnsafe()
    bim_factors = {j: factors.at(i) for j, i in graph.bim_index.items()}
    batch, values = graph.batch(), graph.estimate()
    if solve is not None:
        values = solve(batch, values)
    joint = JointMarginals(batch, values, bim_keys(landmarks))
    return observed_planes(landmarks, values, joint, bim_factors), values.atPose3(E).matrix()
