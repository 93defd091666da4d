"""Naming by backward elimination (rig.diagnosis.selection.name_terms) on synthetic design columns:
a gyroscope scale pays for the axes it is named on, not for all three."""

from __future__ import annotations

import numpy as np
import pytest

from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER, Candidate
from rig.diagnosis.selection import name_terms
from rig.diagnosis.terms import Design, Term

SAMPLES = 3000


def _gyro_scale(columns: np.ndarray, by_axis: bool = True) -> Term:
    candidate = Candidate("imu_gyro_scale", "gyro", "scale", 3, neutral=1.0, prior=0.2, bound=0.5, by_axis=by_axis)
    candidate.columns = columns
    return Term(candidate, columns)


def _data(half_chi_square: list[float], seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Three unit-noise design columns and a standardised residual whose signal on each
    removes about `half_chi_square` of the robust loss: its noise has no part along the
    columns, so the gains are the signal's."""
    rng = np.random.default_rng(seed)
    columns = rng.normal(size=(SAMPLES, 3))
    noise = rng.normal(size=SAMPLES)
    noise -= columns @ np.linalg.lstsq(columns, noise, rcond=None)[0]
    theta = np.sqrt(2.0 * np.asarray(half_chi_square) / SAMPLES)
    return columns, columns @ theta + noise


def _gain(z: np.ndarray, columns: np.ndarray) -> float:
    term = _gyro_scale(columns)
    return Design(z, [term]).gain(term)


def test_a_vector_effect_on_one_axis_pays_for_that_axis_only() -> None:
    """A z scale that removes more than one parameter's bar and less than three's is
    named, on z, its other axes neutral and not fitted."""
    columns, z = _data([0.0, 0.0, 13.5])
    one, three = PENALTY_PER_PARAMETER + MIN_EVIDENCE, 3 * PENALTY_PER_PARAMETER + MIN_EVIDENCE
    assert _gain(z, columns) < three and _gain(z, columns[:, 2:]) >= one     # the case this is about
    [named] = name_terms(z, [_gyro_scale(columns)], [])
    assert named.dropped in [(0, 1), (1, 0)] and named.parameters == 1
    assert named.theta[0] == named.theta[1] == 0.0 and named.theta[2] > 0.0
    assert named.supported


def test_a_vector_effect_named_whole_goes_whole() -> None:
    """The same signal on an effect that is not named axis by axis (an accelerometer
    bias or scale) does not pay for its three axes."""
    columns, z = _data([0.0, 0.0, 13.5])
    assert name_terms(z, [_gyro_scale(columns, by_axis=False)], []) == []


def test_a_vector_effect_on_every_axis_keeps_every_axis() -> None:
    columns, z = _data([20.0, 20.0, 20.0])
    [named] = name_terms(z, [_gyro_scale(columns)], [])
    assert named.dropped == () and named.parameters == 3


@pytest.mark.parametrize("seed", range(5))
def test_noise_alone_names_no_axis(seed: int) -> None:
    rng = np.random.default_rng(seed)
    columns, z = rng.normal(size=(SAMPLES, 3)), rng.normal(size=SAMPLES)
    assert name_terms(z, [_gyro_scale(columns)], []) == []
