"""The robust estimators the diagnosis is built on (rig/robust.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.diagnosis.robust import (
    HUBER_C,
    delay_centre,
    delay_centre_slope,
    huber_loss,
    huber_mean,
    irls,
    mad_scale,
    robust_nll,
    robust_rms,
)


def test_irls_is_not_pulled_by_outliers_that_least_squares_follows() -> None:
    """A line through unit noise with a tenth of its samples 30 deviations out:
    least squares moves its slope by several of its standard errors, the Huber fit
    stays within a fraction of one."""
    rng = np.random.default_rng(0)
    x = np.column_stack([np.ones(400), np.linspace(-1.0, 1.0, 400)])
    z = x @ np.array([0.5, 2.0]) + rng.normal(0.0, 1.0, 400)
    z[::10] += 30.0 * np.sign(x[::10, 1])
    least_squares = np.linalg.lstsq(x, z, rcond=None)[0]
    robust = irls(z, x, iterations=50)
    assert abs(least_squares[1] - 2.0) > 1.0
    assert abs(robust[1] - 2.0) < 0.3 and abs(robust[0] - 0.5) < 0.2


def test_a_prior_holds_a_parameter_the_data_do_not_see() -> None:
    """Two identical columns: without a prior their split is arbitrary; with priors
    of equal size each takes half, the sum still fits the data."""
    rng = np.random.default_rng(1)
    column = rng.normal(0.0, 1.0, 300)
    x = np.column_stack([column, column])
    z = 3.0 * column + rng.normal(0.0, 0.1, 300)
    theta = irls(z, x, prior=np.array([10.0, 10.0]))
    assert theta == pytest.approx([1.5, 1.5], abs=0.02)


def test_the_huber_loss_is_quadratic_inside_and_linear_outside_its_threshold() -> None:
    z = np.array([0.0, 0.5, HUBER_C, 10.0, -10.0])
    loss = huber_loss(z)
    assert loss[:3] == pytest.approx(0.5 * z[:3] ** 2)
    assert loss[3] == pytest.approx(HUBER_C * (10.0 - 0.5 * HUBER_C)) and loss[4] == loss[3]
    assert robust_nll(np.array([1.0]), 2.0)[0] == pytest.approx(np.log(2.0) + 0.125)


def test_robust_scales_and_locations_shrug_off_outliers() -> None:
    rng = np.random.default_rng(2)
    values = rng.normal(1.0, 0.2, 5000)
    values[:250] = 50.0                                   # 5 % garbage
    assert mad_scale(values) == pytest.approx(0.2, rel=0.1)
    assert huber_mean(values, 0.2) == pytest.approx(1.0, abs=0.03)
    assert mad_scale(np.array([np.nan, np.nan])) == 1.0 and mad_scale(np.full(5, 3.0)) == 1.0
    assert np.isnan(huber_mean(np.array([]), 1.0))


def test_the_robust_rms_is_the_rms_for_small_residuals_and_grows_slower_past_the_threshold() -> None:
    scale = np.full(4, 0.5)
    small = np.array([0.1, -0.2, 0.3, -0.1])
    assert robust_rms(small, scale) == pytest.approx(np.sqrt(np.mean(small ** 2)))
    large = np.array([0.1, -0.2, 0.3, 100.0])
    assert robust_rms(large, scale) < 0.2 * np.sqrt(np.mean(large ** 2))
    assert np.isnan(robust_rms(np.array([]), np.array([])))


@pytest.mark.parametrize("seed", range(5))
def test_a_delay_changed_on_one_anchor_shows_on_that_anchor(seed: int) -> None:
    """Delays are reported against their centre (TDOA sees no delay common to all
    anchors). A change of one anchor's delay, as a control and its injected copy
    differ, reads on that anchor within a quarter of its size whichever anchor it is
    (a median of eight averages the middle two: 12 cm on a middle anchor read as
    6.7 cm), and one anchor's large delay moves the others' by well under what a
    mean would."""
    delays = np.random.default_rng(seed).normal(0.0, 0.15, 8)
    for k in range(8):
        changed = delays.copy()
        changed[k] += 0.12
        read = (changed[k] - delay_centre(changed)) - (delays[k] - delay_centre(delays))
        assert abs(read - 0.12) <= 0.03, f"anchor {k}: 0.12 m read as {read:.3f} m"
    large = delays.copy()
    large[0] = -0.7
    others = np.delete(delays, 0)
    assert abs(delay_centre(large) - delay_centre(others)) < 0.6 * abs(np.mean(large) - np.mean(others))


@pytest.mark.parametrize("seed", range(3))
def test_the_delay_centres_slope_is_its_numerical_derivative(seed: int) -> None:
    """The reported delays' standard errors are taken about their centre through its
    slope: it must be the centre's derivative, also with one delay far beyond the
    spread (which hardly moves it) and with the delays spread wide."""
    rng = np.random.default_rng(seed)
    for delays in (rng.normal(0.0, 0.1, 8), np.r_[rng.normal(0.0, 0.1, 7), -0.9], rng.normal(0.0, 0.4, 8)):
        h = 1e-6
        numeric = [(delay_centre(delays + h * e) - delay_centre(delays - h * e)) / (2 * h) for e in np.eye(8)]
        assert np.allclose(delay_centre_slope(delays), numeric, atol=1e-4)
