"""NLOS by the shape of the residuals: where an anchor's ranges pick up a positive,
exponential excess delay on some of the paths, its signed residuals inside that region
are a mixture of the noise seen elsewhere and that noise convolved with an exponential.

A mean shift cannot tell this apart from a displaced anchor or a delay when the region
holds half the flight (they take the shift); the skewed tail no bias effect makes is
what is left. The test, per anchor, on what the fitted bias effects leave:

1. the box of tag positions (a quantile grid of x and y) whose upper tail, above its
   own median, is heavier than outside it (a binomial scan over all boxes);
2. the noise outside the box, fitted as a robust base: a normal core, a positive
   exponential tail (the outliers every range has) and a wide normal;
3. inside, the base shifted (the bias effects' misfit) against the base shifted and
   mixed with its convolution with an exponential (fraction, mean excess);
4. evidence: the log-likelihood that mixture gains on held-out time blocks, with box,
   base and mixture found on the others (as the other effects' evidence).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import erfcx, expit, log_ndtr

from rig.diagnosis.region_scan import BoxScan
from rig.sim import effects as fx

log = logging.getLogger(__name__)

BIN = 0.05                 # residuals are binned this finely (in noise standard deviations) to fit fast
WIDE_FACTOR = 5.0          # the base's wide component, in core standard deviations
MAX_SHARE = 0.3            # largest share of the base's outlier or wide component
MIN_SHARE = 1e-4
MIN_EXCESS = 0.05          # smallest exponential mean fitted, in noise standard deviations
LOG_SIZE_LIMIT = 7.0       # a fitted size (spread, exponential mean) stays within e^±7 noise standard deviations
MAX_FRACTION = 0.98
MIN_BOX_SHARE = 0.05       # a box holds at least this share of the anchor's samples ...
MAX_BOX_SHARE = 0.9        # ... and leaves this share outside, to fit the base on
TAIL = 2.0                 # the scan counts residuals this far above their box's median
LEVELS = np.arange(-4.0, 10.01, 0.25)
MIN_SIDE_SAMPLES = 50      # samples inside the box, and outside it, that a fit needs
# A range error this large is a corrupt measurement, not an excess path in a room: left
# out of the shape fit, where a few at hundreds of noise deviations drag the base's
# spread up to cover them and hide every tail.
GROSS_ERROR_M = 5.0


@dataclass
class Binned:
    """Samples rounded to BIN: the likelihood sums over distinct values, not samples."""

    values: np.ndarray
    counts: np.ndarray

    @classmethod
    def of(cls, samples: np.ndarray) -> "Binned":
        values, counts = np.unique(np.round(samples / BIN), return_counts=True)
        return cls(values * BIN, counts.astype(float))

    @property
    def n(self) -> float:
        return float(self.counts.sum())


def log_emg(x: np.ndarray, mu: float, sigma: float, mean: float) -> np.ndarray:
    """Log density of a normal (mu, sigma) plus an exponential of `mean` (stable both
    where the exponential's tail dominates and where the normal's does)."""
    u = (x - mu) / sigma
    z = u - sigma / mean
    out = np.empty_like(u)
    low = z < 0
    out[low] = -0.5 * u[low] ** 2 + np.log(0.5 * erfcx(-z[low] / np.sqrt(2.0)))
    out[~low] = -u[~low] * sigma / mean + sigma ** 2 / (2 * mean ** 2) + log_ndtr(z[~low])
    return out - np.log(mean)


def log_normal(x: np.ndarray, mu: float, sigma: float) -> np.ndarray:
    return -0.5 * ((x - mu) / sigma) ** 2 - np.log(sigma * np.sqrt(2 * np.pi))


def _log_sum(parts: list[np.ndarray]) -> np.ndarray:
    """log Σ exp(part), elementwise: the mixture's log density from its components'.
    (A ufunc reduction: scipy's logsumexp costs 15 times as much on these small
    arrays, and the simplex searches evaluate it some ten thousand times a flight.)"""
    return np.logaddexp.reduce(parts, axis=0)


def _size(log_size: float) -> float:
    """A positive size from its logarithm, which the simplex search may push far out:
    bounded, so a stray trial point costs a poor likelihood, not an overflow."""
    return float(np.exp(np.clip(log_size, -LOG_SIZE_LIMIT, LOG_SIZE_LIMIT)))


def _share(p: float) -> float:
    return MIN_SHARE + (MAX_SHARE - MIN_SHARE) * float(expit(p))


@dataclass
class Base:
    """The noise of an anchor's signed residuals where it has line of sight."""

    mu: float
    sigma: float
    outlier_share: float
    outlier_mean: float
    wide_share: float

    def log_parts(self, x: np.ndarray, shift: float) -> list[np.ndarray]:
        mu = self.mu + shift
        return [np.log(1 - self.outlier_share - self.wide_share) + log_normal(x, mu, self.sigma),
                np.log(self.outlier_share) + log_emg(x, mu, self.sigma, self.outlier_mean),
                np.log(self.wide_share) + log_normal(x, mu, WIDE_FACTOR * self.sigma)]

    @classmethod
    def from_vector(cls, p: np.ndarray) -> "Base":
        return cls(float(p[0]), _size(p[1]), _share(p[2]), max(_size(p[3]), MIN_EXCESS), _share(p[4]))

    @classmethod
    def fit(cls, data: Binned) -> "Base":
        def cost(p):
            base = cls.from_vector(p)
            return -(data.counts * _log_sum(base.log_parts(data.values, 0.0))).sum()
        start = [_weighted_median(data), 0.0, -2.0, np.log(3.0), -3.0]
        return cls.from_vector(minimize(cost, start, method="Nelder-Mead",
                                        options={"maxiter": 1500, "xatol": 1e-3, "fatol": 1e-3}).x)


