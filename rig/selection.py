"""Which effects a channel supports, and their estimates (steps 3–5 of rig.diagnose's
method): naming by backward elimination (the robust loss a term removes against a
penalty per parameter), estimates in the joint fit of the named terms of their rank
or a simpler one (ORDER), look-alikes noted, an IMU axis's look-alike fitted in its
place, effects confined in time where a window pays, NLOS regions searched by mean
shift (held out) and by the shape of the residuals (rig.nlos_mixture)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from rig import effects as fx
from rig import nlos_mixture
from rig.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER, Candidate
from rig.channels import FOLDS, TIME_BLOCKS, Channel, Problem
from rig.floor_error import ON_GROUND_M
from rig.region_scan import BoxScan
from rig.robust import (HUBER_C, MIN_SAMPLES, delay_centre, delay_centre_slope, huber_loss, irls, mad_scale,
                        weighted_normal)

log = logging.getLogger(__name__)

LOOK_ALIKE_MARGIN = 10.0       # candidates whose evidence came this close to the chosen one

WINDOWABLE = {"anchor_delay", "antenna_pattern", "imu_accel_bias", "imu_gyro_bias", "imu_accel_scale",
              "imu_gyro_scale"}
NLOS_PRIOR_M = 0.3            # small: what all of an anchor's ranges share is its delay's
NLOS_MIN_SHARE = 0.05         # an NLOS region holds at least this share of an anchor's samples ...
NLOS_MAX_SHARE = 0.5          # ... and not most of them: that is a delay, not NLOS
NLOS_MIN_T = 3.0              # and its mean excess this many standard errors above zero


@dataclass
class Term:
    """A candidate in the model: its columns (as used), unfitted settings and fit."""

    candidate: Candidate
    columns: np.ndarray
    extra: dict = field(default_factory=dict)       # during, region, ...
    theta: np.ndarray | None = None                  # in the model: the named terms fitted jointly
    estimate: np.ndarray | None = None               # as reported: given the simpler explanations
    std_err: np.ndarray | None = None                # of the estimate (posterior standard deviation)
    evidence: float = 0.0
    window_cost: bool = False                        # confined in time: its two ends are parameters too
    look_alikes: list = field(default_factory=list)  # (key, evidence) of candidates that did nearly as well
    dropped: tuple[int, ...] = ()                    # axes it is not named on (Candidate.by_axis; column zeroed)

    @property
    def key(self) -> str:
        return self.candidate.key

    @property
    def parameters(self) -> int:
        """How many parameters it fits (a dropped axis is neutral, not fitted)."""
        return self.columns.shape[1] - len(self.dropped)

    @property
    def prior(self) -> np.ndarray:
        return np.full(self.columns.shape[1], self.candidate.prior)

    @property
    def cost(self) -> float:
        return self.candidate.penalty * self.parameters + (2 * PENALTY_PER_PARAMETER if self.window_cost else 0)

    @property
    def net_evidence(self) -> float:
        """Its evidence beyond what its parameters must pay for."""
        return self.evidence - self.cost

    @property
    def supported(self) -> bool:
        return self.net_evidence >= MIN_EVIDENCE

    @property
    def on_top(self) -> bool:
        """Confined in time on top of its whole-flight value (a delay of the family):
        its whole-flight column, then its change inside the window."""
        return self.columns.shape[1] > self.candidate.size

    def param_map(self) -> np.ndarray:
        """The candidate's parameter as a linear map of the fit of the columns: a delay
        confined on top of its whole-flight value reports its value in the window,
        whole-flight value + change."""
        return np.ones((1, 2)) if self.on_top else np.eye(self.columns.shape[1])


def stacked(terms: list[Term]) -> tuple[np.ndarray, np.ndarray] | None:
    if not terms:
        return None
    return np.hstack([t.columns for t in terms]), np.concatenate([t.prior for t in terms])


def refit(z: np.ndarray, terms: list[Term]) -> np.ndarray:
    """Fit all terms jointly; returns the standardised residual left."""
    if not terms:
        return z
    x, prior = stacked(terms)
    _take_fit(terms, irls(z, x, prior))
    return remainder(z, terms)


def _slices(terms: list[Term]) -> list[slice]:
    """Each term's parameters in a joint fit of `terms` (stacked in that order)."""
    ends = np.cumsum([t.columns.shape[1] for t in terms], dtype=int)
    return [slice(int(end) - t.columns.shape[1], int(end)) for t, end in zip(terms, ends)]


