"""Terms: the catalog's candidates as columns of one channel's robust regression — their
joint fit and its covariance, what is left after it, the delay family's gauge (TDOA
sees delays relative to each other), and the order in which a simpler explanation is
preferred (ORDER)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER, Candidate
from rig.diagnosis.robust import (
    HUBER_C,
    delay_centre,
    delay_centre_slope,
    huber_loss,
    irls,
    weighted_normal,
)
from rig.sim import effects as fx

log = logging.getLogger(__name__)

LOOK_ALIKE_MARGIN = 10.0       # candidates whose evidence came this close to the chosen one


@dataclass
class Term:
    """A candidate in the model: its columns (as used), unfitted settings and fit."""

    candidate: Candidate
    columns: np.ndarray
    extra: dict = field(default_factory=dict)       # during, region, ...
    theta: np.ndarray | None = None                  # in the model: the named terms fitted jointly
    estimate: np.ndarray | None = None               # as reported: given the simpler explanations
    std_err: np.ndarray | None = None                # of the estimate, counting a slow error (with_slow_error)
    # the same with the samples counted as independent: what the trajectory alone measures
    std_err_white: np.ndarray | None = None
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

    def beyond_bound(self, theta: np.ndarray) -> bool:
        """Whether the parameters of the fit `theta` lie outside the effect's physical range."""
        values = self.param_map() @ theta
        c = self.candidate
        return bool(fx.size_of(c.effect, c.param, values) > c.bound or (c.nonnegative and values.min() < 0))

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
    take_fit(terms, irls(z, x, prior))
    return remainder(z, terms)


def model_terms(z: np.ndarray, named: list[Term], floor: Term | None = None) -> tuple[list[Term], list[Term]]:
    """The named terms that re-simulate the recording, refitted jointly (with `floor`,
    the ranges' change with the tag on the floor, if any), and those left out for
    their sign. One fitted beyond its physical bounds stands for something the catalog
    does not model, and its linearised fit does not re-simulate (an anchor moved by
    metres), so it is left out, the furthest out first. Only once every kept term is
    within its bounds does a nonnegative one refitted below zero leave (the most
    negative first): its shape is then shared with the others, and a negative gain
    would re-simulate the bias inside out. Judged earlier, it would leave before the
    misfits that made it negative (docs/notebook/diagnosis-experiments.md, session 56)."""
    kept, wrong_sign = list(named), []
    while True:
        refit(z, kept + ([floor] if floor else []))
        if not kept:
            break
        excess = [fx.size_of(t.candidate.effect, t.candidate.param, t.theta) / t.candidate.bound for t in kept]
        below = [float(t.theta.min()) / t.candidate.bound if t.candidate.nonnegative else 0.0 for t in kept]
        if max(excess) > 1.0:
            kept.pop(int(np.argmax(excess)))
        elif min(below) < 0.0:
            wrong_sign.append(kept.pop(int(np.argmin(below))))
        else:
            break
    return kept, wrong_sign


def _slices(terms: list[Term]) -> list[slice]:
    """Each term's parameters in a joint fit of `terms` (stacked in that order)."""
    ends = np.cumsum([t.columns.shape[1] for t in terms], dtype=int)
    return [slice(int(end) - t.columns.shape[1], int(end)) for t, end in zip(terms, ends)]


def _split(terms: list[Term], theta: np.ndarray) -> list[tuple[Term, np.ndarray]]:
    """Each term with its slice of a joint fit of `terms` (stacked in that order)."""
    return [(t, theta[part]) for t, part in zip(terms, _slices(terms))]


def take_fit(terms: list[Term], theta: np.ndarray) -> None:
    """Hand each term its slice of a joint fit of `terms`."""
    for t, part in _split(terms, theta):
        t.theta = part
    _centre_gauge(terms)


def remainder(z: np.ndarray, terms: list[Term]) -> np.ndarray:
    """The standardised residual the terms leave, as fitted."""
    return z - sum((t.columns @ t.theta for t in terms), np.zeros(len(z)))


def delay_family(terms: list[Term]) -> list[Term]:
    """The delay terms, if they are every anchor's for the whole flight: then the same
    delay added to all of them changes no TDOA (their columns sum to zero)."""
    delays = [t for t in terms if t.candidate.effect == "anchor_delay"]
    if len(delays) < 2 or np.abs(sum(t.columns[:, 0] for t in delays)).max() > 1e-6:
        return []
    return delays


