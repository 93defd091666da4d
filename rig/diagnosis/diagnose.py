"""Sim-vs-real diagnosis: where a simulation of a recording's own flight and the
recording disagree, which physical effect of the catalog (rig.sim.effects) explains it,
with fitted parameters, and how much closer the simulation gets with it.

Method, per channel (TDOA, accelerometer, gyroscope), each step's module in brackets:

1. Predict every recorded sample with the simulator's physics along the recording's
   ground truth (simulate.Predictor) and take the residual, recorded − predicted,
   standardised by a robust noise scale (MAD; per axis for the IMU) [rig.diagnosis.channels].
2. Each candidate effect (an effect of the catalog with its anchor, if any) gets
   design columns: the derivative of the prediction with respect to its parameters,
   taken numerically through the effect's own simulator code, so the diagnosis and
   the simulator share one definition of every physical effect [rig.diagnosis.candidates].
3. Naming: backward elimination. A term's `evidence` is the robust loss it removes
   given all remaining terms but its richer look-alikes (half a chi-square in the
   Gaussian limit, so it grows with the recording's length and compares runs of
   equal length); the weakest goes while below a bar (a penalty per parameter); a
   gyroscope scale loses its weakest axis before it goes whole.
   Delays are reported relative to their robust centre (`delay_centre`): TDOA does
   not see a delay common to all anchors [rig.diagnosis.selection, as steps 4 and 5].
4. Estimates (Huber IRLS with weak priors, rig.diagnosis.robust): a named term's estimate is its value in
   the joint fit of the named terms of its rank or a simpler one (ORDER: a delay
   before a displacement before a pattern before NLOS), so the simplest explanation
   takes the signal it can, and a richer effect named or not does not move the
   simpler ones (a comparison with a control recording needs that); a richer TDOA
   effect is fitted given every simplest candidate too, named or not, so neither
   does a simplest one named on one recording and not on another. Each estimate
   carries its standard error (the posterior's, in that fit). Every parametric TDOA
   candidate not named is estimated as it would be named too (unnamed_estimates), a
   flight's own effect below the bar that a comparison starts from. A parameter whose
   standard error is more than half its prior's is reported as not identified by
   this trajectory: the data hardly told it apart from the simpler explanations.
   An IMU bias and scale that the flight cannot tell apart on an axis (the
   accelerometer's z in hover), or a time offset and a clock drift, are both
   reported: the one named, and the other fitted in its place on that axis
   (`alternative_to`, not simulated).
5. Effects that may be confined in time are tried on windows of the flight; NLOS
   candidates get a region found on the training blocks only (held out), on what
   the parametric candidates leave; an NLOS the mean shift misses (a region so
   large that a displacement takes the shift) is found by the shape of the residuals
   (rig.diagnosis.nlos_mixture: a positive exponential tail, held out), its mean excess taken
   out and every candidate named again on what is left; the floor multipath is a
   noise-level effect judged on the local TDOA noise (what a running median leaves)
   below a height, and how the ranges read with the tag on the floor is fitted on
   what the model leaves (rig.diagnosis.floor_error).
6. The link bias every tag–anchor link shares (its shape calibrated on the shared
   flights, one gain: shared_link_bias) is judged after the catalog's effects are
   named, given the simplest of them, so it takes no signal from their selection.
   The named effects, fitted jointly, re-simulate the recording (each channel's
   mismatch before and after); each finding's `fit_before`/`fit_after` is the
   robust RMS mismatch of its affected samples under that model without and with it.
7. What the trajectory can tell apart (rig.diagnosis.identifiability): for every candidate,
   from its design columns, the size from which it shows at all and from which it
   is told from its look-alikes (`identifiability`).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from functools import partial

import numpy as np

from rig.data.recording import Recording
from rig.diagnosis import identifiability as ident
from rig.diagnosis import nlos_mixture
from rig.diagnosis.alternatives import Alternative, axis_alternatives, in_place_estimates
from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER, Candidate, candidates, link_bias_candidate
from rig.diagnosis.channels import AXES, Channel, Problem
from rig.diagnosis.confined import nlos_candidate, nlos_shape
from rig.diagnosis.findings import Diagnosis, Finding, Unnamed, rounded_floats
from rig.diagnosis.floor_error import ON_GROUND_PRIOR, ON_GROUND_SHAPES, floor_multipath, local_noise, on_ground_fits
from rig.diagnosis.lean import measure_lean
from rig.diagnosis.mismatch import locate
from rig.diagnosis.robust import delay_centre, huber_loss, irls, robust_nll, robust_rms
from rig.diagnosis.selection import LOOK_ALIKES, fresh_terms, select, unnamed_simplest_terms
from rig.diagnosis.terms import (
    ORDER,
    Design,
    Term,
    estimate_terms,
    free_offset_terms,
    model_terms,
    rank_of,
    refit,
    remainder,
    simpler_than,
    stacked,
)
from rig.sim import effects as fx

log = logging.getLogger(__name__)

IDENTIFIED_SD_SHARE = 0.5      # a parameter is identified when its white standard error is below this share of its prior
# A named IMU effect is located on an axis when zeroing that axis raises the robust
# loss by more than this (half a chi-square: about 2 standard errors). The effect has
# already paid for itself; this says which of its axes carry it (why 2:
# docs/notebook/diagnosis-experiments.md).
LOCATED_LOSS = 2.0


def unnamed_estimates(problem: Problem, channel: Channel, as_recorded: Channel, named: list[Term],
                      pool: list[Candidate]) -> list[Unnamed]:
    """The channel's parametric candidates (all but NLOS) that the recording does not
    name, each estimated as it would be named (see select): in the joint fit of the
    named effects of its rank or a simpler one and it; the simplest (timing, delays,
    lever arm; an IMU bias or scale) on the channel as recorded (a drift about a free
    offset), a richer one on `channel` (the NLOS found by shape out) with every
    simplest candidate fitted along. A real flight's own effect below the bar is
    still there, and an effect added on top of it is named at the sum (examples in
    docs/notebook/diagnosis-experiments.md). Compared with another recording of the flight that names
    it, this is what the flight had (rig.diagnosis.compare)."""
    fresh = fresh_terms(pool, channel.name)
    parametric = [t for t in named if t.candidate.effect != "nlos"]
    simplest_unnamed = unnamed_simplest_terms(fresh, parametric, channel.name)
    named_keys = {t.key for t in named}
    out = []
    for term in fresh:
        if term.key in named_keys or term.candidate.effect == "nlos":
            continue
        terms = [Term(t.candidate, t.columns, t.extra) for t in parametric if rank_of(t) <= rank_of(term)] + [term]
        estimate_terms(channel.z, terms, as_recorded.z, free_offset_terms(terms, fresh), simplest_unnamed,
                       channel.slow_error_times())
        out.append(_estimated(problem, channel, term))
    return out


def shared_link_bias(problem: Problem, channel: Channel, as_recorded: Channel, named: list[Term],
                     pool: list[Candidate]) -> tuple[Term, np.ndarray] | None:
    """The link bias every tag–anchor link shares (its shape calibrated on the shared
    flights, one gain), if the recording supports it: judged and estimated given the
    simplest effects named (timing, delays, lever arm), like a richer effect, but
    after the catalog's effects are named, so it takes no signal from their
    selection (ranked among them it cost concealed time offsets and antenna
    patterns: docs/notebook/diagnosis-experiments.md); the displacements and patterns
    beside it are each anchor's deviation from it. Returns the term and its residual."""
    candidate = link_bias_candidate(problem)
    term = Term(candidate, candidate.columns)
    simplest = [Term(t.candidate, t.columns, t.extra) for t in named if rank_of(t) == 0]
    fresh = fresh_terms(pool, "tdoa")
    judged = simplest + [term]
    term.evidence = Design(channel.z, judged).gain(term)
    if not term.supported:
        return None
    estimate_terms(channel.z, judged, as_recorded.z, free_offset_terms(judged, fresh),
                   unnamed_simplest_terms(fresh, simplest, "tdoa"), channel.slow_error_times())
    return term, refit(channel.z, judged)


