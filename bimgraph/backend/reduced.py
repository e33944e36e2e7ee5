"""The graph the robust alignment judges on: every factor but the plane-to-BIM ones reduced to
its Gaussian marginal on the extrinsic and the judged landmarks, each held in S. No I/O.

Graduated non-convexity and the tolerance estimate solve the judged graph dozens of times, so
it is kept small: the rest of the walk enters as one dense Gaussian factor. Each landmark
lives in its anchor keyframe, and with its anchor that is 9 dimensions a landmark, the anchor's
6 only there to carry the plane's uncertainty. The marginal is taken on the planes expressed in
S instead, 3 dimensions a landmark: the synthetic world's largest judgement, 56 landmarks, went
from 510 dimensions to 174 (one elimination 13.6 -> 1.2 ms). The plane in S is
`plane_S = plane_A.transform(T_S_A^-1)`; its tangent is, to first order, a linear function of
the anchor's and the anchored plane's, `M`, so the Gaussian marginal on (E, anchors, planes)
maps exactly to one on (E, planes in S): covariance `M Sigma M^T`, mean `M mu`. (Eliminated
as hard constraints by gtsam's QR, the same map took 7.3 s offline at 2000 synthetic
keyframes, 80 landmarks, though some 10 ms online; in numpy 30-40 ms either way.)

There the plane-to-BIM factors are the same C++ factors with the frame S as the anchor: a pose
variable `S_FRAME` pinned at the identity (gtsam's `OrientedPlane3Factor` takes a plane and a
pose, but measures the residual in the predicted plane's basis, not the measured one's). Its
pin's sigma, 1e-8 (rad, m), is a hundred thousand times below the faces' tolerances: the
judgement cannot move it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import gtsam
import numpy as np
import scipy.linalg

from bimgraph.backend.graph import E, L, PLANE_S, S_FRAME, X, bim_keys
from bimgraph.backend.landmarks import Landmark
from bimgraph.backend.marginals import column_blocks
from factors import predict_local_plane

_PIN_SIGMA = 1e-8


def _factors(graph: gtsam.GaussianFactorGraph):
    return (graph.at(i) for i in range(graph.size()))


def tangent_of_plane(plane: np.ndarray) -> np.ndarray:
    """The 3x4 map from a change of a plane in R^4 to gtsam's `OrientedPlane3` tangent at
    `plane`: its `Unit3` basis for the normal, the offset as it is."""
    D = np.zeros((3, 4))
    D[:2, :3] = gtsam.Unit3(np.asarray(plane[:3], dtype=float)).basis().T
    D[2, 3] = 1.0
    return D


@dataclasses.dataclass
class Reduced:
    """The reduced graph: `graph(bim_factor)` is the rest's marginal plus each landmark's
    plane-to-BIM factor from `bim_factor` (None: none); `point` holds the extrinsic, `S_FRAME`
    and each landmark's plane in S where the marginal was taken; `landmarks` are the judged
    landmarks as this graph holds them (in S: `anchor` None), by id."""

    marginal: gtsam.NonlinearFactorGraph
    point: gtsam.Values
    landmarks: dict[int, Landmark]
    T_S_A: dict[int, gtsam.Pose3]  # each landmark's anchor pose where the marginal was taken

    def graph(self, bim_factor: Callable[[Landmark], gtsam.NonlinearFactor | None]) -> gtsam.NonlinearFactorGraph:
        graph = gtsam.NonlinearFactorGraph(self.marginal)
        for lm in self.landmarks.values():
            if (factor := bim_factor(lm)) is not None:
                graph.add(factor)
        return graph

    def anchored(self, values: gtsam.Values) -> gtsam.Values:
        """An estimate of this graph (`values`) in the estimator's variables: the extrinsic,
        and each landmark's plane in its anchor as the anchor stood where the marginal was
        taken (the reduced graph does not move anchors)."""
        out = gtsam.Values()
        out.insert(E, values.atPose3(E))
        for j, T_S_A in self.T_S_A.items():
            out.insert(L(j), values.atOrientedPlane3(PLANE_S(j)).transform(T_S_A))
        return out


def reduced(rest: gtsam.NonlinearFactorGraph, values: gtsam.Values, landmarks: list[Landmark]) -> Reduced:
    """The reduced graph of these matched landmarks, with the rest of the graph (`rest`: every
    factor but the plane-to-BIM ones) as its Gaussian marginal at `values` on the extrinsic
    and the landmarks in S (a `LinearContainerFactor`)."""
    anchored = gtsam.HessianFactor(rest.linearize(values).marginal(gtsam.KeyVector(bim_keys(landmarks))))
    columns = column_blocks(list(anchored.keys()), values)
    keys = [E] + [PLANE_S(lm.id) for lm in landmarks]
    information_x = anchored.information()
    M = np.zeros((3 * len(keys) + 3, len(information_x)))  # (E, anchors, planes) -> (E, planes in S)
    M[:6, columns[E]] = np.eye(6)
    point, T_S_A = gtsam.Values(), {}
    point.insert(E, values.atPose3(E))
    for row, lm in enumerate(landmarks, start=2):
        anchor, plane = X(lm.anchor), L(lm.id)
        T_S_A[lm.id] = values.atPose3(anchor)
        plane_S, J = predict_local_plane(gtsam.Pose3(), T_S_A[lm.id], values.atOrientedPlane3(plane), jacobian=True)
        J = tangent_of_plane(plane_S) @ J[:, 6:]  # (anchor, anchored plane) -> plane in S
        rows = slice(3 * row, 3 * row + 3)
        M[rows, columns[anchor]] = J[:, :6]
        M[rows, columns[plane]] = J[:, 6:]
        point.insert(PLANE_S(lm.id), gtsam.OrientedPlane3(plane_S))
    # (by Cholesky: a solve for M's columns costs a third of inverting the whole)
    cov_x_MT, mean_x = np.hsplit(scipy.linalg.cho_solve(scipy.linalg.cho_factor(information_x),
                                                        np.column_stack([M.T, anchored.linearTerm()])), [M.shape[0]])
    information, mean = np.linalg.inv(M @ cov_x_MT), M @ mean_x.ravel()  # (mean: the rest's optimum as a step)
    # one dense factor: the marginal is dense in these variables anyway, and as the chain of
    # conditionals it came in, each solve re-assembled it (2000 synthetic keyframes: the
    # robust alignment's solves 3.9 -> 3.1 s, the same estimate)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.LinearContainerFactor(_gaussian(column_blocks(keys, point), information, mean), point))
    graph.add(gtsam.PriorFactorPose3(S_FRAME, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, _PIN_SIGMA)))
    point.insert(S_FRAME, gtsam.Pose3())
    return Reduced(graph, point, {lm.id: dataclasses.replace(lm, anchor=None) for lm in landmarks}, T_S_A)


def _gaussian(columns: dict[int, slice], information: np.ndarray, mean: np.ndarray) -> gtsam.HessianFactor:
    """The factor `0.5 (x - mean)^T information (x - mean)` over the keys of `columns` (each
    key's columns in `information`, in order): zero at its minimum, as gtsam's marginal leaves
    it (the solvers' relative error tolerance reads the error's level: with the constant left
    out, the judgement's solves stopped elsewhere, and site 3 online ended 4.7 cm off instead
    of 0.4). Made as
    `|R (x - mean)|^2` with `R` the information's Cholesky factor: gtsam's Python takes
    Jacobian factors of more than three keys only as a conditional on none."""
    R = scipy.linalg.cholesky(information)
    terms = [(key, R[:, block]) for key, block in columns.items()]
    return gtsam.HessianFactor(gtsam.GaussianConditional(terms, len(terms), R @ mean, gtsam.noiseModel.Unit.Create(len(R))))
