"""Effects confined in time or space: a window of the flight where a term pays for
being confined there, and NLOS regions — searched by the mean shift of an anchor's
ranges (held out) and by the shape of its residuals (rig.diagnosis.nlos_mixture)."""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from rig.diagnosis import nlos_mixture
from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER, Candidate
from rig.diagnosis.channels import FOLDS, TIME_BLOCKS, Channel, Problem
from rig.diagnosis.floor_error import ON_GROUND_M
from rig.diagnosis.region_scan import BoxScan
from rig.diagnosis.robust import (
    HUBER_C,
    MIN_SAMPLES,
    huber_loss,
    irls,
    mad_scale,
)
from rig.diagnosis.terms import Term, delay_family, refit, remainder
from rig.sim import effects as fx

log = logging.getLogger(__name__)


WINDOWABLE = {"anchor_delay", "antenna_pattern", "imu_accel_bias", "imu_gyro_bias", "imu_accel_scale",
              "imu_gyro_scale"}
NLOS_PRIOR_M = 0.3            # small: what all of an anchor's ranges share is its delay's
NLOS_MIN_SHARE = 0.05         # an NLOS region holds at least this share of an anchor's samples ...
NLOS_MAX_SHARE = 0.5          # ... and not most of them: that is a delay, not NLOS
NLOS_MIN_T = 3.0              # and its mean excess this many standard errors above zero


def nlos_terms(problem: Problem, channel: Channel, folds: np.ndarray, kept: list[Term]) -> list[Term]:
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
    family = {id(t) for t in delay_family(kept)}
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


def nlos_shape(excess: np.ndarray, outside: np.ndarray, mean_shift: float,
               largest_excess: float = np.inf) -> tuple[float, float]:
    """Fraction and mean excess of an exponential NLOS mixture from its mean shift and
    the extra second moment of the signed residuals inside the region (robustly
    trimmed); falls back to 'every sample, by the mean shift' when unidentifiable.
    The mean excess stays within `largest_excess` (the effect's physical bound), the
    mean shift kept: a small shift over a wide spread would read as a rare excess of
    metres."""
    limit = 6 * mad_scale(outside) if len(outside) else np.inf
    inside, outside = excess[np.abs(excess) < limit], outside[np.abs(outside) < limit]
    if mean_shift <= 0 or len(inside) < MIN_SAMPLES or len(outside) < MIN_SAMPLES:
        return 1.0, max(mean_shift, 0.0)
    extra = np.mean((inside - np.mean(inside)) ** 2) - np.var(outside)    # f m² (2 − f)
    mean_excess = max(mean_shift, min((extra + mean_shift ** 2) / (2 * mean_shift), largest_excess))
    return float(min(1.0, mean_shift / mean_excess)), float(mean_excess)


NLOS_SHAPE_PARAMETERS = 6     # fraction, mean excess and the box's four sides


def nlos_shapes(problem: Problem, channel: Channel, z: np.ndarray,
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