def diagnose(rec: Recording, progress=None, link_bias: bool = True) -> Diagnosis:
    """The module's method on `rec`; `link_bias=False` leaves out step 6 (the catalog alone)."""
    problem = Problem(rec)
    pool = candidates(problem)
    before = problem.residual_before
    findings, model, names, unnamed, in_place, tdoa_left = [], [], list(before), [], [], None
    for name in progress(names) if progress else names:
        as_recorded = problem.channel(name)
        selected, channel, shapes = select(problem, as_recorded, pool)     # fitted jointly
        unnamed += unnamed_estimates(problem, channel, as_recorded, selected, pool)
        if name == "tdoa":
            tdoa_left = remainder(as_recorded.z, [t for t in selected if t.candidate.effect != "nlos"])
        for fit in shapes:
            findings.append(_shape_finding(problem, fit))
            if not findings[-1].beyond_bound:
                model.append(fit.effect())
        z_named, z_own = remainder(channel.z, selected), {}
        named_theta = {id(t): t.theta for t in selected}
        terms = list(selected)
        link = shared_link_bias(problem, channel, as_recorded, selected, pool) if name == "tdoa" and link_bias else None
        if link is not None:            # judged in a fit of its own, then re-simulated with the rest
            link_term, z_own[id(link_term)] = link
            named_theta[id(link_term)] = link_term.theta
            terms.append(link_term)
        in_model, wrong_sign = model_terms(channel.z, terms)
        floor = _on_ground_term(problem, remainder(channel.z, in_model)) if name == "tdoa" else None
        if floor is not None:        # the model's effects fitted with it: the floor's error is not theirs
            in_model, wrong_sign = model_terms(channel.z, terms, floor)
        z_model = remainder(channel.z, in_model + ([floor] if floor else []))
        if floor is not None:
            on_ground = _on_ground_effect(problem, floor)
            findings.append(_on_ground_finding(channel, floor, on_ground, z_model))
            model.append(on_ground)
        simulated, for_sign = {id(t) for t in in_model}, {id(t) for t in wrong_sign}
        for term in terms:
            if id(term) in simulated:
                model.append(_effect_of(problem, channel, term, term.theta))
                z_with, theta = z_model, term.theta
                peers = simpler_than(term, [t for t in terms if id(t) in simulated])
            else:
                z_with, theta = z_own.get(id(term), z_named), named_theta[id(term)]
                peers = simpler_than(term, terms)
            findings.append(_finding(problem, channel, term, _effect_of(problem, channel, term, term.estimate),
                                     z_with, theta, peers, id(term) in simulated, id(term) in for_sign))
        fresh = fresh_terms(pool, name)
        findings += [_alternative_finding(problem, channel, alt, selected)
                     for alt in axis_alternatives(channel.z, selected, fresh, as_recorded.z)]
        in_place += [_estimated(problem, channel, alt.term, _replaced(channel, alt))
                     for alt in in_place_estimates(channel.z, selected, fresh, as_recorded.z)]
    after = {name: problem.recorded(name) - pred for name, pred in problem.predict(model).items()}
    if "tdoa" in after:
        floor = _floor_finding(problem, after["tdoa"])
        if floor is not None:
            findings.append(floor)
            model.append(fx.make_effect("multipath_floor", floor.params))
    findings.sort(key=lambda f: -f.evidence)
    return Diagnosis(problem, findings, model, before, after, identifiability(pool), lever_arm_cross_talk(pool),
                     unnamed, in_place, tdoa_left, locate(problem, before),
                     measure_lean(rec, problem.predictor.trajectory))


