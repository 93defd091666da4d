"""What a recording's trajectory can tell apart (report.json's `identifiability`):
for each candidate effect of the diagnosis, the smallest size at which it shows in
the recording at all, and the smallest at which it shows beyond its look-alikes.

An effect with parameter a (its change from neutral) moves the standardised channel
by M a, M being its design columns (d channel / d parameter over the noise). Fitted,
it removes about ½‖M a‖² of the robust loss (half a chi-square: on inliers the Huber
loss is the squared one), and the diagnosis names it when that pays for its
parameters and MIN_EVIDENCE besides (`bar`). Beyond its look-alikes, the simpler
explanations it must beat (a displacement a delay's, a pattern a delay's and a
displacement's), only the part of M a that their columns L cannot fit counts: R a,
with R = (I − P_L) M. Over all directions of a, ½‖R a‖² is at most ½ λ |a|², λ the
largest eigenvalue of RᵀR; so no effect smaller than √(2 bar / λ) is named on its
own signal beyond its look-alikes, whatever its direction, and its eigenvector is
the direction the trajectory tells apart best; from √(2 bar / λ_min) on, every
direction is told apart.

It is a bound for one effect with unit weights: the robust weights of outliers,
chance, and the other anchors' and effects' terms in the model only raise it. An
effect below it that the diagnosis reports anyway on a real flight was named on the
flight's own effect of the same kind (a comparison with a control recording then
sees what was added); concealed in a flight that has none, it is reported as its
look-alikes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# The unit of each fitted parameter; a scale's size is its change from 1.
PARAM_UNITS = {"seconds": "s", "ppm": "ppm", "meters": "m", "offset_m": "m", "coeffs_m": "m", "mean_shift_m": "m",
               "bias_mps2": "m/s²", "bias_rps": "rad/s", "scale": "", "gain": ""}
SINGULAR = 1e-12               # an eigenvalue this small against the largest of MᵀM: nothing is left


@dataclass
class Identifiability:
    """How large one candidate effect must be for this trajectory to show it."""

    effect: str
    anchors: list[int]
    param: str
    look_alikes: list[str]              # the simpler (or as simple) explanations it must beat
    smallest_seen: float | None         # |a| at which it pays against the noise alone; None: not seen at any size
    smallest_told_apart: float | None   # |a| at which it pays beyond its look-alikes; None: never told apart
    every_direction: float | None       # |a| from which it does so in every direction (equal for one component)
    direction: list[float]              # of a, the one told apart best (unit vector)
    bound: float                        # the largest size it can physically have
    bar: float = field(repr=False)                          # what naming it must remove
    apart_gram: np.ndarray = field(repr=False, compare=False)  # RᵀR: the columns beyond the look-alikes'
    own_scale: float = field(repr=False)                    # the largest eigenvalue of MᵀM
    axis_bars: tuple[float, ...] = field(default=(), repr=False)  # on 1, 2, ... axes, if named axis by axis

    @property
    def told_apart(self) -> bool:
        """Whether an effect of a physically possible size can be told from its look-alikes."""
        return self.smallest_told_apart is not None and self.smallest_told_apart <= self.bound

    def told_apart_along(self, amount: list[float] | float) -> float | None:
        """The size from which an effect of `amount`'s direction (its change from
        neutral) is told from the look-alikes: √(2 bar / uᵀRᵀRu), u the unit direction,
        the bar that of the axes it moves for an effect named axis by axis; None where
        the look-alikes fit it whole (or for no direction at all)."""
        u = np.atleast_1d(np.asarray(amount, float))
        norm = float(np.linalg.norm(u))
        if norm == 0.0:
            return None
        bar = self.axis_bars[np.count_nonzero(u) - 1] if self.axis_bars else self.bar
        return _rounded(_size_at(bar, float((u / norm) @ self.apart_gram @ (u / norm)), self.own_scale))

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


def smallest_sizes(gram: np.ndarray, bar: float, scale: float) -> tuple[float | None, float | None, np.ndarray]:
    """For columns M with `gram` = MᵀM: the smallest |a| for which ½‖M a‖² reaches
    `bar` in the direction that reaches it first, that direction, and the |a| at
    which it does in every direction (the last one to); None where the columns are
    nothing against `scale` (the largest eigenvalue of the effect's own MᵀM): the
    look-alikes fit all of it."""
    values, vectors = np.linalg.eigh(gram)
    best = vectors[:, -1] * np.sign(vectors[np.argmax(np.abs(vectors[:, -1])), -1])
    return _size_at(bar, values[-1], scale), _size_at(bar, values[0], scale), best


def _size_at(bar: float, shown: float, scale: float) -> float | None:
    """The |a| at which ½ shown |a|² reaches `bar` (`shown`: ‖M u‖² along a unit
    direction u); None where that is nothing against `scale`."""
    return float(np.sqrt(2.0 * bar / shown)) if shown > SINGULAR * scale else None


def beyond(columns: np.ndarray, look_alikes: np.ndarray) -> np.ndarray:
    """The part of `columns` that a least-squares fit of the look-alikes' leaves."""
    if not look_alikes.shape[1]:
        return columns
    return columns - look_alikes @ np.linalg.lstsq(look_alikes, columns, rcond=None)[0]


def assess(effect: str, anchors: list[int], param: str, columns: np.ndarray, look_alikes: dict[str, np.ndarray],
           bar: float, bound: float, axis_bars: tuple[float, ...] = ()) -> Identifiability:
    """An effect with design `columns` (rows × parameter components, standardised)
    against its `look_alikes` (name: their columns), named at `bar`, or at
    `axis_bars[k - 1]` on k of its axes if it is named axis by axis: the smallest
    sizes are then at one axis's bar (a bound: a direction off the axes pays more),
    every direction at all axes'."""
    first = axis_bars[0] if axis_bars else bar
    gram = columns.T @ columns
    own = float(np.linalg.eigvalsh(gram)[-1])
    seen = smallest_sizes(gram, first, own)[0]
    left = beyond(columns, np.hstack([columns[:, :0], *look_alikes.values()]))
    apart_gram = left.T @ left
    apart, _, direction = smallest_sizes(apart_gram, first, own)
    every = smallest_sizes(apart_gram, bar, own)[1]
    return Identifiability(effect, anchors, param, list(look_alikes), _rounded(seen), _rounded(apart),
                           _rounded(every), [round(float(v), 4) for v in direction], bound, bar, apart_gram, own,
                           tuple(axis_bars))


def _rounded(size: float | None) -> float | None:
    """Four significant figures: a bound, not a measurement (sizes span ppm to rad/s)."""
    return None if size is None else float(f"{size:.4g}")


def figures(size: float) -> str:
    """A size in words: three significant figures, without an exponent for thousands (ppm)."""
    return f"{size:.3g}" if abs(size) < 1000 else f"{size:.0f}"
