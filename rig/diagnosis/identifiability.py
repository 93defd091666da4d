"""What a recording's trajectory can tell apart (report.json's `identifiability`):
for each candidate effect of the diagnosis, the smallest size at which it shows in
the recording at all, and the smallest at which it shows beyond its look-alikes.
Sizes are as the effect's bound measures them (`Effect.size`: a length, a
pattern's peak-to-peak bias, an IMU's largest axis), so each compares with its bound.

An effect with parameter a (its change from neutral) moves the standardised channel
by M a, M being its design columns (d channel / d parameter over the noise). Fitted,
it removes about ½‖M a‖² of the robust loss (half a chi-square: on inliers the Huber
loss is the squared one), and the diagnosis names it when that pays for its
parameters and MIN_EVIDENCE besides (`bar`). Beyond its look-alikes, the simpler
explanations it must beat (a displacement a delay's, a pattern a delay's and a
displacement's), only the part of M a that their columns L cannot fit counts: R a,
with R = (I − P_L) M. Over all a of size |a|, ½‖R a‖² is at most ½ λ |a|², λ the
largest of aᵀRᵀRa over the a of size 1 (for a length, RᵀR's largest eigenvalue);
so no effect smaller than √(2 bar / λ) is named on its own signal beyond its
look-alikes, whatever its direction, and the a that reaches λ is the direction the
trajectory tells apart best; from √(2 bar / λ_min) on, every direction is told apart.

It is a bound for one effect with unit weights: the robust weights of outliers,
chance, and the other anchors' and effects' terms in the model only raise it. An
effect below it that the diagnosis reports anyway on a real flight was named on the
flight's own effect of the same kind (a comparison with a control recording then
sees what was added); concealed in a flight that has none, it is reported as its
look-alikes."""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import Callable

import numpy as np

# The unit of each fitted parameter; a scale's size is its change from 1.
PARAM_UNITS = {"seconds": "s", "ppm": "ppm", "meters": "m", "offset_m": "m", "coeffs_m": "m", "mean_shift_m": "m",
               "bias_mps2": "m/s²", "bias_rps": "rad/s", "scale": "", "gain": ""}
SINGULAR = 1e-12               # an eigenvalue this small against the largest of MᵀM: nothing is left
DIRECTIONS = 600               # directions sampled for a size that is not a length, before refining
REFINED = 4                    # the best of them refined (a norm's ball has several corners)

# A parameter change's size as its bound measures it (Effect.size); None: its length.
Measure = Callable[[np.ndarray], float] | None


@dataclass
class Identifiability:
    """How large one candidate effect must be for this trajectory to show it."""

    effect: str
    anchors: list[int]
    param: str
    look_alikes: list[str]              # the simpler (or as simple) explanations it must beat
    smallest_seen: float | None         # size at which it pays against the noise alone; None: not seen at any size
    smallest_told_apart: float | None   # size at which it pays beyond its look-alikes; None: never told apart
    every_direction: float | None       # size from which it does so in every direction (equal for one component)
    direction: list[float]              # of a, the one told apart best (unit vector)
    bound: float                        # the largest size it can physically have
    bar: float = field(repr=False)                          # what naming it must remove
    apart_gram: np.ndarray = field(repr=False, compare=False)  # RᵀR: the columns beyond the look-alikes'
    own_scale: float = field(repr=False)                    # the largest eigenvalue of MᵀM
    axis_bars: tuple[float, ...] = field(default=(), repr=False)  # on 1, 2, ... axes, if named axis by axis
    measure: Measure = field(default=None, repr=False, compare=False)

    @property
    def told_apart(self) -> bool:
        """Whether an effect of a physically possible size can be told from its look-alikes."""
        return self.smallest_told_apart is not None and self.smallest_told_apart <= self.bound

    def size(self, amount: list[float] | float) -> float:
        """An amount's size (its change from neutral), as its bound measures it."""
        return measured_size(np.atleast_1d(np.asarray(amount, float)), self.measure)

    def told_apart_along(self, amount: list[float] | float) -> float | None:
        """The size from which an effect of `amount`'s direction (its change from
        neutral) is told from the look-alikes: √(2 bar / uᵀRᵀRu), u the direction of
        size 1, the bar that of the axes it moves for an effect named axis by axis;
        None where the look-alikes fit it whole (or for no direction at all)."""
        u = np.atleast_1d(np.asarray(amount, float))
        size = self.size(u)
        if size == 0.0:
            return None
        bar = self.axis_bars[np.count_nonzero(u) - 1] if self.axis_bars else self.bar
        return _rounded(_size_at(bar, float((u / size) @ self.apart_gram @ (u / size)), self.own_scale))

    @property
    def unit(self) -> str:
        return PARAM_UNITS.get(self.param, "")

    def to_json(self) -> dict:
        out = {"effect": self.effect, "param": self.param, "unit": self.unit, "look_alikes": self.look_alikes,
               "smallest_seen": self.smallest_seen, "smallest_told_apart": self.smallest_told_apart,
               "told_apart_in_every_direction": self.every_direction, "direction": self.direction,
               "bound": self.bound, "told_apart": self.told_apart}
        if self.anchors:
            out["anchors"] = self.anchors
        return out