def _split(terms: list[Term], theta: np.ndarray) -> list[tuple[Term, np.ndarray]]:
    """Each term with its slice of a joint fit of `terms` (stacked in that order)."""
    return [(t, theta[part]) for t, part in zip(terms, _slices(terms))]


def _take_fit(terms: list[Term], theta: np.ndarray) -> None:
    """Hand each term its slice of a joint fit of `terms`."""
    for t, part in _split(terms, theta):
        t.theta = part
    _centre_gauge(terms)


def remainder(z: np.ndarray, terms: list[Term]) -> np.ndarray:
    """The standardised residual the terms leave, as fitted."""
    return z - sum((t.columns @ t.theta for t in terms), np.zeros(len(z)))


def _delay_family(terms: list[Term]) -> list[Term]:
    """The delay terms, if they are every anchor's for the whole flight: then the same
    delay added to all of them changes no TDOA (their columns sum to zero)."""
    delays = [t for t in terms if t.candidate.effect == "anchor_delay"]
    if len(delays) < 2 or np.abs(sum(t.columns[:, 0] for t in delays)).max() > 1e-6:
        return []
    return delays


def _centre_gauge(terms: list[Term], attribute: str = "theta") -> None:
    """TDOA sees delays only relative to each other: they are reported relative to
    their robust centre (delay_centre)."""
    family = _delay_family(terms)
    if family:
        shift = delay_centre(np.array([getattr(t, attribute)[0] for t in family]))
        for t in family:
            setattr(t, attribute, getattr(t, attribute) - shift)


# Simplest first: a term's evidence is judged given all other terms but the richer
# ones of its own group, so the simpler explanation gets the signal it can explain and
# a richer one only what is left: an anchor displaced along the line of sight is a
# delay; a lever arm at a constant attitude is every anchor displaced the same way; a
# pattern over a narrow cone of viewing angles is partly a delay and a displacement.
# On a repeated path the velocity is a function of the position, so a time offset is
# too: the timing effects come before the position-dependent ones. In TDOA a delay of
# one anchor is the opposite delay of all the others, so the order holds across
# anchors. Effects of equal rank are judged given each other: of two
# look-alikes, backward elimination drops the one that adds less (a scale factor in
# hover reads as a bias unless the thrust varies enough to tell them apart).
# Vibration rectification is richer than an accelerometer bias: over steady shaking
# it is one, so it takes only what follows the vibration around the bias's mean.
ORDER = {"time_offset": ("tdoa", 0), "clock_drift": ("tdoa", 0),
         "anchor_delay": ("tdoa", 0), "lever_arm": ("tdoa", 0), "anchor_position": ("tdoa", 1),
         "antenna_pattern": ("tdoa", 2), "nlos": ("tdoa", 3),
         "imu_accel_bias": ("accel", 0), "imu_accel_scale": ("accel", 0), "imu_vibration_rectification": ("accel", 1),
         "imu_gyro_bias": ("gyro", 0), "imu_gyro_scale": ("gyro", 0)}


def _richer(term: Term, terms: list[Term]) -> list[Term]:
    group, rank = ORDER[term.candidate.effect]
    return [t for t in terms if ORDER[t.candidate.effect][0] == group and ORDER[t.candidate.effect][1] > rank]


def simpler_than(term: Term, terms: list[Term]) -> list[Term]:
    group, rank = ORDER[term.candidate.effect]
    return [t for t in terms if ORDER[t.candidate.effect][0] == group and ORDER[t.candidate.effect][1] < rank]


# Delays are measured relative to each other (TDOA does not see a delay common to all
# anchors): once one anchor's delay is supported, every anchor's is kept and reported,
# so the delays of two recordings of the same flight compare anchor by anchor.
FAMILIES = {"anchor_delay"}


