"""The physical range of a fitted effect (Candidate.excess) and the re-simulating model
(diagnose._model_terms), which leaves out what is fitted beyond it: a size beyond its
bound, or a gain of the calibrated link bias below zero (its pattern turned inside
out), which would re-simulate the opposite of the bias."""

from __future__ import annotations

import math

import numpy as np

from rig.diagnosis.candidates import Candidate
from rig.diagnosis.diagnose import _model_terms
from rig.diagnosis.terms import Term

SAMPLES = 4000


def _term(candidate: Candidate, column: np.ndarray) -> Term:
    candidate.columns = column[:, None]
    return Term(candidate, candidate.columns)


def test_a_size_is_measured_in_bounds_and_a_negative_gain_is_out_of_range() -> None:
    delay = Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": 2}, bound=1.0)
    gain = Candidate("link_bias", "tdoa", "gain", 1, bound=3.0, nonnegative=True)
    assert delay.excess(np.array([-2.0])) == 2.0
    assert gain.excess(np.array([1.5])) == 0.5
    assert math.isinf(gain.excess(np.array([-0.01])))


def test_the_model_leaves_out_a_negative_link_gain_and_keeps_the_rest() -> None:
    rng = np.random.default_rng(3)
    shape, delay_column = rng.normal(size=SAMPLES), rng.normal(size=SAMPLES)
    z = -0.5 * shape + 0.3 * delay_column + rng.normal(size=SAMPLES)
    link = _term(Candidate("link_bias", "tdoa", "gain", 1, bound=3.0, nonnegative=True), shape)
    delay = _term(Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": 2}, bound=1.0), delay_column)
    kept = _model_terms(z, [delay, link])
    assert kept == [delay]
    assert abs(float(delay.theta[0]) - 0.3) < 0.05

    symmetric = _term(Candidate("lever_arm", "tdoa", "offset_m", 1, bound=3.0), shape)
    assert _model_terms(z, [delay, symmetric]) == [delay, symmetric], "a negative value within a symmetric bound stays"