def smallest_sizes(gram: np.ndarray, bars: tuple[float, ...], scale: float,
                   measure: Measure = None) -> tuple[float | None, float | None, np.ndarray]:
    """For columns M with `gram` = MᵀM: the smallest size of a for which ½‖M a‖²
    reaches its bar in the direction that reaches it first, that direction (a unit
    vector), and the size at which it does in every direction (the last one to);
    None where the columns are nothing against `scale` (the largest eigenvalue of the
    effect's own MᵀM): the look-alikes fit all of it. One bar holds in every
    direction; with one a axis (`bars[k - 1]` for an a on k of the axes, an effect
    named axis by axis) the first direction is sought on each set of axes."""
    dims = len(gram)
    every_axis = tuple(range(dims))
    supports = [every_axis] if len(bars) == 1 else \
        [axes for k in range(1, dims + 1) for axes in combinations(range(dims), k)]
    smallest, best, every = None, np.eye(dims)[0], None
    for axes in supports:
        largest, least, direction = _extremes(gram[np.ix_(axes, axes)], _on_axes(measure, axes, dims))
        size = _size_at(bars[min(len(axes), len(bars)) - 1], largest, scale)
        if size is not None and (smallest is None or size < smallest):
            smallest, best = size, np.zeros(dims)
            best[list(axes)] = direction
        if axes == every_axis:
            every = _size_at(bars[-1], least, scale)
    best = best / np.linalg.norm(best)
    return smallest, every, best * np.sign(best[np.argmax(np.abs(best))])


def _on_axes(measure: Measure, axes: tuple[int, ...], dims: int) -> Measure:
    """`measure` of an amount on `axes` only (the others zero)."""
    if measure is None:
        return None

    def on_axes(amount: np.ndarray) -> float:
        full = np.zeros(dims)
        full[list(axes)] = amount
        return measure(full)
    return on_axes


def _extremes(gram: np.ndarray, measure: Measure) -> tuple[float, float, np.ndarray]:
    """The largest and the smallest aᵀ gram a over the a of size 1, and the a of the
    largest: eigenvalues for a length (or a scalar, whose every measure is one), else
    over directions sampled and then refined, the quadratic form's extremes on a
    norm's sphere lying where its ball has corners."""
    if measure is None or len(gram) == 1:
        values, vectors = np.linalg.eigh(gram)
        return float(values[-1]) / measured_size(vectors[:, -1], measure) ** 2, \
            float(values[0]) / measured_size(vectors[:, 0], measure) ** 2, vectors[:, -1]
    from scipy.optimize import minimize

    def shown(u: np.ndarray) -> float:
        size = measured_size(u, measure)
        return float(u @ gram @ u) / size ** 2 if size > 0 else 0.0

    starts = np.random.default_rng(0).normal(size=(DIRECTIONS, len(gram)))
    values = np.array([shown(u) for u in starts])
    extremes = []
    for sign, order in ((-1.0, np.argsort(-values)), (1.0, np.argsort(values))):
        runs = [minimize(lambda u: sign * shown(u), starts[i], method="Nelder-Mead",
                         options={"xatol": 1e-9, "fatol": 1e-12 * max(values.max(), 1e-300), "maxiter": 4000})
                for i in order[:REFINED]]
        best = min(runs, key=lambda run: run.fun)
        extremes.append((sign * float(best.fun), best.x))
    (largest, direction), (smallest, _) = extremes
    return largest, smallest, direction


def measured_size(amount: np.ndarray, measure: Measure) -> float:
    """An amount's size by `measure` (None: its length)."""
    return float(np.linalg.norm(amount)) if measure is None else float(measure(amount))


def _size_at(bar: float, shown: float, scale: float) -> float | None:
    """The size s at which ½ shown s² reaches `bar` (`shown`: ‖M u‖² along a
    direction u of size 1); None where that is nothing against `scale`."""
    return float(np.sqrt(2.0 * bar / shown)) if shown > SINGULAR * scale else None


def beyond(columns: np.ndarray, look_alikes: np.ndarray) -> np.ndarray:
    """The part of `columns` that a least-squares fit of the look-alikes' leaves."""
    if not look_alikes.shape[1]:
        return columns
    return columns - look_alikes @ np.linalg.lstsq(look_alikes, columns, rcond=None)[0]


def assess(effect: str, anchors: list[int], param: str, columns: np.ndarray, look_alikes: dict[str, np.ndarray],
           bar: float, bound: float, axis_bars: tuple[float, ...] = (), measure: Measure = None) -> Identifiability:
    """An effect with design `columns` (rows × parameter components, standardised)
    against its `look_alikes` (name: their columns), named at `bar`, or at
    `axis_bars[k - 1]` on k of its axes if it is named axis by axis: the smallest
    sizes are then over every set of axes at its bar, every direction at all axes'. Sizes by `measure` (None: the length)."""
    bars = tuple(axis_bars) or (bar,)
    gram = columns.T @ columns
    own = float(np.linalg.eigvalsh(gram)[-1])
    seen = smallest_sizes(gram, bars, own, measure)[0]
    left = beyond(columns, np.hstack([columns[:, :0], *look_alikes.values()]))
    apart_gram = left.T @ left
    apart, every, direction = smallest_sizes(apart_gram, bars, own, measure)
    return Identifiability(effect, anchors, param, list(look_alikes), _rounded(seen), _rounded(apart),
                           _rounded(every), [round(float(v), 4) for v in direction], bound, bar, apart_gram, own,
                           tuple(axis_bars), measure)


def _rounded(size: float | None) -> float | None:
    """Four significant figures: a bound, not a measurement (sizes span ppm to rad/s)."""
    return None if size is None else float(f"{size:.4g}")


def figures(size: float) -> str:
    """A size in words: three significant figures, without an exponent for thousands (ppm)."""
    return f"{size:.3g}" if abs(size) < 1000 else f"{size:.0f}"