class _Design:
    """All terms fitted jointly (Huber IRLS), then the weights frozen: the weighted
    normal equations give the fit of any subset of the terms in a small solve, so
    every term can be judged given all the others."""

    def __init__(self, z: np.ndarray, terms: list[Term]):
        self.z, self.terms = z, terms
        self.x, prior = stacked(terms)
        self.ridge = 1.0 / prior ** 2
        self.theta = irls(z, self.x, prior)
        self.slices = {id(t): np.arange(part.start, part.stop) for t, part in zip(terms, _slices(terms))}
        self.gram, self.moment = weighted_normal(z, self.x, self.theta)

    def _columns(self, terms: list[Term]) -> np.ndarray:
        return np.concatenate([self.slices[id(t)] for t in terms]) if terms else np.zeros(0, int)

    def _loss(self, cols: np.ndarray) -> float:
        if not len(cols):
            return float(huber_loss(self.z).sum())
        theta = np.linalg.solve(self.gram[np.ix_(cols, cols)] + np.diag(self.ridge[cols]), self.moment[cols])
        return float(huber_loss(self.z - self.x[:, cols] @ theta).sum())

    def gain(self, term: Term, leave_out: list[Term] = ()) -> float:
        """Robust loss removed by `term` on top of all terms but it and `leave_out`."""
        base = [t for t in self.terms if t is not term and all(t is not o for o in leave_out)]
        return self._loss(self._columns(base)) - self._loss(self._columns(base + [term]))


def rank_of(term: Term) -> int:
    return ORDER[term.candidate.effect][1]


def estimate_terms(z: np.ndarray, terms: list[Term], z_simplest: np.ndarray | None = None,
              nuisance: list[Term] = (), simplest_unnamed: list[Term] = ()) -> None:
    """Each named term's estimate given the simpler explanations: its value in the
    joint fit of the named terms of its rank or a simpler one (see select), and its
    standard error in that fit; the simplest (rank 0) on `z_simplest` if given. The
    `nuisance` terms (rank 0, not named) are fitted along and not reported; so are
    the `simplest_unnamed` ones (rank 0) for the richer terms, whose estimates then do
    not depend on which of the simplest effects a recording names (0425-traj5: a
    time offset and a clock drift named with a displaced anchor injected, and not on
    the untouched flight, moved the displacement's z by 9 cm)."""
    for rank in sorted({rank_of(t) for t in terms}):
        reported = [t for t in terms if rank_of(t) <= rank]
        nested = reported + list(nuisance)
        if rank:
            nested += [t for t in simplest_unnamed if all(t.key != n.key for n in nested)]
        x, prior = stacked(nested)
        z_rank = z if rank or z_simplest is None else z_simplest
        theta = irls(z_rank, x, prior)
        family = {id(t) for t in _delay_family(nested)}
        gauge = np.concatenate([(np.arange(t.columns.shape[1]) == 0) & (id(t) in family) for t in nested])
        cov = _about_centre(posterior_cov(z_rank, x, prior, theta, gauge), theta, gauge)
        for t, part in zip(reported, _slices(nested)):        # the nuisance terms come last
            if rank_of(t) == rank:
                m = t.param_map()
                t.estimate, t.std_err = theta[part], np.sqrt(np.diag(m @ cov[part, part] @ m.T))
    _centre_gauge(terms, "estimate")


def free_offset_terms(named: list[Term], pool: list[Term]) -> list[Term]:
    """A clock drift is judged and measured about a free time offset, named or not:
    the drift's growth over the flight is what tells it from an offset, and a
    flight's own offset named on one run and not on another would otherwise move the
    drift by that offset over the flight's mean time (0422-log03: a drift of 2000 ppm
    added to the flight's own came out as +335 ppm when its −85 ms offset went
    unnamed)."""
    effects = {t.candidate.effect for t in named}
    if "clock_drift" not in effects or "time_offset" in effects:
        return []
    return [Term(t.candidate, t.candidate.columns) for t in pool if t.candidate.effect == "time_offset"]


GAUGE_WEIGHT = 1e6             # pins the sum of a delay family: TDOA sees delays relative to each other


def _about_centre(cov: np.ndarray, theta: np.ndarray, gauge: np.ndarray) -> np.ndarray:
    """The covariance of the parameters with the `gauge` ones (a family of delays) taken
    relative to their reported centre (`delay_centre`), not to their mean, which
    `posterior_cov` pins: the two differ once a delay lies beyond the centre's spread,
    which then hardly moves with it."""
    family = np.flatnonzero(gauge)
    if not len(family):
        return cov
    to_reported = np.eye(len(theta))
    to_reported[np.ix_(family, family)] -= delay_centre_slope(theta[family])[None, :]
    return to_reported @ cov @ to_reported.T