def _centre_gauge(terms: list[Term], attribute: str = "theta") -> None:
    """TDOA sees delays only relative to each other: they are reported relative to
    their robust centre (delay_centre)."""
    family = delay_family(terms)
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
# The link bias every link shares is judged and estimated given the simplest effects
# alone, after the others are named (rig.diagnosis.diagnose).
ORDER = {"time_offset": ("tdoa", 0), "clock_drift": ("tdoa", 0),
         "anchor_delay": ("tdoa", 0), "lever_arm": ("tdoa", 0), "link_bias": ("tdoa", 1),
         "anchor_position": ("tdoa", 1),
         "antenna_pattern": ("tdoa", 2), "nlos": ("tdoa", 3),
         "imu_accel_bias": ("accel", 0), "imu_accel_scale": ("accel", 0), "imu_vibration_rectification": ("accel", 1),
         "imu_gyro_bias": ("gyro", 0), "imu_gyro_scale": ("gyro", 0)}


def richer_than(term: Term, terms: list[Term]) -> list[Term]:
    group, rank = ORDER[term.candidate.effect]
    return [t for t in terms if ORDER[t.candidate.effect][0] == group and ORDER[t.candidate.effect][1] > rank]


def simpler_than(term: Term, terms: list[Term]) -> list[Term]:
    group, rank = ORDER[term.candidate.effect]
    return [t for t in terms if ORDER[t.candidate.effect][0] == group and ORDER[t.candidate.effect][1] < rank]


# Delays are measured relative to each other (TDOA does not see a delay common to all
# anchors): once one anchor's delay is supported, every anchor's is kept and reported,
# so the delays of two recordings of the same flight compare anchor by anchor.
FAMILIES = {"anchor_delay"}


class Design:
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
              nuisance: list[Term] = (), simplest_unnamed: list[Term] = (), times: np.ndarray | None = None) -> None:
    """Each named term's estimate given the simpler explanations: its value in the
    joint fit of the named terms of its rank or a simpler one (see select), and its
    standard error in that fit; the simplest (rank 0) on `z_simplest` if given. With
    the rows' `times` (a channel whose error varies slowly: TDOA), the standard error
    counts the error's correlation over time (`with_slow_error`); `std_err_white` is
    the one with independent samples either way. The
    `nuisance` terms (rank 0, not named) are fitted along and not reported; so are
    the `simplest_unnamed` ones (rank 0) for the richer terms, whose estimates then do
    not depend on which of the simplest effects a recording names (naming a time
    offset and a clock drift on one recording only would move a displacement's
    estimate between it and its control)."""
    for rank in sorted({rank_of(t) for t in terms}):
        reported = [t for t in terms if rank_of(t) <= rank]
        nested = reported + list(nuisance)
        if rank:
            nested += [t for t in simplest_unnamed if all(t.key != n.key for n in nested)]
        z_rank = z if rank or z_simplest is None else z_simplest
        _estimate_in(z_rank, nested, [t for t in reported if rank_of(t) == rank], times)
        if rank == 0:
            # a simplest effect fitted beyond its bound stands for something else: the
            # others are estimated without it (it keeps its own estimate)
            _centre_gauge(reported, "estimate")
            beyond = [t for t in reported if t.beyond_bound(t.estimate)]
            if beyond and len(beyond) < len(reported):
                _estimate_in(z_rank, [t for t in nested if t not in beyond],
                             [t for t in reported if t not in beyond], times)
    _centre_gauge(terms, "estimate")


def _estimate_in(z: np.ndarray, nested: list[Term], reported: list[Term], times: np.ndarray | None) -> None:
    """The `reported` terms' estimates and standard errors in the joint fit of `nested`."""
    x, prior = stacked(nested)
    theta = irls(z, x, prior)
    family = {id(t) for t in delay_family(nested)}
    gauge = np.concatenate([(np.arange(t.columns.shape[1]) == 0) & (id(t) in family) for t in nested])
    normal = posterior_normal(z, x, prior, theta, gauge)
    white = np.linalg.inv(normal)
    slow = white if times is None else with_slow_error(normal, z, x, theta, times)
    white, slow = (_about_centre(cov, theta, gauge) for cov in (white, slow))
    wanted = {id(t) for t in reported}
    for t, part in zip(nested, _slices(nested)):
        if id(t) in wanted:
            m = t.param_map()
            t.estimate = theta[part]
            t.std_err, t.std_err_white = (np.sqrt(np.diag(m @ cov[part, part] @ m.T)) for cov in (slow, white))


