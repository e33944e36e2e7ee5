"""The graph's model of the front-end's odometry (online and offline): its poses, parsed once,
its steps without the drift measured so far (`bimgraph.backend.drift`), under its noise scaled
by the variance factors estimated from the smoothed steps (`bimgraph.backend.tolerance`,
offline only), and across a long stretch without upright planes by
`isam2.gap_odometry_scale`. No I/O."""

from __future__ import annotations

import copy
import math

import gtsam
import numpy as np

from bimgraph.backend import drift
from bimgraph.backend.drift import DriftRates
from bimgraph.backend.graph import FactorBuilder, X
from bimgraph.backend.marginals import JointMarginals
from bimgraph.backend.tolerance import redundancy, variance_factors
from bimgraph.geometry import inverse
from bimgraph.sequence.format import Keyframe

# the components of a Pose3 residual: rotation (3), then translation (3)
_POSE_GROUPS = (0, 0, 0, 1, 1, 1)
# a step whose given covariance's trace is this many times the walk's median is a jump
_JUMP = 100.0
# the steps whose poses are marginalised onto at once (one elimination each; their joint
# marginal is dense, so not the whole walk's at once)
_STEPS_AT_ONCE = 25


class OdometryModel:
    def __init__(self, build: FactorBuilder, up_S: np.ndarray):
        """`up_S`: B's vertical in S (by the initial alignment), which tells level planes."""
        self.build = build
        # the steps in and out of a long stretch without upright planes (`gap_steps`) have
        # their noise sigmas scaled
        self.gap_keyframes, self._gap_variance = build.cfg.isam2.judge_gap_keyframes, build.cfg.isam2.gap_odometry_scale**2
        self.up_S = np.asarray(up_S, dtype=float)
        self._cos_level = float(np.cos(np.radians(build.cfg.isam2.freeze_max_tilt_deg)))
        self._gap: set[int] = set()  # keyframes whose step in is a gap's
        self._stretch: list[Keyframe] = []  # `follow`'s current stretch without upright planes...
        self._before: Keyframe | None = None  # ...and the keyframe before it
        self._drift = DriftRates()
        self.variance = np.ones(2)  # factors on the given noise: rotation, translation
        self._poses: dict[int, np.ndarray] = {}  # keyframe -> its front-end pose (parsing it is slow)
        self._covs: dict[int, np.ndarray] = {}  # keyframe -> its step's covariance as given
        # keyframe -> its step's factor under the drift and variance as they stand (the offline
        # graph is rebuilt a score of times, its odometry changes only with them)
        self._factors: dict[int, gtsam.NonlinearFactor] = {}

    @property
    def drift(self) -> DriftRates:
        return self._drift

    @drift.setter
    def drift(self, rates: DriftRates) -> None:
        self._drift, self._factors = rates, {}

    @property
    def variance(self) -> np.ndarray:
        return self._variance

    @variance.setter
    def variance(self, factors: np.ndarray) -> None:
        self._variance, self._factors = np.asarray(factors, dtype=float), {}
        scale = np.sqrt(np.repeat(self._variance, 3))
        self._scale = np.outer(scale, scale)

    def scaled(self, sigma_scale: float) -> "OdometryModel":
        """This model with its noise's sigmas scaled (the same poses and drift)."""
        model = copy.copy(self)
        model.variance = self.variance * sigma_scale**2
        return model

    def pose(self, kf: Keyframe) -> np.ndarray:
        """The front-end's `T_S_C` of keyframe `kf` (one keyframe per index)."""
        if kf.index not in self._poses:
            self._poses[kf.index] = kf.pose
        return self._poses[kf.index]

    def _given_cov(self, kf: Keyframe) -> np.ndarray:
        if kf.index not in self._covs:
            self._covs[kf.index] = self.build.default_odometry_cov if kf.cov is None else np.asarray(kf.cov)
        return self._covs[kf.index]

    def _cov(self, kf: Keyframe) -> np.ndarray:
        return self._given_cov(kf) * (self._scale * self._gap_variance if kf.index in self._gap else self._scale)

    def holds_heading(self, kf: Keyframe) -> bool:
        """Whether keyframe `kf` sees an upright plane: level ones (floors, ceilings) hold
        neither the heading nor the position along them, which is what drifts."""
        ux, uy, uz = (self.pose(kf)[:3, :3].T @ self.up_S).tolist()  # (in C; plain floats for a few planes)
        return any(abs(nx * ux + ny * uy + nz * uz) < self._cos_level * math.sqrt(nx * nx + ny * ny + nz * nz)
                   for nx, ny, nz in (p.n for p in kf.planes))

    def in_gap(self, kf: Keyframe) -> bool:
        """Whether the step into `kf` is a gap's (as far as marked)."""
        return kf.index in self._gap

    def mark_gaps(self, keyframes: list[Keyframe]) -> None:
        """The gaps of a whole walk."""
        held = [self.holds_heading(kf) for kf in keyframes]
        self._mark([kf for kf, gap in zip(keyframes[1:], gap_steps(held, self.gap_keyframes)) if gap])

    def follow(self, kf: Keyframe) -> list[tuple[Keyframe, Keyframe]]:
        """The next keyframe of a walk seen keyframe by keyframe (before its step's factor is
        made): marks the gaps as they show, and returns the steps before `kf` that a gap
        marked only now, whose factors must be made again (those of the stretch, once it is
        long enough to be one)."""
        if not self.holds_heading(kf):
            self._stretch.append(kf)
            if len(self._stretch) > self.gap_keyframes:
                self._mark([kf])
            elif len(self._stretch) == self.gap_keyframes:
                self._mark(self._stretch)
                steps = zip([self._before, *self._stretch], self._stretch[:-1])
                return [(previous, kf) for previous, kf in steps if previous is not None]
            return []
        if len(self._stretch) >= self.gap_keyframes:
            self._mark([kf])  # (the step out of it)
        self._before, self._stretch = kf, []
        return []

    def _mark(self, keyframes: list[Keyframe]) -> None:
        for kf in keyframes:
            self._gap.add(kf.index)
            self._factors.pop(kf.index, None)

    def step(self, previous: Keyframe, kf: Keyframe) -> np.ndarray:
        """The front-end's step from `previous` to `kf` without its drift."""
        T_S_prev = self.pose(previous)
        return self.drift.corrected(T_S_prev, inverse(T_S_prev) @ self.pose(kf))

    def factor(self, previous: Keyframe, kf: Keyframe) -> gtsam.NonlinearFactor:
        """That step as a factor, under the front-end's noise (`previous` is the keyframe
        before `kf`: one step per keyframe)."""
        if kf.index not in self._factors:
            self._factors[kf.index] = self.build.odometry(previous.index, kf.index, self.step(previous, kf), self._cov(kf))
        return self._factors[kf.index]

    def regular(self, keyframes: list[Keyframe]) -> np.ndarray:
        """Per step (into each keyframe but the first), whether its given noise is the walk's
        usual: a step the front-end gives a covariance `_JUMP` times the median's or more (a
        relocalisation, a jump it knows of) is no part of a drift, which is steady."""
        traces = np.array([np.trace(self._given_cov(kf)) for kf in keyframes[1:]])
        return traces < _JUMP * np.median(traces) if len(traces) else np.zeros(0, dtype=bool)

    def fitted_drift(self, keyframes: list[Keyframe], T_S_C_smoothed: list[np.ndarray], probability: float) -> DriftRates:
        """The drift rates the smoothed poses of `keyframes` show against the front-end's
        (`drift.estimate`, significant at `probability`), from its `regular` steps."""
        regular = self.regular(keyframes)
        return drift.estimate([self.pose(kf) for kf in keyframes], T_S_C_smoothed, self.step_sigmas(keyframes, regular),
                              probability, regular)

    def step_sigmas(self, keyframes: list[Keyframe], regular: np.ndarray | None = None) -> tuple[float, float]:
        """The noise per step and axis, rotation (rad) and translation (m), on average over the
        `regular` steps (computed here if not given)."""
        regular = self.regular(keyframes) if regular is None else regular
        steps = [kf for kf, usual in zip(keyframes[1:], regular) if usual] or keyframes[:1]
        diag = np.array([self._given_cov(kf) for kf in steps]).diagonal(axis1=1, axis2=2).mean(axis=0) \
            * np.repeat(self.variance, 3)
        return float(np.sqrt(diag[:3].mean())), float(np.sqrt(diag[3:].mean()))

    def estimated_variance(self, keyframes: list[Keyframe], graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                           confidence: float, floor: float, max_steps: int) -> np.ndarray:
        """The variance factors (rotation, translation) the smoothed steps of `graph` at
        `values` show, between `floor`^2 and 1: variance component estimation over the
        odometry factors, as for the walls' tolerance, from at most `max_steps` steps spread
        evenly over the walk (each needs the joint marginal of its two poses: `JointMarginals`
        onto the poses of `_STEPS_AT_ONCE` steps at a time, equal to gtsam's `Marginals` pair by pair to
        1e-13 and 2-3x faster on a 600-keyframe walk; all of the walk's at once would be one
        dense marginal of thousands of dimensions)."""
        steps = [(previous, kf) for previous, kf in zip(keyframes, keyframes[1:]) if not self.in_gap(kf)]
        if len(steps) > max_steps:
            steps = [steps[i] for i in np.unique(np.linspace(0, len(steps) - 1, max_steps).round().astype(int))]
        terms = []
        for start in range(0, len(steps), _STEPS_AT_ONCE):
            chunk = steps[start:start + _STEPS_AT_ONCE]
            joint = JointMarginals(graph, values, [X(kf.index) for step in chunk for kf in step])
            for previous, kf in chunk:
                A, b = self.factor(previous, kf).linearize(values).jacobian()
                terms.append(redundancy(A, -b, joint([X(previous.index), X(kf.index)])))
        return np.clip(self.variance * variance_factors(terms, confidence, _POSE_GROUPS), floor**2, 1.0)

    def summary(self) -> dict:
        scale = np.sqrt(self.variance)
        return {**self.drift.summary(), "odometry_sigma_scale": {"rotation": float(scale[0]), "translation": float(scale[1])}}


def gap_steps(held: list[bool], min_run: int) -> np.ndarray:
    """Per step (into each keyframe but the first), whether it lies in a stretch of at least
    `min_run` keyframes that hold no heading (`held`: per keyframe, whether it sees an upright
    plane), or leads out of one. Over such a stretch the front-end's errors add up alike (a
    heading turning steadily), faster than its per-step covariance says, and nothing but the
    odometry holds the walk."""
    given = np.zeros(len(held), dtype=bool)
    start = None
    for i, holds in enumerate([*held, True]):
        if not holds and start is None:
            start = i
        elif holds and start is not None:
            if i - start >= min_run:
                given[start:min(i + 1, len(held))] = True  # (and the step out of it)
            start = None
    return given[1:]