def posterior_cov(z: np.ndarray, x: np.ndarray, prior: np.ndarray, theta: np.ndarray,
                  gauge: np.ndarray | None = None) -> np.ndarray:
    """Covariance of the parameters of a Huber fit with Gaussian priors, from its
    weighted normal equations (z is standardised: unit noise). Where the data do not
    separate a parameter from the others its variance approaches its prior's. The
    `gauge` parameters (a family of delays) are pinned by their sum: the common delay
    TDOA cannot see does not blur each one (`_about_centre` then takes them relative
    to their reported centre)."""
    normal = weighted_normal(z, x, theta)[0] + np.diag(1.0 / prior ** 2)
    if gauge is not None and gauge.any():
        normal += GAUGE_WEIGHT * np.outer(gauge, gauge).astype(float)
    return np.linalg.inv(normal)


def _name(z: np.ndarray, terms: list[Term], pool: list[Term], fixed: list[Term] = ()) -> list[Term]:
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
        design = _Design(z, terms)
        _take_fit(terms, design.theta)
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
    richer = {id(t) for t in _richer(term, terms)}
    rest = [t for t in terms if t is not term and id(t) not in richer]

    def gain_of(j: int) -> float:
        own = _axis(term, j)
        return _Design(z, [*rest, *_without_axes(term, [j]), own]).gain(own)

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


def _judge(z: np.ndarray, terms: list[Term], design: _Design, free_offset: list[Term] = ()) -> None:
    """Every term's evidence given the others but its richer look-alikes. A complete
    delay family is judged against a reference anchor, the median one (against all
    the others an anchor's delay adds nothing: they can all move together), and the
    reference against the next one. A clock drift is judged with `free_offset` too."""
    family = sorted(_delay_family(terms), key=lambda t: t.theta[0])
    judges = {id(t): design for t in terms}
    if family:
        middle = len(family) // 2
        reference, second = family[middle], family[middle - 1]
        without_reference = _Design(z, [t for t in terms if t is not reference])
        judges.update({id(t): without_reference for t in family if t is not reference})
        judges[id(reference)] = _Design(z, [t for t in terms if t is not second])
    if free_offset:
        with_offset = _Design(z, terms + list(free_offset))
        judges.update({id(t): with_offset for t in terms if t.candidate.effect == "clock_drift"})
    for t in terms:
        t.evidence = judges[id(t)].gain(t, _richer(t, terms))


def select(problem: Problem, channel: Channel, pool: list[Candidate]
           ) -> tuple[list[Term], Channel, list[nlos_mixture.NlosShapeFit]]:
    """The channel's effects, named and measured.

    Which terms are named is decided by backward elimination (_name). A named term's
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
    them (a lever arm moved by 9 cm) nor drop them (0422-log03's own lever arm and
    time offset, supported on the channel as recorded, went once shapes on four
    anchors took part of their signal); it may add one (0425-traj17's own offset
    less an injected one pays only once its shapes are out); named effects are
    tried confined in time; the named effects, fitted jointly, are the model that
    re-simulates the recording. Returns the terms, the channel they were fitted on
    and the NLOS found by shape."""
    z = z_before_shapes = channel.z
    folds = channel.folds()
    terms = fresh_terms(pool, channel.name)
    named = _name(z, terms, terms)
    shapes, simplest = [], []
    if channel.name == "tdoa":
        nlos = _nlos_terms(problem, channel, folds, terms)
        if nlos:
            terms += nlos
            named = _name(z, named + nlos, terms)
    refit(z, named)                 # the NLOS search refits every candidate
    if channel.name == "tdoa":
        taken = {t.candidate.fixed["anchor"] for t in named if t.candidate.effect == "nlos"}
        shapes = _nlos_shapes(problem, channel, remainder(z, named), taken)
        if shapes:
            residual = problem.recorded("tdoa") - problem.predict_channel("tdoa", [f.effect() for f in shapes])
            channel = replace(channel, residual=residual)
            z = channel.z
            simplest = [t for t in named if rank_of(t) == 0]
            named = _name(z, terms, terms, simplest)
            refit(z, named)
    positions = problem.tag_positions() if channel.name == "tdoa" else None
    if confine_in_time(channel, named, positions):
        named = _name(z, named, terms, simplest)      # leaves them fitted jointly
    unnamed = unnamed_simplest_terms(terms, named, channel.name)
    estimate_terms(z, named, z_before_shapes, free_offset_terms(named, terms), unnamed)
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


