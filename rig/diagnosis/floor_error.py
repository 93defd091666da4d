"""What the floor does to UWB ranges, measured on a diagnosis's TDOA residuals.

Two effects, both near the ground:

- with the tag sitting on the floor, each anchor's ranges read longer or shorter
  than in flight (the floor anchors' direct paths run along the floor; what arrives
  first has gone round): `on_ground_fits`, modelled as `on_ground_delay`;
- close to the floor (take-off and landing) the TDOA noise is larger: the floor
  multipath, a noise-level effect judged on each residual less the running median of
  its anchor pair's neighbours (`local_noise`, `floor_multipath`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rig.diagnosis.robust import MIN_SAMPLES, delay_centre, huber_loss, irls, mad_scale, robust_nll
from rig.sim.effects import on_ground_weight

if TYPE_CHECKING:
    from rig.diagnosis.channels import Problem

ON_GROUND_M = 0.2              # a tag this low sits on the floor or is taking off or landing: left out of the
#                                NLOS search and the floor multipath (transients); located on its own (locate)
MIN_ON_GROUND = 20             # samples of an anchor with the tag on the floor to say how it reads there
ON_GROUND_PRIOR = 100.0        # in noise deviations: as good as none, it only fixes the delays' common part
# where the ranges start to read as on the floor, (height below which all of the
# error, width over which it fades out above): steps, and fades. On the real flights
# the error is whole below 0.05-0.1 m (sitting), a fraction of it at 0.1-0.15 m and
# gone above 0.2 m; 24 of the 35 choose a fade (23 of them from 0.05 to 0.15 m)
ON_GROUND_SHAPES = ((0.05, 0.0), (0.1, 0.0), (0.15, 0.0), (0.2, 0.0), (0.05, 0.1), (0.1, 0.05))
FLOOR_HEIGHTS_M = (0.25, 0.4, 0.6, 0.8, 1.0)   # the floor multipath's heights tried
# its steps tried: one of those heights, or two of them, lower first
FLOOR_STEPS = [(h,) for h in FLOOR_HEIGHTS_M] + [(low, high) for low in FLOOR_HEIGHTS_M for high in FLOOR_HEIGHTS_M
                                                if low < high]
LOCAL_SAMPLES = 4              # neighbours on each side, in measurements of one anchor pair


@dataclass
class OnGroundFit:
    """How much longer each anchor's ranges read with the tag on the floor than in
    flight (on_ground_fits)."""

    height: float               # the tag below this, m: all of the change
    fade: float                 # and over this much above it, m: linearly less
    anchors: list[int]          # those seen on the floor often enough
    change: np.ndarray          # per anchor, in noise deviations, against their centre
    columns: np.ndarray         # per anchor, its sign in the rows on the floor, 0 elsewhere
    gain: float                 # robust loss the changes take off, in half chi-square units


def on_ground_fits(problem: Problem, z: np.ndarray,
                   shapes: tuple[tuple[float, float], ...] = ((ON_GROUND_M, 0.0),)) -> list[OnGroundFit]:
    """At each of `shapes` (height, fade: `on_ground_weight`), every anchor's delay and
    its change with the tag on the floor fitted jointly (Huber) on `z` (the
    standardised residual), against the delays alone (fitted once for all shapes);
    the changes against their centre as delays are (TDOA sees them only relative to
    each other). Anchors with fewer than MIN_ON_GROUND samples below the height are
    left out, and a shape where fewer than two are left."""
    signs = np.stack([problem.anchor_sign(k) for k in problem.anchor_ids], axis=1)
    delays_only = irls(z, signs, np.full(signs.shape[1], ON_GROUND_PRIOR))
    loss_delays_only = float(huber_loss(z - signs @ delays_only).sum())
    fits = []
    tag_height = problem.tag_positions()[:, 2]
    for height, fade in shapes:
        on_floor = (tag_height < height)[:, None]
        seen = np.sum((signs != 0) & on_floor, axis=0) >= MIN_ON_GROUND
        if seen.sum() < 2:
            continue
        floor_columns = signs[:, seen] * on_ground_weight(tag_height, height, fade)[:, None]
        x = np.concatenate([signs, floor_columns], axis=1)
        theta = irls(z, x, np.full(x.shape[1], ON_GROUND_PRIOR))
        change = theta[signs.shape[1]:]
        fits.append(OnGroundFit(height, fade, [int(k) for k in np.asarray(problem.anchor_ids)[seen]],
                                change - delay_centre(change), floor_columns,
                                loss_delays_only - float(huber_loss(z - x @ theta).sum())))
    return fits


def on_ground_delays(problem: Problem, z: np.ndarray) -> dict[str, float]:
    """The changes below ON_GROUND_M (on_ground_fits) by anchor id, in noise deviations of `z`."""
    fits = on_ground_fits(problem, z)
    return {str(k): float(c) for k, c in zip(fits[0].anchors, fits[0].change)} if fits else {}


def local_noise(problem: Problem, residual: np.ndarray) -> np.ndarray:
    """Each TDOA residual minus the median of its anchor pair's 2 x LOCAL_SAMPLES
    neighbouring measurements (itself left out), scaled so that white noise keeps its
    standard deviation (a median of n samples varies about pi/2n times as much). The
    neighbours are taken in the sample's own regime, the tag below ON_GROUND_M or
    above it: the ranges' step between the two (on_ground_delay) would otherwise enter
    the windows of the first and last airborne samples and read as noise near the
    floor (docs/notebook/diagnosis-experiments.md, session 88)."""
    d, rows = problem.rec.tdoa, problem.tdoa_rows
    airborne = problem.tag_positions()[:, 2] >= ON_GROUND_M
    pair = (d.id_a[rows].astype(np.int64) * 65536 + d.id_b[rows]) * 2 + airborne
    out = np.zeros(len(residual))
    k = LOCAL_SAMPLES
    for key in np.unique(pair):
        idx = np.flatnonzero(pair == key)
        idx = idx[np.argsort(d.t[rows][idx], kind="stable")]
        values = residual[idx]
        if len(values) <= 2 * k:
            out[idx] = values - np.median(values)
            continue
        windows = np.lib.stride_tricks.sliding_window_view(np.pad(values, k, mode="reflect"), 2 * k + 1)
        out[idx] = values - np.median(np.delete(windows, k, axis=1), axis=1)
    return out / np.sqrt(1.0 + np.pi / (4 * k))


def floor_multipath(noise: np.ndarray, heights: np.ndarray, bar: float) -> dict | None:
    """Is the TDOA noise (`noise`: local_noise, at the tag's `heights`) larger below
    some height? The robust log-likelihood a two-level noise model (below/above h)
    gains over one level, at the best h of FLOOR_HEIGHTS_M, on the samples above
    ON_GROUND_M; None when that gain is below `bar` (what the diagnosis asks of an
    effect with the two parameters, height and extra noise). A second step nested in
    it, more noise still below a lower height or less up to a higher one, is kept
    where its two parameters pay `bar` again: a flight's own floor noise can reach
    higher than what is added nearer the floor, and one step would average the two
    (docs/notebook/diagnosis-experiments.md). `std_m` is the lowest step's extra
    noise over the band above it; `upper_height_m` and `upper_std_m`, with two, the
    upper step's over the flight above it."""
    airborne = heights >= ON_GROUND_M
    r, heights = noise[airborne], heights[airborne]
    one = mad_scale(r)
    fits = [fit for fit in (_noise_levels(r, heights, cuts, one) for cuts in FLOOR_STEPS) if fit is not None]
    single = max((f for f in fits if len(f["cuts"]) == 1), key=lambda f: f["evidence"], default=None)
    if single is None or single["evidence"] < bar:
        return None
    double = max((f for f in fits if len(f["cuts"]) == 2), key=lambda f: f["evidence"], default=None)
    best = double if double is not None and double["evidence"] - single["evidence"] >= bar else single
    sigmas, cuts = best["sigmas"], best["cuts"]
    out = {"height_m": cuts[0], "std_m": float(np.sqrt(sigmas[0] ** 2 - sigmas[1] ** 2)),
           "evidence": best["evidence"], "sigma_one_level": one}
    if len(cuts) == 2:
        out |= {"upper_height_m": cuts[1], "upper_std_m": float(np.sqrt(sigmas[1] ** 2 - sigmas[2] ** 2))}
    low = np.zeros(len(airborne), bool)
    low[np.flatnonzero(airborne)[heights < cuts[-1]]] = True
    sigma_rows = np.full(len(airborne), sigmas[-1])
    sigma_rows[np.flatnonzero(airborne)] = sigmas[best["bands"]]
    return out | {"low": low, "sigma_rows": sigma_rows}


def _noise_levels(r: np.ndarray, heights: np.ndarray, cuts: tuple[float, ...], one: float) -> dict | None:
    """The noise's robust scale in each band between `cuts` and what that model gains
    over one level (`one`); None where a band has fewer than MIN_SAMPLES or the noise
    does not grow towards the floor from band to band."""
    bands = np.digitize(heights, cuts)          # 0: below cuts[0], ...
    counts = np.bincount(bands, minlength=len(cuts) + 1)
    if counts.min() < MIN_SAMPLES:
        return None
    sigmas = np.array([mad_scale(r[bands == b]) for b in range(len(cuts) + 1)])
    if np.any(np.diff(sigmas) >= 0):
        return None
    gain = float((robust_nll(r, one) - robust_nll(r, sigmas[bands])).sum())
    return {"cuts": cuts, "sigmas": sigmas, "bands": bands, "evidence": gain}