def _weighted_median(data: Binned) -> float:
    return float(data.values[np.searchsorted(np.cumsum(data.counts), 0.5 * data.n)])


@dataclass
class Shape:
    """The residuals inside the region: the base moved by `shift`, a `fraction` of them
    with an exponential excess of mean `mean_excess` (noise standard deviations)."""

    shift: float
    fraction: float = 0.0
    mean_excess: float = 1.0

    def log_likelihood(self, data: Binned, base: Base) -> float:
        parts = base.log_parts(data.values, self.shift)
        if self.fraction > 0:
            parts = [np.log(1 - self.fraction) + p for p in parts]
            parts.append(np.log(self.fraction) + log_emg(data.values, base.mu + self.shift, base.sigma,
                                                         self.mean_excess))
        return float((data.counts * _log_sum(parts)).sum())


def fit_shapes(data: Binned, base: Base) -> tuple[Shape, Shape]:
    """The best shifted base (no NLOS) and the best shifted NLOS mixture."""
    shifted = minimize(lambda p: -Shape(p[0]).log_likelihood(data, base), [0.0], method="Nelder-Mead").x[0]
    null = Shape(float(shifted))

    def mixture(p):
        return Shape(float(p[0]), MAX_FRACTION * float(expit(p[1])), max(_size(p[2]), MIN_EXCESS))
    best = min((minimize(lambda p: -mixture(p).log_likelihood(data, base), [shifted, -1.0, np.log(mean)],
                         method="Nelder-Mead", options={"maxiter": 600, "xatol": 1e-3, "fatol": 1e-3})
                for mean in (0.7, 2.5)), key=lambda r: r.fun)
    return null, mixture(best.x)


# ----------------------------------------------------------------------------- the box scan

