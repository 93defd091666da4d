"""The catalog's candidate effects as the diagnosis (rig.diagnosis.diagnose) fits them: one per
anchor where the effect has one, each with a vector parameter, a weak prior, a
physical bound, the evidence each parameter must pay for, and design columns, the
derivative of a channel's prediction with respect to the parameter taken
numerically through the effect's own simulator code (rig.sim.effects), so the diagnosis
and the simulator share one definition of every physical effect."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from rig.sim import effects as fx


class Problem(Protocol):
    """What a candidate needs of the channels it is fitted to (rig.diagnosis.channels.Problem,
    which uses this module to choose the gyroscope's blocks: the dependency points one way)."""

    tdoa_rows: np.ndarray
    imu_rows: dict[str, np.ndarray]
    anchor_ids: list[int]
    scales: dict[str, np.ndarray]

    def predict_channel(self, name: str, effects: list[fx.Effect]) -> np.ndarray: ...

    def recorded_under(self, name: str, effects: list[fx.Effect]) -> np.ndarray: ...

    def truth_noise_share(self, name: str) -> float: ...


PENALTY_PER_PARAMETER = 2.0    # evidence a parameter must pay for (AIC-like)
MIN_EVIDENCE = 8.0             # evidence, in half chi-square units, to name an effect


@dataclass
class Candidate:
    """An effect of the catalog whose vector parameter `param` is fitted."""

    effect: str
    channel: str
    param: str
    size: int
    fixed: dict = field(default_factory=dict)       # e.g. {"anchor": 3}
    neutral: float = 0.0                            # parameter value that means "no effect"
    step: float = 0.01                              # finite-difference step
    prior: float = 0.5                              # plausible size of the parameter (a weak ridge)
    bound: float | None = None                      # largest physical size (default: the catalog's, Effect.bounds)
    nonnegative: bool = False                       # a negative value is no physical size either (a gain)
    penalty: float = PENALTY_PER_PARAMETER          # evidence each parameter must pay for
    by_axis: bool = False                           # named on the axes that pay for themselves (gyro_scale_candidate)
    recorded_weight: np.ndarray | float = 0.0       # share of the regressor that is the recording (design_columns)
    columns: np.ndarray | None = None               # design columns (standardised), rows x size
    key: str = ""

    def __post_init__(self) -> None:
        self.key = self.effect + "".join(f":{v}" for v in self.fixed.values())
        if self.bound is None:                      # a fit beyond it is a misfit
            self.bound = fx.bound_of(self.effect, self.param)

    @property
    def anchors(self) -> list[int]:
        """The anchor it is on, as report.json lists it (none for a global effect)."""
        return [self.fixed["anchor"]] if "anchor" in self.fixed else []

    @property
    def naming_bar(self) -> float:
        """The robust loss its fit must remove to be named, unconfined in time (Term.cost
        and MIN_EVIDENCE)."""
        return self.bar_on(self.size)

    def bar_on(self, axes: int) -> float:
        """The robust loss its fit on `axes` of its components must remove to be named."""
        return self.penalty * axes + MIN_EVIDENCE

    @property
    def axis_bars(self) -> tuple[float, ...]:
        """What naming it on 1, 2, ... of its axes must remove; () if named whole."""
        return tuple(self.bar_on(k) for k in range(1, self.size + 1)) if self.by_axis else ()

    def value(self, theta: np.ndarray) -> np.ndarray:
        """The parameter for fitted column weights θ. A scale s regressed on w × the
        recorded reading + (1 − w) × the predicted one (w: `recorded_weight`) has
        recorded − predicted = (s − 1) / (w s + 1 − w) × that regressor, so
        s = 1 + θ / (1 − w θ) (w = 1: 1 / (1 − θ); w = 0: 1 + θ)."""
        theta = np.asarray(theta, float)
        return self.neutral + theta / (1.0 - self.recorded_weight * theta)

    def value_slope(self, theta: np.ndarray) -> np.ndarray:
        """d value / d θ: carries a standard error of θ into the parameter's unit."""
        theta = np.asarray(theta, float)
        return 1.0 / (1.0 - self.recorded_weight * theta) ** 2

    def make(self, theta: np.ndarray, extra: dict | None = None) -> fx.Effect:
        return self.effect_at(self.value(theta), extra)

    def effect_at(self, value: np.ndarray, extra: dict | None = None) -> fx.Effect:
        """The effect with its parameter at `value`."""
        params = {**self.fixed, self.param: float(value[0]) if self.size == 1 else value.tolist(), **(extra or {})}
        return fx.make_effect(self.effect, params)



def candidates(problem: Problem) -> list[Candidate]:
    """The catalog's mean effects, one per anchor where they have one."""
    out = []
    if len(problem.tdoa_rows):
        out += [Candidate("time_offset", "tdoa", "seconds", 1, step=0.005, prior=0.2),
                Candidate("clock_drift", "tdoa", "ppm", 1, step=200.0, prior=2000.0),
                Candidate("lever_arm", "tdoa", "offset_m", 3, prior=0.3)]
        for k in problem.anchor_ids:
            out += [Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": k}),
                    Candidate("anchor_position", "tdoa", "offset_m", 3, {"anchor": k}, prior=0.3,
                              penalty=2 * PENALTY_PER_PARAMETER),     # a delay wins a tie
                    Candidate("antenna_pattern", "tdoa", "coeffs_m", 3, {"anchor": k}, prior=0.3,
                              penalty=3 * PENALTY_PER_PARAMETER)]    # the least specific: pays most
    if len(problem.imu_rows["accel"]):
        out += [Candidate("imu_accel_bias", "accel", "bias_mps2", 3, prior=3.0),
                Candidate("imu_accel_scale", "accel", "scale", 3, neutral=1.0, step=1e-3, prior=0.2),
                Candidate("imu_vibration_rectification", "accel", "gain", 3, step=1.0, prior=5.0)]
    if len(problem.imu_rows["gyro"]):
        out += [Candidate("imu_gyro_bias", "gyro", "bias_rps", 3, step=1e-3, prior=0.2),
                gyro_scale_candidate(problem)]
    for c in out:
        c.columns = design_columns(problem, c)
    return out


def link_bias_candidate(problem: Problem) -> Candidate:
    """The link bias as calibrated on the shared flights, its gain fitted: one flight
    cannot tell the six coefficients apart (on a level circle the anchor's zonal term
    is a delay, the tag's sin(elevation) a vertical lever arm), but it can tell how
    strongly it shows their pattern. Bounded where a coefficient reaches its physical
    bound, and below by zero: antennas do not turn their pattern inside out
    (rig.diagnosis.terms.model_terms). Not in `candidates`: it is judged after them
    (rig.diagnosis.diagnose, docs/notebook/diagnosis-experiments.md)."""
    coeffs = fx.calibrated_link_bias()
    c = Candidate("link_bias", "tdoa", "gain", 1, {"coeffs_m": list(coeffs)}, step=0.1, prior=1.0,
                  bound=fx.LINK_BOUND_M / max(abs(v) for v in coeffs), nonnegative=True)
    c.key = "link_bias"
    c.columns = design_columns(problem, c)
    return c


def gyro_scale_candidate(problem: Problem) -> Candidate:
    """Named axis by axis (rig.diagnosis.selection): a flight turns about z and only
    wobbles about x and y, so its three axes carry very different signal, and a z scale
    would have to pay for all three. The other IMU vectors are named whole: their axes
    are measured alike (a bias's columns are constant), and an accelerometer scale
    named on fewer axes leaves the rest to its look-alike, the bias
    (docs/notebook/diagnosis-experiments.md)."""
    return Candidate("imu_gyro_scale", "gyro", "scale", 3, neutral=1.0, step=1e-3, prior=0.2,
                     recorded_weight=problem.truth_noise_share("gyro"), by_axis=True)


def design_columns(problem: Problem, c: Candidate, model: list[fx.Effect] = ()) -> np.ndarray:
    """d prediction / d parameter, through the effect's own simulator code, standardised.

    A gyroscope scale is regressed on the rate both the recording and the ground truth
    measure, each weighted by the other's share of the noise (`recorded_weight`:
    errors in variables; the difference of the two is then uncorrelated with their
    weighted mean). On the real flights the ground truth's side is far the noisier
    (the motion capture's attitude noise, differentiated, is a few per cent of their
    small rates even when averaged, and a regression on the predicted rate shrinks
    every fitted scale by as much: slopes 0.95–0.97), and the regressor is the
    recording; in a simulation with an exact ground truth it is the prediction, and an
    axis that does not rotate carries no scale (regressed on the recording, the
    gyroscope's noise would explain itself: a z scale of 2.36 on a level circle)."""
    columns = _derivative(c, lambda effects: problem.predict_channel(c.channel, [*model, *effects]))
    if np.any(c.recorded_weight):
        recorded = _derivative(c, lambda effects: problem.recorded_under(c.channel, effects))
        columns = c.recorded_weight * recorded + (1.0 - c.recorded_weight) * columns
    return np.nan_to_num(columns) / problem.scales[c.channel][:, None]


def _derivative(c: Candidate, channel_under) -> np.ndarray:
    """d channel / d parameter by a step of each component from neutral."""
    base = channel_under([])
    cols = []
    for j in range(c.size):
        value = np.full(c.size, c.neutral)
        value[j] += c.step
        cols.append((channel_under([c.effect_at(value)]) - base) / c.step)
    return np.stack(cols, axis=1)
