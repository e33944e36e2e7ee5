"""Graduated non-convexity with the Geman-McClure cost (`bimgraph.backend.gnc`)."""

import numpy as np
import pytest

from bimgraph.backend import gnc

C2 = 9.0  # residuals beyond 3 sigma are outliers


def test_nothing_to_decide_when_every_residual_is_an_inlier():
    assert gnc.initial_mu(np.array([0.5, 8.9]), C2) is None
    assert gnc.initial_mu(np.array([]), C2) is None


def test_schedule_descends_by_the_step_to_the_robust_cost():
    mu = gnc.initial_mu(np.array([1.0, 400.0]), C2)
    assert mu == pytest.approx(2 * 400.0 / C2)
    steps = gnc.schedule(mu, 1.4)
    assert steps[0] == mu and steps[-1] == 1.0
    assert np.allclose(np.array(steps[:-2]) / np.array(steps[1:-1]), 1.4)
    assert gnc.schedule(0.5, 1.4) == [0.5]


def test_weights_start_near_least_squares_and_end_robust():
    r2 = np.linspace(0.0, 400.0, 401)
    first = gnc.gm_weights(r2, gnc.initial_mu(r2, C2), C2)
    assert first.min() > 0.4  # every residual still counts: the surrogate is convex over them
    last = gnc.gm_weights(r2, 1.0, C2)
    assert last[0] == 1.0 and last[-1] < 1e-3
    for w in (first, last):
        assert np.all(np.diff(w) < 0)


def fit_line(x, y, w):
    A = np.stack([x, np.ones_like(x)], axis=1) * np.sqrt(w)[:, None]
    return np.linalg.lstsq(A, y * np.sqrt(w), rcond=None)[0]


def test_gnc_finds_the_consistent_majority_from_a_start_the_outliers_decide():
    """A line through 60 points with 0.1 noise and 40 outliers all on one side, pulling least
    squares far off: after GNC's schedule exactly the inliers are within the threshold."""
    rng = np.random.default_rng(0)
    x = rng.uniform(-5, 5, 100)
    y = 0.5 * x + 1.0 + rng.normal(0, 0.1, 100)
    outlier = np.arange(100) < 40
    y[outlier] += rng.uniform(2.0, 6.0, outlier.sum())
    sigma = 0.1

    def squared_residuals(line):
        return ((y - x * line[0] - line[1]) / sigma) ** 2

    line = fit_line(x, y, np.ones(100))
    r2 = squared_residuals(line)
    assert np.sum(r2[~outlier] > C2) > 10  # least squares alone fits the inliers badly
    for mu in gnc.schedule(gnc.initial_mu(r2, C2), 1.4):
        line = fit_line(x, y, gnc.gm_weights(r2, mu, C2))
        r2 = squared_residuals(line)
    assert np.array_equal(r2 <= C2, ~outlier)
    assert abs(line[0] - 0.5) < 0.01 and abs(line[1] - 1.0) < 0.03