def _crossing(cdf: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per row, the level at which the row's empirical CDF (over LEVELS) reaches target."""
    i = np.clip(np.argmax(cdf >= target[:, None], axis=1), 1, len(LEVELS) - 1)
    rows = np.arange(len(cdf))
    lo, hi = cdf[rows, i - 1], cdf[rows, i]
    w = np.clip((target - lo) / np.maximum(hi - lo, 1e-12), 0, 1)
    return LEVELS[i - 1] + w * (LEVELS[i] - LEVELS[i - 1])


def _upper_tail(counts: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Share above its median + TAIL, per row of CDF counts over LEVELS."""
    cdf = counts / np.maximum(n, 1)[:, None]
    above = _crossing(cdf, np.full(len(cdf), 0.5)) + TAIL
    j = np.clip(np.searchsorted(LEVELS, above), 1, len(LEVELS) - 1)
    rows = np.arange(len(cdf))
    w = (above - LEVELS[j - 1]) / (LEVELS[j] - LEVELS[j - 1])
    return 1.0 - np.clip(cdf[rows, j - 1] + w * (cdf[rows, j] - cdf[rows, j - 1]), 0, 1)


def _binomial_llr(p_in, n_in, p_out, n_out):
    p_in, p_out = np.clip(p_in, 1e-3, 1 - 1e-3), np.clip(p_out, 1e-3, 1 - 1e-3)
    pooled = (p_in * n_in + p_out * n_out) / (n_in + n_out)

    def kl(a, b):
        return a * np.log(a / b) + (1 - a) * np.log((1 - a) / (1 - b))
    return n_in * kl(p_in, pooled) + n_out * kl(p_out, pooled)


def scan_box(positions: np.ndarray, s: np.ndarray) -> fx.Region | None:
    """The box whose upper tail (above its own median, so a shift does not count) is
    most significantly heavier than outside it."""
    scan = BoxScan(positions, MIN_BOX_SHARE, MAX_BOX_SHARE)
    below_in, below_all = scan.sums((s[:, None] <= LEVELS[None, :]).astype(float))
    p_in = _upper_tail(below_in, scan.n_in)
    p_out = _upper_tail(below_all[None, :] - below_in, scan.n_all - scan.n_in)
    return scan.best(np.where(p_in > p_out, _binomial_llr(p_in, scan.n_in, p_out, scan.n_all - scan.n_in), -np.inf))


# ----------------------------------------------------------------------------- evidence

@dataclass
class NlosShapeFit:
    """An anchor's NLOS, found by its shape (parameters in the channel's unit)."""

    anchor: int
    region: fx.Region
    fraction: float
    mean_excess_m: float
    evidence: float                  # held-out log-likelihood gain
    nll_before: float                # mean negative log-likelihood per sample inside, base only
    nll_after: float                 # ... with the NLOS mixture

    def effect(self) -> fx.Effect:
        return fx.make_effect("nlos", {"anchor": self.anchor, "fraction": self.fraction,
                                       "mean_excess_m": self.mean_excess_m, "region": self.region.to_json()})


def _fit_in(positions: np.ndarray, s: np.ndarray):
    """Box, base, both shapes and the binned samples inside, on these samples (None:
    no box)."""
    region = scan_box(positions, s)
    fit = None if region is None else _fit_region(positions, s, region)
    return None if fit is None else (region, *fit)


def _fit_region(positions: np.ndarray, s: np.ndarray, region: fx.Region):
    """Base (outside the region), both shapes and the binned samples inside (None: too
    few samples on either side)."""
    inside = region.contains(positions)
    if inside.sum() < MIN_SIDE_SAMPLES or (~inside).sum() < MIN_SIDE_SAMPLES:
        return None
    base = Base.fit(Binned.of(s[~inside]))
    data = Binned.of(s[inside])
    return (base, *fit_shapes(data, base), data)


def _sound(s: np.ndarray, scale: float) -> np.ndarray:
    """The samples that are not corrupt measurements (GROSS_ERROR_M)."""
    return np.abs(s) * scale <= GROSS_ERROR_M


def shape_in_region(positions: np.ndarray, s: np.ndarray, scale: float, region: fx.Region
                    ) -> tuple[float, float] | None:
    """Fraction and mean excess (m) of the NLOS mixture of an anchor's standardised
    signed residuals `s` (at `positions`) inside a given region, the base fitted
    outside it: the search by shape's measure of the NLOS it finds, for a region found
    on another recording of the flight. None: too few samples on either side."""
    sound = _sound(s, scale)
    fit = _fit_region(positions[sound], s[sound], region)
    if fit is None:
        return None
    mixture = fit[2]
    return mixture.fraction, mixture.mean_excess * scale


def held_out_gain(positions: np.ndarray, s: np.ndarray, folds: np.ndarray) -> float:
    """Log-likelihood the NLOS mixture gains on each time block, found on the others."""
    gain = 0.0
    for fold in np.unique(folds):
        train, test = folds != fold, folds == fold
        fit = _fit_in(positions[train], s[train])
        if fit is None:
            continue
        region, base, null, mixture, _ = fit
        inside = Binned.of(s[test][region.contains(positions[test])])
        if inside.n:
            gain += mixture.log_likelihood(inside, base) - null.log_likelihood(inside, base)
    return gain


def fit_anchor(anchor: int, positions: np.ndarray, s: np.ndarray, folds: np.ndarray, scale: float,
               min_gain: float) -> NlosShapeFit | None:
    """The anchor's NLOS from its standardised signed residuals `s` (at `positions`),
    when the in-sample gain reaches min_gain (then judged on held-out blocks)."""
    sound = _sound(s, scale)
    positions, s, folds = positions[sound], s[sound], folds[sound]
    if len(s) < 2 * MIN_SIDE_SAMPLES:
        return None
    fit = _fit_in(positions, s)
    if fit is None:
        return None
    region, base, null, mixture, inside = fit
    null_ll, mixture_ll = null.log_likelihood(inside, base), mixture.log_likelihood(inside, base)
    if mixture_ll - null_ll < min_gain or mixture.fraction <= 0:
        return None
    evidence = held_out_gain(positions, s, folds)
    log.debug("nlos shape anchor %d: in-sample %.1f, held-out %.1f", anchor, mixture_ll - null_ll, evidence)
    # the standardised residuals carry the unit normal's constant per sample: the fit's
    # own unit is the channel's, so the log of the scale is added back
    per_sample = np.log(scale)
    return NlosShapeFit(anchor, region, mixture.fraction, mixture.mean_excess * scale, evidence,
                        -null_ll / inside.n + per_sample, -mixture_ll / inside.n + per_sample)
