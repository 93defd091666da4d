"""NLOS by the shape of the residuals, on synthetic residuals whose answer is known."""

from __future__ import annotations

import numpy as np

from rig.diagnosis import nlos_mixture as nm

N = 4000


def residuals(seed: int, nlos: bool, shift_inside: float = 0.0):
    """Signed standardised residuals of one anchor over a square flight area: normal
    noise with 2 % positive outliers everywhere; inside y > 0.5, optionally, half the
    samples get an exponential excess of mean 1.5 σ and all of them a shift (what a
    displaced anchor's fit leaves)."""
    rng = np.random.default_rng(seed)
    positions = np.column_stack([rng.uniform(-2, 2, N), rng.uniform(-2, 2, N), rng.uniform(0.5, 1.5, N)])
    s = rng.normal(size=N) + (rng.random(N) < 0.02) * rng.exponential(6.0, N)
    inside = positions[:, 1] > 0.5
    if nlos:
        s += inside * ((rng.random(N) < 0.5) * rng.exponential(1.5, N) + shift_inside)
    folds = np.minimum((np.arange(N) * 5) // N, 4)
    return positions, s, folds, inside


def test_the_exponentially_modified_normal_is_a_density_with_the_right_mean() -> None:
    x = np.linspace(-12, 60, 72001)
    for mean in (0.05, 0.7, 4.0):
        density = np.exp(nm.log_emg(x, 0.3, 1.2, mean))
        assert abs(np.trapezoid(density, x) - 1) < 1e-4
        assert abs(np.trapezoid(x * density, x) - (0.3 + mean)) < 1e-3


def test_a_heavy_upper_tail_in_part_of_the_flight_is_found_and_measured() -> None:
    positions, s, folds, inside = residuals(1, nlos=True, shift_inside=-0.4)
    fit = nm.fit_anchor(6, positions, s, folds, scale=0.2, min_gain=10.0)
    assert fit is not None and fit.evidence > 50
    found = fit.region.contains(positions)
    assert (found & inside).sum() / (found | inside).sum() > 0.7       # the region, as boxes on a quantile grid
    assert abs(fit.fraction * fit.mean_excess_m - 0.5 * 1.5 * 0.2) < 0.03    # mean excess, metres
    assert fit.nll_after < fit.nll_before


def test_a_few_corrupt_ranges_do_not_hide_the_tail() -> None:
    """Three ranges off by some 90 m (a real flight, 0425-traj17, has them) once
    stretched the base's spread to cover them, and no tail was found."""
    positions, s, folds, inside = residuals(1, nlos=True)
    s[np.flatnonzero(~inside)[:3]] = -467.0
    fit = nm.fit_anchor(6, positions, s, folds, scale=0.2, min_gain=10.0)
    assert fit is not None and fit.evidence > 50
    assert abs(fit.fraction * fit.mean_excess_m - 0.5 * 1.5 * 0.2) < 0.03


def test_outliers_everywhere_and_a_shift_are_not_nlos() -> None:
    positions, s, folds, inside = residuals(2, nlos=False)
    s = s + 0.8 * inside                     # a bias in part of the flight: a shift, no tail
    fit = nm.fit_anchor(6, positions, s, folds, scale=0.2, min_gain=-np.inf)
    assert fit is None or fit.evidence < 10.0


def test_a_stray_simplex_point_costs_likelihood_not_an_overflow() -> None:
    """The simplex search once pushed a log-spread to hundreds (a real flight,
    0425-traj10): the sizes are bounded, so the likelihood stays finite."""
    base = nm.Base.from_vector(np.array([0.0, 800.0, 0.0, -800.0, 0.0]))
    parts = np.stack(base.log_parts(np.linspace(-5.0, 5.0, 11), 0.0))
    assert np.isfinite(parts).all()
