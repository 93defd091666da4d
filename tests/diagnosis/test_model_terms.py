"""The re-simulating model (terms.model_terms): the named terms refitted jointly, less
those fitted beyond their physical range — a size beyond its bound first, the furthest
out first, and only then a nonnegative gain refitted below zero (the link bias's
pattern turned inside out). And how such a finding is reported (diagnose._finding's
flags in report.json)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.diagnosis.candidates import Candidate
from rig.diagnosis.findings import Finding
from rig.diagnosis.report import describe
from rig.diagnosis.terms import Term, model_terms

SAMPLES = 4000


def _term(candidate: Candidate, column: np.ndarray) -> Term:
    candidate.columns = column[:, None]
    return Term(candidate, candidate.columns)


def _link(column: np.ndarray) -> Term:
    return _term(Candidate("link_bias", "tdoa", "gain", 1, prior=1.0, bound=3.0, nonnegative=True), column)


def _displacement(column: np.ndarray) -> Term:
    return _term(Candidate("anchor_position", "tdoa", "offset_m", 1, {"anchor": 2}, bound=1.0), column)


def test_a_gain_refitted_below_zero_within_bounds_leaves_the_model() -> None:
    rng = np.random.default_rng(3)
    shape, other = rng.normal(size=SAMPLES), rng.normal(size=SAMPLES)
    z = -0.5 * shape + 0.3 * other + rng.normal(size=SAMPLES)
    link, displacement = _link(shape), _displacement(other)
    kept, wrong_sign = model_terms(z, [displacement, link])
    assert kept == [displacement] and wrong_sign == [link]
    assert abs(float(displacement.theta[0]) - 0.3) < 0.05, "the rest is refitted without it"


def test_a_gain_negative_only_beside_a_misfit_stays_once_the_misfit_leaves() -> None:
    """Session 56's defect: judged at once, the gain left before the displacement that
    made it negative. Here z = 0.5·shape + 2·e, and the displacement's column is
    e + shape, so jointly the gain is −1.5 (within its bound) and the displacement 2
    (twice its bound); once the displacement leaves, the gain is 0.5."""
    rng = np.random.default_rng(4)
    shape, e = rng.normal(size=SAMPLES), rng.normal(size=SAMPLES)
    z = 0.5 * shape + 2.0 * e + 0.1 * rng.normal(size=SAMPLES)
    link, displacement = _link(shape), _displacement(e + shape)
    kept, wrong_sign = model_terms(z, [displacement, link])
    assert kept == [link] and wrong_sign == []
    assert abs(float(link.theta[0]) - 0.5) < 0.05


def test_a_negative_value_within_a_symmetric_bound_stays() -> None:
    rng = np.random.default_rng(5)
    column = rng.normal(size=SAMPLES)
    lever = _term(Candidate("lever_arm", "tdoa", "offset_m", 1, bound=3.0), column)
    kept, wrong_sign = model_terms(-0.5 * column + rng.normal(size=SAMPLES), [lever])
    assert kept == [lever] and wrong_sign == []


def test_the_physical_range_of_a_gain_is_bounded_below_by_zero() -> None:
    column = np.ones(SAMPLES)
    gain = _term(Candidate("link_bias", "tdoa", "gain", 1, bound=3.0, nonnegative=True), column)
    offset = _term(Candidate("lever_arm", "tdoa", "offset_m", 1, bound=3.0), column)
    assert not gain.beyond_bound(np.array([1.5]))
    assert gain.beyond_bound(np.array([-0.01]))
    assert gain.beyond_bound(np.array([3.5]))
    assert not offset.beyond_bound(np.array([-1.5]))


def test_a_displacement_leaves_the_model_by_its_length_and_says_how_far_beyond_along_it() -> None:
    """[0.8, -0.8, 0] m lies within 1 m on every axis and 1.13 m from the survey: beyond
    the anchor's bound, first out of the model, and reported by its length, with the
    standard error along the fitted direction."""
    from rig.diagnosis.wording import beyond_bound_by

    rng = np.random.default_rng(6)
    columns = rng.normal(size=(SAMPLES, 3))
    candidate = Candidate("anchor_position", "tdoa", "offset_m", 3, {"anchor": 2})
    candidate.columns = columns
    displacement = Term(candidate, columns)
    assert displacement.beyond_bound(np.array([0.8, -0.8, 0.0]))
    assert not displacement.beyond_bound(np.array([0.9, 0.0, 0.3]))
    kept, _ = model_terms(columns @ np.array([0.8, -0.8, 0.0]) + 0.1 * rng.normal(size=SAMPLES), [displacement])
    assert kept == []
    size, bound, beyond = beyond_bound_by("anchor_position", {"anchor": 2, "offset_m": [0.8, -0.8, 0.0]},
                                          {"offset_m": [0.05, 0.05, 0.5]})
    assert (size, bound) == (pytest.approx(np.hypot(0.8, 0.8)), 1.0)
    assert beyond == pytest.approx((np.hypot(0.8, 0.8) - 1.0) / 0.05)   # the z error is across the fitted direction
    assert beyond_bound_by("anchor_position", {"offset_m": [0.9, 0.0, 0.3]}, {"offset_m": [0.1] * 3}) is None


def test_a_finding_left_out_for_its_sign_is_reported_as_a_finding_marked_not_simulated() -> None:
    finding = Finding("link_bias", "tdoa", [], {"gain": 1.2}, 50.0, 0.3, 0.2, {}, not_simulated=True)
    out = finding.to_json()
    assert out["not_simulated"] is True and "beyond_physical_bound" not in out
    assert "not_simulated" not in Finding("link_bias", "tdoa", [], {"gain": 1.2}, 50.0, 0.3, 0.2, {}).to_json()
    assert "not re-simulated" in describe(finding) and "beyond what" not in describe(finding)


def test_the_simplest_effects_are_estimated_without_one_fitted_beyond_its_bound() -> None:
    """A delay and a lever arm (both rank 0) fitted together: with the lever arm beyond
    its bound the delay's estimate is its fit without it (what the lever arm took of its
    signal included), and the lever arm keeps its own; within its bound, the joint fit."""
    from rig.diagnosis.terms import estimate_terms

    rng = np.random.default_rng(8)
    own, shared = rng.normal(size=SAMPLES), rng.normal(size=SAMPLES)
    noise = 0.1 * rng.normal(size=SAMPLES)

    def estimates(lever_size: float) -> tuple[float, float]:
        delay = _term(Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": 3}, prior=1.0, bound=1.5), shared)
        lever = _term(Candidate("lever_arm", "tdoa", "offset_m", 1, prior=1.0, bound=0.15), own + 0.5 * shared)
        estimate_terms(0.3 * shared + lever_size * lever.columns[:, 0] + noise, [delay, lever])
        return float(delay.estimate[0]), float(lever.estimate[0])

    delay, lever = estimates(1.0)
    assert abs(lever - 1.0) < 0.02                          # beyond 0.15: reported as fitted (not explained)
    assert abs(delay - 0.8) < 0.05                          # 0.3 of its own and 0.5 the lever arm's column held
    delay, lever = estimates(0.1)
    assert abs(lever - 0.1) < 0.02 and abs(delay - 0.3) < 0.02
