"""An IMU axis's look-alike: where a named effect's axis is not told apart from its
look-alike's (a bias from a scale in hover), the look-alike as it would be fitted in
its place (report.json's `alternative_to` and `in_place_estimates`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rig.diagnosis.candidates import MIN_EVIDENCE
from rig.diagnosis.terms import (
    LOOK_ALIKE_MARGIN,
    Design,
    Term,
    axis_term,
    estimate_terms,
    free_offset_terms,
    rank_of,
    refit,
    richer_than,
    without_axes,
)

log = logging.getLogger(__name__)



AXIS_LOOK_ALIKES = {"imu_accel_bias": "imu_accel_scale", "imu_accel_scale": "imu_accel_bias",
                    "imu_gyro_bias": "imu_gyro_scale", "imu_gyro_scale": "imu_gyro_bias",
                    "time_offset": "clock_drift", "clock_drift": "time_offset"}


@dataclass
class Alternative:
    """An unnamed look-alike fitted in place of some axes of a named term: it explains
    them as well and the flight cannot tell the two apart."""

    term: Term                  # the look-alike, fitted (theta, estimate, std_err, evidence), neutral off `axes`
    replaces: Term              # the named term
    axes: list[int]             # the named term's axes it takes
    z_with: np.ndarray          # what the named terms leave with it in place of those axes

    @property
    def cost(self) -> float:
        """What its parameters on `axes` must pay for."""
        return self.term.candidate.penalty * len(self.axes)

    @property
    def supported(self) -> bool:
        """It pays for its parameters on `axes`, as a named term must (Term.supported)."""
        return self.term.evidence - self.cost >= MIN_EVIDENCE


def axis_alternatives(z: np.ndarray, named: list[Term], pool: list[Term],
                      z_simplest: np.ndarray | None = None) -> list[Alternative]:
    """For each named whole-flight term with a look-alike of the same shape
    (AXIS_LOOK_ALIKES), its axes that the unnamed look-alike's same axes explain
    nearly as well in their place, where the named one's axis does not pay for itself
    given the look-alike's (_cannot_tell). The look-alike is fitted on those axes in
    their place and reported when it pays for its parameters, so a flight that cannot
    tell a z scale from a z bias, or a drift from an offset, says both, and either
    compares with a control recording of the same flight. The look-alikes are all
    simplest (rank 0) effects: they are judged and estimated on `z_simplest` if given
    (the channel before NLOS found by its shape was taken out), as the simplest named
    ones are (select)."""
    judged_on = z if z_simplest is None else z_simplest
    out = []
    keys = {t.key for t in named}
    for term in named:
        effect = AXIS_LOOK_ALIKES.get(term.candidate.effect)
        alike = next((t for t in pool if t.candidate.effect == effect and t.key not in keys), None)
        if alike is None or term.extra:
            continue
        richer = {id(t) for t in richer_than(term, named)}
        rivals = [t for t in named if t is not term and id(t) not in richer]
        axes = [j for j in range(term.columns.shape[1]) if _cannot_tell(judged_on, term, alike, j, rivals)]
        if axes:
            alternative = _in_place(z, judged_on, term, alike, axes, named, pool)
            if alternative.supported:
                out.append(alternative)
    return out


def in_place_estimates(z: np.ndarray, named: list[Term], pool: list[Term],
                       z_simplest: np.ndarray | None = None) -> list[Alternative]:
    """For each named whole-flight term with a look-alike of the same shape
    (AXIS_LOOK_ALIKES), the look-alike fitted in its place on all of its axes, whether
    the flight tells the two apart or not, and whether it names the look-alike too
    (then without it on those axes): what another recording of the flight that cannot
    tell them apart reports in the named one's place (axis_alternatives), estimated
    here, so that the two compare (rig.diagnosis.compare): a scale one recording names
    jointly with a bias compares with the other's scale in its bias's place, not with
    its joint estimate."""
    judged_on = z if z_simplest is None else z_simplest
    out = []
    for term in named:
        effect = AXIS_LOOK_ALIKES.get(term.candidate.effect)
        alike = next((t for t in pool if t.candidate.effect == effect), None)
        if alike is None or term.extra or any(t.key == alike.key and t.extra for t in named):
            continue
        out.append(_in_place(z, judged_on, term, alike, list(range(term.columns.shape[1])), named, pool))
    return out


def _cannot_tell(z: np.ndarray, term: Term, alike: Term, j: int, rivals: list[Term]) -> bool:
    """Axis j of `term` is supported given the others, does not pay for itself given the
    same axis of `alike`, and that axis in its place explains nearly as much (within
    LOOK_ALIKE_MARGIN, as a look-alike)."""
    rest, own, other = [*rivals, *without_axes(term, [j])], axis_term(term, j), axis_term(alike, j)
    alone = Design(z, [*rest, own]).gain(own)
    if alone < MIN_EVIDENCE or Design(z, [*rest, other, own]).gain(own) - own.cost >= MIN_EVIDENCE:
        return False
    return Design(z, [*rest, other]).gain(other) >= alone - LOOK_ALIKE_MARGIN


def _in_place(z: np.ndarray, z_simplest: np.ndarray, term: Term, alike: Term, axes: list[int], named: list[Term],
              pool: list[Term]) -> Alternative:
    """`alike` on `axes` only, fitted with the named terms, `term` (and `alike`, where it
    is named too) without those axes:
    its evidence given the others but its richer look-alikes and its estimate given
    the simpler ones as a named term's (estimate_terms: a drift about a free offset, so it
    compares with a drift named on a control), both on `z_simplest`, and what the
    whole model leaves with it on `z`. Its other axes are neutral and not identified
    (their standard error is the prior's): the flight supported the look-alike on
    none of them."""
    others = [kept for t in named for kept in (without_axes(t, axes) if t is term or t.key == alike.key
                                               else [Term(t.candidate, t.columns, t.extra)])]
    stand_in = Term(alike.candidate, alike.columns[:, axes])
    richer = {id(t) for t in richer_than(stand_in, others)}
    evidence = Design(z_simplest, [t for t in others if id(t) not in richer] + [stand_in]).gain(stand_in)
    reported = [t for t in others if rank_of(t) <= rank_of(stand_in)] + [stand_in]
    estimate_terms(z, reported, z_simplest, free_offset_terms(reported, pool))
    z_with = refit(z, [*others, stand_in])

    def on_axes(values: np.ndarray, elsewhere: float) -> np.ndarray:
        full = np.full(alike.columns.shape[1], elsewhere)
        full[axes] = values
        return full

    fitted = Term(alike.candidate, alike.columns, theta=on_axes(stand_in.theta, 0.0), evidence=evidence,
                  estimate=on_axes(stand_in.estimate, 0.0), std_err=on_axes(stand_in.std_err, alike.candidate.prior),
                  std_err_white=on_axes(stand_in.std_err_white, alike.candidate.prior))
    return Alternative(fitted, term, axes, z_with)
