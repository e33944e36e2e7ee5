"""The front-end's systematic drift, measured from the data. Pure maths, no graph.

A tracker's odometry is not only noisy, it can be biased: its heading turns steadily as it
goes, its position runs off in one direction, and each step's length is off by a share (a
wheel odometry's or a visual-inertial tracker's scale error; the simulator's front-end does all
three, per metre travelled). Odometry factors with white noise cannot say that: between the
walls that pin the poses, the
estimate follows the biased steps, and a wall seen only from there is measured off by what the
bias added (centimetres over a room). So the estimator measures the drift: each step's
discrepancy between the front-end's relative pose and the smoothed one, rotated into the
front-end's frame S, is fitted by least squares as a constant rate per metre travelled, for
rotation and for translation, with the scale (a share of the step itself) beside the latter,
and the odometry factors take them out of their measurements. The
smoothed poses follow the biased odometry in part, so the fit is repeated on the corrected
graph until the rates settle: a fixed point, where each solve recovers a share of what remains
(small where the odometry is precise), so the iteration extrapolates by that share (`Settle`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from bimgraph.geometry import make_pose

# the rates as one vector (`as_vector`): rotation, then translation with the scale (all m/m)
_BLOCKS = (slice(0, 3), slice(3, 7))


@dataclass(frozen=True)
class DriftRates:
    """Rates per metre travelled, in the front-end's frame S, of the correction its steps need
    (the drift, negated): `rotation` (rad/m, a rotation vector) and `translation` (m/m: 0.01
    is 1 % of the distance); `scale`, the share of each step's own length (-0.0099 takes the
    excess out of steps 1 % too long)."""

    rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 0.0

    def corrected(self, T_S_prev: np.ndarray, T_prev_k: np.ndarray) -> np.ndarray:
        """The front-end's step `T_prev_k` from its pose `T_S_prev`, without the drift."""
        if self.is_zero():
            return T_prev_k
        R_S_prev = T_S_prev[:3, :3]
        length = float(np.linalg.norm(T_prev_k[:3, 3]))
        # a rotation about S's axes, seen from the previous keyframe, before the step's own
        rotation = gtsam.Rot3.Expmap(R_S_prev.T @ self.rotation * length).matrix()
        return make_pose(rotation @ T_prev_k[:3, :3],
                         (1.0 + self.scale) * T_prev_k[:3, 3] + R_S_prev.T @ self.translation * length)

    def differs(self, other: DriftRates, rtol: float) -> bool:
        """Whether the rates differ by more than `rtol` of their size (either's)."""
        ours, theirs = as_vector(self), as_vector(other)
        return any(np.linalg.norm(ours[b] - theirs[b]) > rtol * max(np.linalg.norm(ours[b]), np.linalg.norm(theirs[b]), 1e-12)
                   for b in _BLOCKS)

    def __post_init__(self):
        # (asked for every odometry factor made; numpy's `any` twice costs more than the step)
        object.__setattr__(self, "_zero", not (self.rotation.any() or self.translation.any() or self.scale))

    def is_zero(self) -> bool:
        return self._zero

    def summary(self) -> dict:
        """The rates as a user reads them: degrees and percent per metre, the scale in percent."""
        return {"rotation_deg_per_m": np.round(np.degrees(self.rotation), 6).tolist(),
                "translation_percent": np.round(100.0 * self.translation, 6).tolist(),
                "scale_percent": round(100.0 * self.scale, 6)}