def _nlos_terms(problem: Problem, channel: Channel, folds: np.ndarray, kept: list[Term]) -> list[Term]:
    """NLOS regions, strongest first, on what the kept effects leave."""
    found = []
    while True:
        left = refit(channel.z, kept + found)
        taken = {t.key for t in kept + found}
        trials = [trial for k in problem.anchor_ids if f"nlos:{k}" not in taken
                  for trial in [_nlos_trial(problem, channel, left, folds, k)] if trial is not None]
        if not trials:
            return found
        gain, best = max(trials, key=lambda gt: gt[0] - gt[1].cost)
        if gain - best.cost < MIN_EVIDENCE:
            return found
        log.info("%s: + %s (held-out gain %.1f)", channel.name, best.key, gain)
        found.append(best)


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
        others = [t for t in kept if t is not term and t not in _richer(term, kept)]
        for alt in [Term(t.candidate, t.columns) for t in pool if t.key not in keys
                    and t.candidate.effect in LOOK_ALIKES.get(term.candidate.effect, ())
                    and t.candidate.fixed.get("anchor") == anchor]:
            gain = _Design(z, others + [alt]).gain(alt)
            if gain - alt.cost >= term.net_evidence - LOOK_ALIKE_MARGIN:
                term.look_alikes.append((alt.key, round(gain, 1)))


# Look-alikes of one shape, axis by axis: over a flight in which an axis reads about
# the same all along (the accelerometer's z in hover) an IMU scale on it is a bias;
# far from the zero of the recording's clock a drift is an offset that hardly grows.
# No rule that does not depend on the trajectory can say which of two a recording has.
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
        richer = {id(t) for t in _richer(term, named)}
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
    here, so that the two compare (rig.compare). 0422-log00 names a z scale of 0.89
    jointly with a z bias of 0.98; with a z scale of 1.03 injected it names a bias and
    the scale in its place, 1.020, which compares with the untouched flight's scale in
    its bias's place, not with its joint 0.89."""
    judged_on = z if z_simplest is None else z_simplest
    out = []
    for term in named:
        effect = AXIS_LOOK_ALIKES.get(term.candidate.effect)
        alike = next((t for t in pool if t.candidate.effect == effect), None)
        if alike is None or term.extra or any(t.key == alike.key and t.extra for t in named):
            continue
        out.append(_in_place(z, judged_on, term, alike, list(range(term.columns.shape[1])), named, pool))
    return out


def _without_axes(term: Term, axes: list[int]) -> list[Term]:
    """`term` without `axes` (none when nothing is left)."""
    keep = [j for j in range(term.columns.shape[1]) if j not in axes]
    return [Term(term.candidate, term.columns[:, keep])] if keep else []


def _axis(term: Term, j: int) -> Term:
    return Term(term.candidate, term.columns[:, [j]])


def _cannot_tell(z: np.ndarray, term: Term, alike: Term, j: int, rivals: list[Term]) -> bool:
    """Axis j of `term` is supported given the others, does not pay for itself given the
    same axis of `alike`, and that axis in its place explains nearly as much (within
    LOOK_ALIKE_MARGIN, as a look-alike)."""
    rest, own, other = [*rivals, *_without_axes(term, [j])], _axis(term, j), _axis(alike, j)
    alone = _Design(z, [*rest, own]).gain(own)
    if alone < MIN_EVIDENCE or _Design(z, [*rest, other, own]).gain(own) - own.cost >= MIN_EVIDENCE:
        return False
    return _Design(z, [*rest, other]).gain(other) >= alone - LOOK_ALIKE_MARGIN


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
    others = [kept for t in named for kept in (_without_axes(t, axes) if t is term or t.key == alike.key
                                               else [Term(t.candidate, t.columns, t.extra)])]
    stand_in = Term(alike.candidate, alike.columns[:, axes])
    richer = {id(t) for t in _richer(stand_in, others)}
    evidence = _Design(z_simplest, [t for t in others if id(t) not in richer] + [stand_in]).gain(stand_in)
    reported = [t for t in others if rank_of(t) <= rank_of(stand_in)] + [stand_in]
    estimate_terms(z, reported, z_simplest, free_offset_terms(reported, pool))
    z_with = refit(z, [*others, stand_in])

    def on_axes(values: np.ndarray, elsewhere: float) -> np.ndarray:
        full = np.full(alike.columns.shape[1], elsewhere)
        full[axes] = values
        return full

    fitted = Term(alike.candidate, alike.columns, theta=on_axes(stand_in.theta, 0.0), evidence=evidence,
                  estimate=on_axes(stand_in.estimate, 0.0), std_err=on_axes(stand_in.std_err, alike.candidate.prior))
    return Alternative(fitted, term, axes, z_with)


