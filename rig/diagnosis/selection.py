"""Which effects a channel supports, and their estimates (steps 3–5 of rig.diagnosis.diagnose's
method): naming by backward elimination (the robust loss a term removes against a
penalty per parameter), estimates in the joint fit of the named terms of their rank
or a simpler one (ORDER), look-alikes noted, an IMU axis's look-alike fitted in its
place, effects confined in time where a window pays, NLOS regions searched by mean
shift (held out) and by the shape of the residuals (rig.diagnosis.nlos_mixture)."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from rig.diagnosis import nlos_mixture
from rig.diagnosis.candidates import Candidate
from rig.diagnosis.channels import Channel, Problem
from rig.diagnosis.confined import confine_in_time, nlos_shapes, nlos_terms
from rig.diagnosis.terms import (
    FAMILIES,
    LOOK_ALIKE_MARGIN,
    Design,
    Term,
    axis_term,
    delay_family,
    estimate_terms,
    free_offset_terms,
    rank_of,
    refit,
    remainder,
    richer_than,
    take_fit,
    without_axes,
)

log = logging.getLogger(__name__)





def name_terms(z: np.ndarray, terms: list[Term], pool: list[Term], fixed: list[Term] = ()) -> list[Term]:
    """Backward elimination: every term's evidence is the robust loss it removes given
    all the others but its richer look-alikes, and the weakest goes while it does not
    pay for its parameters. Look-alikes of equal rank are judged given each other, so
    of two the one that adds less goes first and the other keeps the signal they
    share (a scale factor in hover reads as a bias unless the thrust varies enough
    to tell them apart). A clock drift is judged about a free time offset from `pool`
    (named or not), and of the two, when neither is supported given the other, the
    drift goes first: a drift is an offset that grows, and only the growth tells it
    from one. A supported delay keeps every anchor's delay: they are measured
    against each other. The `fixed` terms stay, with the evidence they came with
    (what they were named on)."""
    named_on = {id(t): t.evidence for t in fixed}
    terms = list(terms)
    while terms:
        design = Design(z, terms)
        take_fit(terms, design.theta)
        _judge(z, terms, design, free_offset_terms(terms, pool))
        supported = {t.candidate.effect for t in terms if t.supported}
        removable = [t for t in terms if t.candidate.effect not in FAMILIES & supported and id(t) not in named_on]
        weakest = _weakest(removable)
        if weakest is None or weakest.supported:
            break
        fewer = _fewer_axes(z, weakest, terms)
        if fewer is not None:
            log.debug("- %s axis %d (evidence %.1f given the others)", weakest.key, fewer.dropped[-1],
                      weakest.evidence)
            terms = [fewer if t is weakest else t for t in terms]
            continue
        log.debug("- %s (evidence %.1f given the others)", weakest.key, weakest.evidence)
        terms.remove(weakest)
    for t in fixed:
        t.evidence = named_on[id(t)]
    return terms


def _fewer_axes(z: np.ndarray, term: Term, terms: list[Term]) -> Term | None:
    """An effect named axis by axis (Candidate.by_axis: the gyroscope scale) that does
    not pay for all its axes, without the axis that adds least given the others (its
    column zeroed: neutral there), or None for a term named whole or of one axis."""
    if not term.candidate.by_axis or term.parameters < 2 or term.extra:
        return None
    richer = {id(t) for t in richer_than(term, terms)}
    rest = [t for t in terms if t is not term and id(t) not in richer]

    def gain_of(j: int) -> float:
        own = axis_term(term, j)
        return Design(z, [*rest, *without_axes(term, [j]), own]).gain(own)

    weakest = min((j for j in range(term.columns.shape[1]) if j not in term.dropped), key=gain_of)
    columns = term.columns.copy()
    columns[:, weakest] = 0.0
    return Term(term.candidate, columns, dict(term.extra), dropped=(*term.dropped, weakest))


def _weakest(removable: list[Term]) -> Term | None:
    """The term to drop: the least supported, but a clock drift before a time offset
    when neither pays given the other (a flight that cannot tell them apart has its
    timing named as the offset, the same on every run and on its control)."""
    weakest = min(removable, key=lambda t: t.net_evidence, default=None)
    if weakest is None or weakest.candidate.effect != "time_offset":
        return weakest
    drift = [t for t in removable if t.candidate.effect == "clock_drift" and not t.supported]
    return drift[0] if drift else weakest


def _judge(z: np.ndarray, terms: list[Term], design: Design, free_offset: list[Term] = ()) -> None:
    """Every term's evidence given the others but its richer look-alikes. A complete
    delay family is judged against a reference anchor, the median one (against all
    the others an anchor's delay adds nothing: they can all move together), and the
    reference against the next one. A clock drift is judged with `free_offset` too."""
    family = sorted(delay_family(terms), key=lambda t: t.theta[0])
    judges = {id(t): design for t in terms}
    if family:
        middle = len(family) // 2
        reference, second = family[middle], family[middle - 1]
        without_reference = Design(z, [t for t in terms if t is not reference])
        judges.update({id(t): without_reference for t in family if t is not reference})
        judges[id(reference)] = Design(z, [t for t in terms if t is not second])
    if free_offset:
        with_offset = Design(z, terms + list(free_offset))
        judges.update({id(t): with_offset for t in terms if t.candidate.effect == "clock_drift"})
    for t in terms:
        t.evidence = judges[id(t)].gain(t, richer_than(t, terms))


def select(problem: Problem, channel: Channel, pool: list[Candidate]
           ) -> tuple[list[Term], Channel, list[nlos_mixture.NlosShapeFit]]:
    """The channel's effects, named and measured.

    Which terms are named is decided by backward elimination (name_terms). A named term's
    estimate is its value in the joint fit of the named terms of its rank or a
    simpler one (ORDER): the simplest explanation takes the signal it can, a richer
    one only what is left (by Frisch-Waugh-Lovell, its fit on the part the simpler
    ones cannot explain), and whether a richer effect is named or not does not move
    the simpler ones' estimates; a richer TDOA term is fitted given every simplest
    (rank-0) candidate too, named or not, so neither does a simplest one named on
    one recording and not on another; so what an effect added to a recording
    changes in them is mostly that effect (a comparison with a control recording
    needs that).
    NLOS regions are searched on what all parametric candidates leave, first as a
    mean shift, then by the shape of the residuals (nlos_mixture); the mean excess
    of an NLOS found by its shape is taken out of the channel and every candidate
    named again on what is left (over half the flight a displacement would take it;
    one dropped against the excess may now be supported), but the simplest effects
    (timing, delays, lever arm) named on the channel as it was stay, with the
    evidence they were named on, and every simplest effect is estimated there: NLOS
    is the richest explanation, and which regions its shape finds must not move
    them nor drop them (shapes on several anchors can take part of a lever arm's or
    a time offset's signal); it may add one (an offset that pays only once the
    shapes are out); named effects are
    tried confined in time; the named effects, fitted jointly, are the model that
    re-simulates the recording. Returns the terms, the channel they were fitted on
    and the NLOS found by shape."""
    z = z_before_shapes = channel.z
    folds = channel.folds()
    terms = fresh_terms(pool, channel.name)
    named = name_terms(z, terms, terms)
    shapes, simplest = [], []
    if channel.name == "tdoa":
        nlos = nlos_terms(problem, channel, folds, terms)
        if nlos:
            terms += nlos
            named = name_terms(z, named + nlos, terms)
    refit(z, named)                 # the NLOS search refits every candidate
    if channel.name == "tdoa":
        taken = {t.candidate.fixed["anchor"] for t in named if t.candidate.effect == "nlos"}
        shapes = nlos_shapes(problem, channel, remainder(z, named), taken)
        if shapes:
            residual = problem.recorded("tdoa") - problem.predict_channel("tdoa", [f.effect() for f in shapes])
            channel = replace(channel, residual=residual)
            z = channel.z
            simplest = [t for t in named if rank_of(t) == 0]
            named = name_terms(z, terms, terms, simplest)
            refit(z, named)
    positions = problem.tag_positions() if channel.name == "tdoa" else None
    if confine_in_time(channel, named, positions):
        named = name_terms(z, named, terms, simplest)      # leaves them fitted jointly
    unnamed = unnamed_simplest_terms(terms, named, channel.name)
    estimate_terms(z, named, z_before_shapes, free_offset_terms(named, terms), unnamed, channel.slow_error_times())
    _note_look_alikes(z, named, terms)
    return named, channel, shapes


def fresh_terms(pool: list[Candidate], channel: str) -> list[Term]:
    """The channel's candidates as unfitted terms, with their catalog columns."""
    return [Term(c, c.columns) for c in pool if c.channel == channel]


def unnamed_simplest_terms(terms: list[Term], named: list[Term], channel: str) -> list[Term]:
    """The simplest (rank 0) of `terms` that are not among `named`, as unfitted terms:
    on TDOA, what a richer term is fitted along with (see select); none on an IMU
    channel, whose richer term (the rectification) is fitted given the named ones."""
    if channel != "tdoa":
        return []
    named_keys = {t.key for t in named}
    return [Term(t.candidate, t.candidate.columns) for t in terms if rank_of(t) == 0 and t.key not in named_keys]


LOOK_ALIKES = {"anchor_delay": ("anchor_position", "antenna_pattern"),
               "anchor_position": ("anchor_delay", "antenna_pattern"),
               "antenna_pattern": ("anchor_delay", "anchor_position"),
               "time_offset": ("clock_drift",), "clock_drift": ("time_offset",),
               "imu_accel_bias": ("imu_accel_scale", "imu_vibration_rectification"),
               "imu_accel_scale": ("imu_accel_bias",), "imu_vibration_rectification": ("imu_accel_bias",),
               "imu_gyro_bias": ("imu_gyro_scale",), "imu_gyro_scale": ("imu_gyro_bias",)}


def _note_look_alikes(z: np.ndarray, kept: list[Term], pool: list[Term]) -> None:
    """For each kept effect, the look-alikes left out (on the same anchor) that would
    have explained nearly as much in its place."""
    keys = {t.key for t in kept}
    for term in kept:
        anchor = term.candidate.fixed.get("anchor")
        others = [t for t in kept if t is not term and t not in richer_than(term, kept)]
        for alt in [Term(t.candidate, t.columns) for t in pool if t.key not in keys
                    and t.candidate.effect in LOOK_ALIKES.get(term.candidate.effect, ())
                    and t.candidate.fixed.get("anchor") == anchor]:
            gain = Design(z, others + [alt]).gain(alt)
            if gain - alt.cost >= term.net_evidence - LOOK_ALIKE_MARGIN:
                term.look_alikes.append((alt.key, round(gain, 1)))


# Look-alikes of one shape, axis by axis: over a flight in which an axis reads about
# the same all along (the accelerometer's z in hover) an IMU scale on it is a bias;
# far from the zero of the recording's clock a drift is an offset that hardly grows.
# No rule that does not depend on the trajectory can say which of two a recording has.