def identifiability(pool: list[Candidate]) -> list[ident.Identifiability]:
    """For every candidate, how large it must be for the recording to show it, and to
    tell it from its look-alikes (rig.diagnosis.identifiability): those of LOOK_ALIKES on its
    anchor that are as simple or simpler (ORDER), the explanations it must beat to be
    named; a richer look-alike gives way to it."""
    out = []
    for c in pool:
        rank = ORDER[c.effect][1]
        alikes = {a.effect: a.columns for a in pool if a.effect in LOOK_ALIKES.get(c.effect, ())
                  and ORDER[a.effect][1] <= rank and a.fixed.get("anchor") == c.fixed.get("anchor")}
        out.append(ident.assess(c.effect, c.anchors, c.param, c.columns, alikes, c.naming_bar, c.bound,
                                c.axis_bars, bound_measure(c.effect, c.param)))
    return out


def bound_measure(effect: str, param: str) -> ident.Measure:
    """How `effect`'s bound measures a change of `param` (`Effect.size`); None where
    that is its length."""
    kind = fx.EFFECTS[effect]
    return None if param in kind.lengths else partial(kind.size, param)


def lever_arm_cross_talk(pool: list[Candidate]) -> dict[int, list[float]]:
    """Per anchor, how its delay as reported moves with the lever arm when the two are
    fitted together (both rank 0): d delay / d lever arm, in metres per metre, every
    other delay refitted. A lever arm moved by a signal that is not its own (part of a
    pattern on one anchor) moves every anchor's delay by this times its change, so a
    delay's change against a control is partly the lever arm's (`rig diagnose
    --control` shows that share). Linear and unweighted; the gauge, delays reported
    about their centre, taken as their mean (delay_centre_slope with every delay near
    it)."""
    delays = [c for c in pool if c.effect == "anchor_delay"]
    lever = next((c for c in pool if c.effect == "lever_arm"), None)
    if lever is None or len(delays) < 2:
        return {}
    x = np.hstack([c.columns for c in delays])
    ridge = np.diag([1.0 / c.prior ** 2 for c in delays])     # as irls: it fixes the gauge
    slope = -np.linalg.solve(x.T @ x + ridge, x.T @ lever.columns)
    slope -= slope.mean(axis=0)
    return {c.fixed["anchor"]: slope[i].tolist() for i, c in enumerate(delays)}