def confine_in_time(channel: Channel, kept: list[Term], positions: np.ndarray | None = None) -> bool:
    """An effect present in part of the flight only: try every run of whole time
    blocks; keep the best window when it explains clearly more than the whole flight
    and, given the tag's `positions` (TDOA), more than the same effect confined to the
    places the window visited, at all times (_visited): a bias of the tag's pose
    (an antenna's pattern, a reflection) shows in the window the tag flew through its
    region, and again whenever the path passes there.
    A delay of the family changes in the window on top of its whole-flight value
    (TDOA sees delays relative to each other: a delay cannot be zero outside the
    window, and taking it out of the family would hand its whole-flight part to
    every other effect); any other effect is absent outside the window."""
    if not kept:
        return False
    windows = []
    edges = np.quantile(channel.t, np.linspace(0, 1, TIME_BLOCKS + 1))
    family = {id(t) for t in _delay_family(kept)}
    for term in kept:
        if term.candidate.effect not in WINDOWABLE:
            continue
        others = [t for t in kept if t is not term]
        z = remainder(channel.z, others)
        base = term.columns if id(term) in family else term.columns[:, :0]
        full = huber_loss(z - term.columns @ irls(z, term.columns, term.prior)).sum()
        # a window must add half again what the whole flight explains: slowly varying
        # real errors always make some window fit a little better
        margin = max(MIN_EVIDENCE + 2 * PENALTY_PER_PARAMETER, 0.5 * (huber_loss(z).sum() - full))
        best = (full - margin, None, None, None)
        for i in range(TIME_BLOCKS):
            for j in range(i + 1, TIME_BLOCKS + 1):
                if j - i == TIME_BLOCKS:
                    continue
                inside = (channel.t >= edges[i]) & (channel.t < edges[j] if j < TIME_BLOCKS else True)
                loss, cols = _confined_fit(z, base, term, inside)
                if loss < best[0]:
                    best = (loss, [float(edges[i]), float(edges[j])], cols, inside)
        loss, during, cols, inside = best
        if during is None:
            continue
        if positions is not None:
            place, _ = _confined_fit(z, base, term, _visited(positions, inside))
            if place <= loss:
                log.debug("%s: window %s is a place (%.1f against %.1f)", term.key, during, place, loss)
                continue
        windows.append((term, cols, during))
    for term, columns, during in windows:     # each was judged given the others as fitted
        term.columns, term.extra["during"], term.window_cost = columns, during, True
    return bool(windows)


def _confined_fit(z: np.ndarray, base: np.ndarray, term: Term, rows: np.ndarray) -> tuple[float, np.ndarray]:
    """The robust loss left by `term` acting on `rows` only (on top of `base`, its
    whole-flight columns for a delay of the family), and the columns that do it."""
    cols = np.hstack([base, term.columns * rows[:, None]])
    return float(huber_loss(z - cols @ irls(z, cols, np.full(cols.shape[1], term.candidate.prior))).sum()), cols


SAME_PLACE_M = 0.3             # within this of where a window took the tag: the same place