def free_offset_terms(named: list[Term], pool: list[Term]) -> list[Term]:
    """A clock drift is judged and measured about a free time offset, named or not:
    the drift's growth over the flight is what tells it from an offset, and a
    flight's own offset named on one run and not on another would otherwise move the
    drift by that offset over the flight's mean time."""
    effects = {t.candidate.effect for t in named}
    if "clock_drift" not in effects or "time_offset" in effects:
        return []
    return [Term(t.candidate, t.candidate.columns) for t in pool if t.candidate.effect == "time_offset"]


GAUGE_WEIGHT = 1e6             # pins the sum of a delay family: TDOA sees delays relative to each other


def _about_centre(cov: np.ndarray, theta: np.ndarray, gauge: np.ndarray) -> np.ndarray:
    """The covariance of the parameters with the `gauge` ones (a family of delays) taken
    relative to their reported centre (`delay_centre`), not to their mean, which
    `posterior_normal` pins: the two differ once a delay lies beyond the centre's spread,
    which then hardly moves with it."""
    family = np.flatnonzero(gauge)
    if not len(family):
        return cov
    to_reported = np.eye(len(theta))
    to_reported[np.ix_(family, family)] -= delay_centre_slope(theta[family])[None, :]
    return to_reported @ cov @ to_reported.T


def posterior_normal(z: np.ndarray, x: np.ndarray, prior: np.ndarray, theta: np.ndarray,
                     gauge: np.ndarray | None = None) -> np.ndarray:
    """The weighted normal equations of a Huber fit with Gaussian priors: the inverse
    of the parameters' covariance (z is standardised: unit noise). Where the data do
    not separate a parameter from the others its variance approaches its prior's.
    The `gauge` parameters (a family of delays) are pinned by their sum: the common
    delay TDOA cannot see does not blur each one (`_about_centre` then takes them
    relative to their reported centre)."""
    normal = weighted_normal(z, x, theta)[0] + np.diag(1.0 / prior ** 2)
    if gauge is not None and gauge.any():
        normal += GAUGE_WEIGHT * np.outer(gauge, gauge).astype(float)
    return normal


# A slow error's standard error is measured by deleting one stretch of the flight at a
# time: stretches of a tenth of a 25–52 s flight are 2.5–5 s long, several times as
# long as the TDOA error stays correlated (most of it varies over about 0.5 s).
JACKKNIFE_BLOCKS = 10


def with_slow_error(normal: np.ndarray, z: np.ndarray, x: np.ndarray, theta: np.ndarray,
                    times: np.ndarray) -> np.ndarray:
    """The posterior covariance (the inverse of `posterior_normal`'s `normal`), raised
    to the delete-a-block jackknife's where that is larger: the fit's spread when
    each of JACKKNIFE_BLOCKS stretches of the flight is left out in turn, which
    counts an error that is correlated within a stretch. Each refit is one Newton
    step from `theta` on the Huber loss (its curvature counts the rows within the
    threshold; the priors and the gauge, `normal` less the rows' weighted Gram,
    stay). Only what it adds is kept (its positive part), so where the error is
    not slow the covariance stays the posterior's."""
    cov = np.linalg.inv(normal)
    residual = z - x @ theta
    psi = np.clip(residual, -HUBER_C, HUBER_C)
    inside = (np.abs(residual) <= HUBER_C).astype(float)
    fixed = normal - weighted_normal(z, x, theta)[0]
    block = np.minimum(((times - times.min()) / max(np.ptp(times), 1e-9) * JACKKNIFE_BLOCKS).astype(int),
                       JACKKNIFE_BLOCKS - 1)
    curvature = fixed + (x * inside[:, None]).T @ x
    shifts = []
    for b in np.unique(block):
        rows = block == b
        left = curvature - (x[rows] * inside[rows, None]).T @ x[rows]
        shifts.append(-np.linalg.solve(left, x[rows].T @ psi[rows]))
    shifts = np.array(shifts) - np.mean(shifts, axis=0)
    k = len(shifts)
    values, vectors = np.linalg.eigh((k - 1) / k * shifts.T @ shifts - cov)
    return cov + (vectors * np.maximum(values, 0.0)) @ vectors.T


def without_axes(term: Term, axes: list[int]) -> list[Term]:
    """`term` without `axes` (none when nothing is left)."""
    keep = [j for j in range(term.columns.shape[1]) if j not in axes]
    return [Term(term.candidate, term.columns[:, keep])] if keep else []


def axis_term(term: Term, j: int) -> Term:
    return Term(term.candidate, term.columns[:, [j]])