def nlos_identifiability(problem: Problem, pool: list[Candidate], anchor: int,
                         region: fx.Region) -> ident.Identifiability:
    """How large a mean excess (fraction × mean excess) on `anchor`'s ranges inside
    `region` must be to show at all, and to show beyond every parametric TDOA
    candidate, which the search by mean shift fits first (method, step 7). The search
    by shape sees a heavy tail besides, which this does not count."""
    channel = problem.channel("tdoa")
    column = region.contains(problem.tag_positions()) * problem.anchor_sign(anchor) / channel.scale
    parametric = np.hstack([c.columns for c in pool if c.channel == "tdoa"])
    nlos = nlos_candidate(anchor)
    return ident.assess("nlos", [anchor], "mean_shift_m", column[:, None],
                        {"every parametric TDOA candidate": parametric}, nlos.naming_bar, nlos.bound)


def _effect_of(problem: Problem, channel: Channel, term: Term, theta: np.ndarray) -> fx.Effect:
    """The effect with parameters `theta` (the term's model fit, or its estimate)."""
    c = term.candidate
    if term.on_top:
        return c.make(term.param_map() @ theta, {**term.extra, "outside_m": float(theta[0])})
    if c.effect != "nlos":
        return c.make(theta, term.extra)
    k, shift = c.fixed["anchor"], float(theta[0])
    sign, inside = problem.anchor_sign(k), term.columns[:, 0] != 0
    signed = sign * channel.residual          # before any effect
    fraction, mean_excess = nlos_shape(signed[inside], signed[(sign != 0) & ~inside], shift, c.bound)
    return fx.make_effect("nlos", {"anchor": k, "fraction": fraction, "mean_excess_m": mean_excess,
                                   "region": term.extra["region"]})


def _finding(problem: Problem, channel: Channel, term: Term, effect: fx.Effect, z_with: np.ndarray,
             theta: np.ndarray, peers: list[Term], simulated: bool, for_sign: bool = False) -> Finding:
    """The effect as estimated (given the simpler explanations); fit_before/fit_after:
    the affected rows' mismatch under the re-simulating model without and with this
    effect (the whole model re-simulated is in Diagnosis.channel_fits); for an effect
    beyond its physical bounds, which the model leaves out, under all named effects
    fitted jointly (`z_with` and `theta` are the fit it is judged in, with `peers`);
    `for_sign`: left out of the model for its sign only (terms.model_terms)."""
    rows = np.any(term.columns != 0, axis=1)
    scale = channel.scale[rows]
    z_without = z_with + term.columns @ theta
    std_err, independent, not_identified = _uncertainty(term)
    return Finding(effect.name, channel.name, term.candidate.anchors, rounded_floats(effect.params()),
                   round(float(term.evidence), 2),
                   robust_rms(z_without[rows] * scale, scale), robust_rms(z_with[rows] * scale, scale),
                   _where(problem, channel, term, effect, rows, z_with, theta, peers),
                   [{"candidate": key, "evidence": gain} for key, gain in term.look_alikes],
                   (not simulated and not for_sign) or term.beyond_bound(term.estimate),
                   std_err, not_identified, not_named_axes=[AXES[j] for j in sorted(term.dropped)],
                   not_simulated=for_sign, std_err_independent=independent)


def _alternative_finding(problem: Problem, channel: Channel, alt: Alternative, named: list[Term]) -> Finding:
    """A look-alike in place of some axes of a named effect: reported with the named
    one, not simulated with it (the model keeps the named effect)."""
    term = alt.term
    finding = _finding(problem, channel, term, _effect_of(problem, channel, term, term.estimate), alt.z_with,
                       term.theta, simpler_than(term, named), True)
    return replace(finding, alternative_to=_replaced(channel, alt))