def estimate(T_S_C_frontend: list[np.ndarray], T_S_C_smoothed: list[np.ndarray],
             step_sigmas: tuple[float, float] | None = None, probability: float = 0.999,
             regular: np.ndarray | None = None) -> DriftRates:
    """The constant drift rates that best explain, in least squares, each step's difference
    between the front-end's relative pose and the smoothed one (both sequences of `T_S_C`).
    With `step_sigmas` (the odometry's noise per step and axis: rotation rad, translation m),
    a rate (rotation or translation) not significant at `probability` is zero: a front-end
    whose error is a random walk shows a trend too, which is no bias to take out. Steps that
    `regular` (per step) marks False count for nothing (a relocalisation's jump of 2 m had
    been fitted as a drift of -21 % of the distance)."""
    F, T = np.asarray(T_S_C_frontend), np.asarray(T_S_C_smoothed)
    if len(F) < 2:
        return DriftRates()
    R_prev, R_next = F[:-1, :3, :3], F[1:, :3, :3]
    Rs_prev, Rs_next = T[:-1, :3, :3], T[1:, :3, :3]
    # the steps in the previous keyframe's frame: front-end z, smoothed r
    z_t = np.einsum("nji,nj->ni", R_prev, F[1:, :3, 3] - F[:-1, :3, 3])
    r_t = np.einsum("nji,nj->ni", Rs_prev, T[1:, :3, 3] - T[:-1, :3, 3])
    z_R = np.einsum("nji,njk->nik", R_prev, R_next)
    r_R = np.einsum("nji,njk->nik", Rs_prev, Rs_next)
    lengths = np.linalg.norm(z_t, axis=1)
    if regular is not None:
        lengths = lengths * regular
    # each step's difference, rotated into S by the front-end's previous pose
    rotations = np.einsum("nij,nj->ni", R_prev, Rotation.from_matrix(np.einsum("nij,nkj->nik", r_R, z_R)).as_rotvec())
    translations = np.einsum("nij,nj->ni", R_prev, r_t - z_t)
    norm = float(lengths @ lengths)
    if norm == 0.0:
        return DriftRates()
    rates = [lengths @ rotations / norm, lengths @ translations / norm]
    steps_S = (F[1:, :3, 3] - F[:-1, :3, 3]) * (lengths > 0)[:, None]
    scale = _scale(translations, steps_S, lengths, None if step_sigmas is None else step_sigmas[1], probability)
    if scale:
        rates[1] = (lengths @ translations - scale * (lengths @ steps_S)) / norm
    if step_sigmas is not None:
        # each component of a rate has the standard error sigma / sqrt(sum of squared lengths)
        for block, sigma in enumerate(step_sigmas):
            if float(rates[block] @ rates[block]) * norm / sigma**2 < chi2.ppf(probability, 3):
                rates[block] = np.zeros(3)
    return DriftRates(*rates, scale=scale)


def _scale(translations: np.ndarray, steps_S: np.ndarray, lengths: np.ndarray, sigma: float | None,
           probability: float) -> float:
    """The scale that, beside a translation rate, best explains the steps' `translations`
    (their differences in S); zero unless significant at `probability` against `sigma`, the
    translation's noise per step and axis. A walk along one line cannot tell the two apart,
    and its scale comes out insignificant: the rate alone explains it, as before the scale."""
    # least squares for (rate, scale) with the rate eliminated: the scale's normal equation
    # is the steps' part not along the length-weighted mean direction
    norm = float(lengths @ lengths)
    mean_step = lengths @ steps_S / norm
    info = float(np.einsum("ni,ni->", steps_S, steps_S) - norm * mean_step @ mean_step)
    if info <= 1e-12 * norm:
        return 0.0
    scale = float(np.einsum("ni,ni->", steps_S, translations) - norm * mean_step @ (lengths @ translations / norm)) / info
    if sigma is not None and scale**2 * info / sigma**2 < chi2.ppf(probability, 1):
        return 0.0
    return scale


def as_vector(rates: DriftRates) -> np.ndarray:
    return np.concatenate([rates.rotation, rates.translation, [rates.scale]])


class Settle:
    """The fixed point of `rates -> estimate(frontend, smoothed under rates)`. Each solve
    recovers a share `s` of the rates still in the odometry, `fit(r) - r = s (r* - r)`, so two
    fits measure the share (a secant, separately for rotation and for translation with scale) and the next
    guess is `r + (fit(r) - r) / s` (the share kept within [min_share, 1])."""

    def __init__(self, min_share: float = 0.05):
        self.min_share = min_share
        self.last: tuple[np.ndarray, np.ndarray] | None = None  # the last guess and its step

    def next(self, current: DriftRates, fitted: DriftRates) -> DriftRates:
        r = as_vector(current)
        step = as_vector(fitted) - r
        guess = r + step
        if self.last is not None:
            r_last, step_last = self.last
            for block in _BLOCKS:
                moved = r[block] - r_last[block]
                if float(moved @ moved) > 0.0:
                    share = -float((step[block] - step_last[block]) @ moved) / float(moved @ moved)
                    guess[block] = r[block] + step[block] / np.clip(share, self.min_share, 1.0)
        self.last = (r, step)
        return DriftRates(guess[:3], guess[3:6], float(guess[6]))