def _visited(positions: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The rows whose tag position lies within SAME_PLACE_M of one the `inside` rows
    took it to."""
    distance = cKDTree(positions[inside]).query(positions, distance_upper_bound=SAME_PLACE_M)[0]
    return np.isfinite(distance)


# ----------------------------------------------------------------------------- NLOS

def _nlos_trial(problem: Problem, channel: Channel, z: np.ndarray, folds: np.ndarray,
                k: int) -> tuple[float, Term] | None:
    """Held-out gain of a positive excess on anchor k's ranges inside a region that is
    found on the training blocks only; the term carries the region found on all data."""
    sign = problem.anchor_sign(k)
    positions = problem.tag_positions()

    def column(region: fx.Region) -> np.ndarray:      # an excess of 1 m on anchor k's ranges inside
        return (region.contains(positions) * sign)[:, None] / channel.scale[:, None]
    gain = 0.0
    for fold in range(FOLDS):
        train, test = folds != fold, folds == fold
        region = find_region(positions[train], (sign * z)[train], sign[train] != 0)
        if region is None:
            continue
        col = column(region)
        theta = irls(z[train], col[train], np.array([NLOS_PRIOR_M]))
        if theta[0] <= 0:
            continue
        gain += huber_loss(z[test]).sum() - huber_loss(z[test] - col[test] @ theta).sum()
    region = find_region(positions, sign * z, sign != 0)
    if region is None:
        return None
    return gain, Term(nlos_candidate(k), column(region), {"region": region.to_json()})


def nlos_candidate(k: int) -> Candidate:
    """The mean excess on anchor k's ranges in a region, as the search by mean shift fits it."""
    return Candidate("nlos", "tdoa", "mean_excess_m", 1, {"anchor": k}, prior=NLOS_PRIOR_M)


def find_region(positions: np.ndarray, s: np.ndarray, involved: np.ndarray) -> fx.Region | None:
    """Where an anchor's ranges read long: the box of the region scan (at most
    NLOS_MAX_SHARE of the anchor's samples) whose mean of `s`, its standardised signed
    residual, is most significantly above zero, when NLOS_MIN_T standard errors above."""
    pos, s = positions[involved], np.clip(s[involved], -HUBER_C * 3, HUBER_C * 3)
    if len(s) < MIN_SAMPLES:
        return None
    scan = BoxScan(pos, NLOS_MIN_SHARE, NLOS_MAX_SHARE)
    tstat = scan.sums(s)[0] / np.sqrt(np.maximum(scan.n_in, 1))      # s has unit variance: mean * sqrt(n)
    return scan.best(np.where(tstat > NLOS_MIN_T, tstat, -np.inf))


def nlos_shape(excess: np.ndarray, outside: np.ndarray, mean_shift: float) -> tuple[float, float]:
    """Fraction and mean excess of an exponential NLOS mixture from its mean shift and
    the extra second moment of the signed residuals inside the region (robustly
    trimmed); falls back to 'every sample, by the mean shift' when unidentifiable."""
    limit = 6 * mad_scale(outside) if len(outside) else np.inf
    inside, outside = excess[np.abs(excess) < limit], outside[np.abs(outside) < limit]
    if mean_shift <= 0 or len(inside) < MIN_SAMPLES or len(outside) < MIN_SAMPLES:
        return 1.0, max(mean_shift, 0.0)
    extra = np.mean((inside - np.mean(inside)) ** 2) - np.var(outside)    # f m² (2 − f)
    mean_excess = max(mean_shift, (extra + mean_shift ** 2) / (2 * mean_shift))
    return float(min(1.0, mean_shift / mean_excess)), float(mean_excess)


NLOS_SHAPE_PARAMETERS = 6     # fraction, mean excess and the box's four sides


def _nlos_shapes(problem: Problem, channel: Channel, z: np.ndarray,
                 taken: set[int]) -> list[nlos_mixture.NlosShapeFit]:
    """NLOS found by the shape of each anchor's residuals (z: what the named effects
    leave), on anchors without an NLOS region already, airborne samples only; kept
    when the held-out gain pays for its parameters like any other effect's."""
    cost = MIN_EVIDENCE + PENALTY_PER_PARAMETER * NLOS_SHAPE_PARAMETERS
    positions, folds = problem.tag_positions(), channel.folds()
    found = []
    for k in problem.anchor_ids:
        sign = problem.anchor_sign(k)
        rows = (sign != 0) & (positions[:, 2] >= ON_GROUND_M)
        if k in taken or rows.sum() < MIN_SAMPLES:
            continue
        fit = nlos_mixture.fit_anchor(k, positions[rows], (sign * z)[rows], folds[rows], float(channel.scale[0]),
                                      min_gain=cost)
        if fit is not None and fit.evidence >= cost:
            log.info("%s: + nlos:%d by its shape (held-out gain %.1f)", channel.name, k, fit.evidence)
            found.append(fit)
    return found