def _replaced(channel: Channel, alt: Alternative) -> dict:
    """The named effect a look-alike stands in for, and on an IMU channel its axes."""
    instead = {"effect": alt.replaces.candidate.effect}
    if channel.name != "tdoa":
        instead["axes"] = [AXES[j] for j in alt.axes]
    return instead


def _estimated(problem: Problem, channel: Channel, term: Term, in_place_of: dict | None = None) -> Unnamed:
    """A fitted term's estimate and standard error, as a report lists an effect it
    does not report as a finding."""
    return Unnamed(term.candidate.effect, term.candidate.anchors,
                   rounded_floats(_effect_of(problem, channel, term, term.estimate).params()),
                   *_uncertainty(term)[:2], in_place_of=in_place_of)


def _shape_finding(problem: Problem, fit: nlos_mixture.NlosShapeFit) -> Finding:
    """An NLOS found by its shape: its fit is the likelihood of the anchor's residuals
    inside the region (a noise-level effect, like the floor's). Its mean excess is the
    mixture's own, not bounded by the fit: beyond the catalog's bound it is not
    explained, like any other fit, and not simulated."""
    inside = fit.region.contains(problem.tag_positions()) & (problem.anchor_sign(fit.anchor) != 0)
    effect = fit.effect()
    return Finding("nlos", "tdoa", [fit.anchor], rounded_floats(effect.params()), round(fit.evidence, 2),
                   fit.nll_before, fit.nll_after,
                   {"time": _span(problem.times("tdoa")[inside]), "region": fit.region.to_json(),
                    "anchors": [fit.anchor], "found_by": "shape (a positive exponential tail)",
                    "fit_unit": "mean negative log-likelihood per sample (a noise-level effect)"},
                   beyond_bound=bool(effect.beyond_bound()))


def _uncertainty(term: Term) -> tuple[dict, dict, list[str]]:
    """The estimate's standard errors, keyed like its parameter (an NLOS term fits the
    mean shift, fraction × mean excess), the same with the samples counted as
    independent (for a change between two recordings of one flight, which share its
    slow error), and the components that the trajectory does
    not tell apart from the simpler explanations, their values mostly the prior's:
    those whose standard error with independent samples is more than
    IDENTIFIED_SD_SHARE of the prior (a slow error makes a measurement less precise,
    not a trajectory less telling)."""
    c = term.candidate
    name = "mean_shift_m" if c.effect == "nlos" else c.param
    vague = np.flatnonzero(term.std_err_white > IDENTIFIED_SD_SHARE * c.prior)
    slope = c.value_slope(term.estimate)        # to the parameter's unit
    if c.size == 1:
        return ({name: rounded_floats(float(term.std_err[0] * slope[0]))},
                {name: rounded_floats(float(term.std_err_white[0] * slope[0]))}, [name] if len(vague) else [])
    return ({name: rounded_floats((term.std_err * slope).tolist())},
            {name: rounded_floats((term.std_err_white * slope).tolist())}, [f"{name}[{i}]" for i in vague])


def _floor_finding(problem: Problem, residual: np.ndarray) -> Finding | None:
    """Floor multipath on what is left of each measurement after the running median of
    its anchor pair's (local_noise): the extra noise stays, most slowly varying
    mismatch (a bias the model leaves, or one it adds where it extrapolates) goes, so
    the finding depends little on the rest of the model (measured in
    benchmarks/floor_order.py)."""
    noise = local_noise(problem, residual)
    heights = problem.tag_positions()[:, 2]
    floor = floor_multipath(noise, heights, MIN_EVIDENCE + 2 * PENALTY_PER_PARAMETER)
    if floor is None:
        return None
    low = floor["low"]
    before = float(np.mean(robust_nll(noise[low], floor["sigma_one_level"])))
    after = float(np.mean(robust_nll(noise[low], floor["sigma_rows"][low])))
    params = {key: round(floor[key], 4) if key.endswith("std_m") else floor[key]
              for key in ("height_m", "std_m", "upper_height_m", "upper_std_m") if key in floor}
    return Finding("multipath_floor", "tdoa", [], params, round(floor["evidence"], 2), before, after,
                   {"below_height_m": floor.get("upper_height_m", floor["height_m"]),     # the samples it affects
                    "time": _span(problem.times("tdoa")[low]),
                    "fit_unit": "mean negative log-likelihood per sample (a noise-level effect)"})


def _on_ground_term(problem: Problem, z: np.ndarray) -> Term | None:
    """The ranges' change with the tag on the floor, as a term of the TDOA model, where
    what the model leaves (`z`) supports it (on_ground_fits, at the shape of
    ON_GROUND_SHAPES that removes most): its evidence must pay for its parameters,
    one fewer than the anchors (only their differences show) and its shape. Not a
    candidate of the selection: the samples on the floor are what tells an injected
    displacement or pattern of a floor anchor apart (docs/notebook/diagnosis-experiments.md)."""
    fits = on_ground_fits(problem, z, ON_GROUND_SHAPES)
    if not fits:
        return None
    fit = max(fits, key=lambda f: f.gain)
    candidate = Candidate("on_ground_delay", "tdoa", "meters", len(fit.anchors), prior=ON_GROUND_PRIOR, bound=np.inf)
    term = Term(candidate, fit.columns, {"height_m": fit.height, "fade_m": fit.fade, "anchors": fit.anchors},
                evidence=fit.gain)
    return term if term.supported else None


def _on_ground_effect(problem: Problem, term: Term) -> fx.Effect:
    """The floor's term as fitted in the model, in metres against the anchors' centre."""
    change = term.theta * problem.scales["tdoa"][0]
    meters = {str(k): float(m) for k, m in zip(term.extra["anchors"], change - delay_centre(change))}
    return fx.make_effect("on_ground_delay", {"height_m": term.extra["height_m"], "fade_m": term.extra["fade_m"],
                                              "meters": meters})


def _on_ground_finding(channel: Channel, term: Term, effect: fx.Effect, z_model: np.ndarray) -> Finding:
    """The floor's term as fitted in the model (`effect`); fit_before/fit_after: the
    rows on the floor under the model without and with it."""
    rows = np.any(term.columns != 0, axis=1)
    scale = channel.scale[rows]
    without = z_model + term.columns @ term.theta
    anchors = term.extra["anchors"]
    return Finding("on_ground_delay", "tdoa", anchors, rounded_floats(effect.params()),
                   round(float(term.net_evidence), 2), robust_rms(without[rows] * scale, scale),
                   robust_rms(z_model[rows] * scale, scale),
                   {"below_height_m": term.extra["height_m"], "time": _span(channel.t[rows]), "anchors": anchors})


def _span(t: np.ndarray) -> list[float]:
    return [round(float(t.min()), 3), round(float(t.max()), 3)] if len(t) else []


def _where(problem: Problem, channel: Channel, term: Term, effect: fx.Effect, rows: np.ndarray,
           z_after: np.ndarray, theta: np.ndarray, peers: list[Term]) -> dict:
    where: dict = {"time": term.extra.get("during") or _span(channel.t[rows])}
    if channel.name == "tdoa":
        positions = problem.tag_positions()[rows]
        where["region"] = term.extra.get("region") or {"min": np.round(positions.min(axis=0), 3).tolist(),
                                                        "max": np.round(positions.max(axis=0), 3).tolist()}
        if "anchor" in term.candidate.fixed:
            where["anchors"] = [term.candidate.fixed["anchor"]]
        if hasattr(effect, "largest"):      # how much it changes the ranges, the anchor and viewing angles where most
            where.update(effect.largest(problem.predictor.tdoa([]), problem.predictor.world([]),
                                        problem.tdoa_rows[rows]))
        return where
    where["axes"] = [AXES[j] for j in _significant_axes(term, theta, z_after, peers)]
    return where


def _significant_axes(term: Term, theta: np.ndarray, z_after: np.ndarray, peers: list[Term]) -> list[int]:
    """Axes whose parameter matters: zeroing it (all else as fitted) raises the robust
    loss by more than LOCATED_LOSS (about 2 standard errors), with the simpler effects'
    (`peers`) refitted, so one that would make up for it does (simplest first, as in the
    selection): a rectification's gain on an axis that shakes evenly all flight is the
    bias's offset shared out between the two. Look-alikes of equal rank stay as fitted:
    each has its axes, as in the fit, where a bias and a scale are told apart."""
    best = huber_loss(z_after).sum()
    simpler = stacked(peers)
    out = []
    for j in range(term.columns.shape[1]):
        shifted = z_after + term.columns[:, j] * theta[j]
        if simpler is not None:
            shifted = shifted - simpler[0] @ irls(shifted, *simpler)
        if huber_loss(shifted).sum() - best > LOCATED_LOSS:
            out.append(j)
    return out
