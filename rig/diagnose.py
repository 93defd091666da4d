"""Sim-vs-real diagnosis: where a simulation of a recording's own flight and the
recording disagree, which physical effect of the catalog (rig.effects) explains it,
with fitted parameters, and how much closer the simulation gets with it.

Method, per channel (TDOA, accelerometer, gyroscope):

1. Predict every recorded sample with the simulator's physics along the recording's
   ground truth (simulate.Predictor) and take the residual, recorded − predicted,
   standardised by a robust noise scale (MAD; per axis for the IMU).
2. Each candidate effect (an effect of the catalog with its anchor, if any) gets
   design columns: the derivative of the prediction with respect to its parameters,
   taken numerically through the effect's own simulator code, so the diagnosis and
   the simulator share one definition of every physical effect.
3. Naming: backward elimination. A term's `evidence` is the robust loss it removes
   given all remaining terms but its richer look-alikes (half a chi-square in the
   Gaussian limit, so it grows with the recording's length and compares runs of
   equal length); the weakest goes while below a bar (a penalty per parameter).
   Delays are reported relative to their robust centre (`delay_centre`): TDOA does
   not see a delay common to all anchors.
4. Estimates (Huber IRLS with weak priors, rig.robust): a named term's estimate is its value in
   the joint fit of the named terms of its rank or a simpler one (ORDER: a delay
   before a displacement before a pattern before NLOS), so the simplest explanation
   takes the signal it can, and a richer effect named or not does not move the
   simpler ones (a comparison with a control recording needs that); a richer TDOA
   effect is fitted given every simplest candidate too, named or not, so neither
   does a simplest one named on one recording and not on another. Each estimate
   carries its standard error (the posterior's, in that fit). Every simplest TDOA
   candidate not named is estimated as it would be named too (unnamed_simplest), a
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
   (rig.nlos_mixture: a positive exponential tail, held out), its mean excess taken
   out and every candidate named again on what is left; the floor multipath is a
   noise-level effect judged on the local TDOA noise (what a running median leaves)
   below a height, and how the ranges read with the tag on the floor is fitted on
   what the model leaves (rig.floor_error).
6. The named effects, fitted jointly, re-simulate the recording (each channel's
   mismatch before and after); each finding's `fit_before`/`fit_after` is the
   robust RMS mismatch of its affected samples under that model without and with it.
7. What the trajectory can tell apart (rig.identifiability): for every candidate,
   from its design columns, the size from which it shows at all and from which it
   is told from its look-alikes (`identifiability`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from rig import effects as fx
from rig import identifiability as ident
from rig import imu_spectrum, nlos_mixture
from rig.floor_error import (ON_GROUND_M, ON_GROUND_PRIOR, ON_GROUND_SHAPES, floor_multipath, local_noise,
                             on_ground_delays, on_ground_fits)
from rig.recording import Recording, Vec3Series
from rig.region_scan import BoxScan
from rig.robust import (HUBER_C, MIN_SAMPLES, delay_centre, delay_centre_slope, huber_loss, huber_mean, irls,
                        mad_scale, robust_nll, robust_rms, weighted_normal)
from rig.simulate import Predictor
from rig.trajectory import ATTITUDE_WINDOW_S, window_mean

log = logging.getLogger(__name__)

FOLDS = 5                      # contiguous time blocks for cross-validation
PENALTY_PER_PARAMETER = 2.0    # evidence a parameter must pay for (AIC-like)
MIN_EVIDENCE = 8.0             # evidence, in half chi-square units, to name an effect
LOOK_ALIKE_MARGIN = 10.0       # candidates whose evidence came this close to the chosen one
IDENTIFIED_SD_SHARE = 0.5      # a parameter is identified when its standard error is below this share of its prior
TIME_BLOCKS = 10               # resolution of "only in part of the flight"
EDGE_S = 0.5                   # ignore samples this close to the ends of the ground truth
# IMU channels compare block means. The ground truth's rates are those of its attitude
# averaged over ATTITUDE_WINDOW_S (its noise, differentiated, would drown the small
# rates of these flights and dilute a fitted scale factor): the gyroscope is averaged
# over as long. Which block length measures a gyroscope scale best depends on the
# flight (Problem._choose_gyro_blocks): blocks as long as that window keep the yaw
# wobble above 1 Hz (19-68 % of the yaw rate's power on the real flights), the signal
# a scale is measured on where a flight hardly turns (standard error on z 0.009-0.026 on four real
# flights, against 0.014-0.031 in 0.5 s blocks), and neighbours share no noise there
# (the differentiated motion-capture noise is blue: residual rows of real flights
# correlate at -0.4 to 0.15 with their neighbour); a slow swing under noisy motion
# capture is measured better in longer blocks, which average more of that noise.
GYRO_BLOCKS_S = (0.2, 0.5)     # the gyroscope's block lengths tried
IMU_BLOCK_S = {"accel": 0.2, "gyro": GYRO_BLOCKS_S[0]}
IMU_SMOOTHING_S = {"accel": 0.0, "gyro": ATTITUDE_WINDOW_S}
IMU_MIN_BLOCK = 5              # samples a block needs
AXES = "xyz"
GROSS_Z = 50.0                 # a row this many noise deviations out is a corrupt one (see Problem)


def _block_index(t: np.ndarray, length: float) -> np.ndarray:
    """Which block of `length` seconds each sample time (from the start) falls in."""
    return np.floor(t / length).astype(int)


def _row_width(name: str) -> int:
    """Values per row of a channel's residual: IMU rows are block means, one per axis."""
    return 1 if name == "tdoa" else len(AXES)


def left_out_text(left_out: dict[str, int]) -> str:
    """What was left out as corrupt, per channel ("10 tdoa samples, 6 gyro samples"),
    in the unit of the channel's `samples`; empty when nothing was."""
    return ", ".join(f"{n} {name} samples" for name, n in left_out.items() if n)


@dataclass
class Channel:
    """One channel's rows: standardised residual, time of each row, noise scale."""

    name: str
    t: np.ndarray
    residual: np.ndarray       # recorded − predicted, in the channel's unit
    scale: np.ndarray          # robust noise standard deviation of each row

    @property
    def z(self) -> np.ndarray:
        return self.residual / self.scale

    def folds(self) -> np.ndarray:
        edges = np.quantile(self.t, np.linspace(0, 1, FOLDS + 1))
        return np.clip(np.searchsorted(edges, self.t, side="right") - 1, 0, FOLDS - 1)


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
    bound: float = 1.0                              # largest physical size: a fit beyond is a misfit
    penalty: float = PENALTY_PER_PARAMETER          # evidence each parameter must pay for
    recorded_weight: np.ndarray | float = 0.0       # share of the regressor that is the recording (design_columns)
    columns: np.ndarray | None = None               # design columns (standardised), rows x size
    key: str = ""

    def __post_init__(self) -> None:
        self.key = self.effect + "".join(f":{v}" for v in self.fixed.values())

    @property
    def anchors(self) -> list[int]:
        """The anchor it is on, as report.json lists it (none for a global effect)."""
        return [self.fixed["anchor"]] if "anchor" in self.fixed else []

    @property
    def naming_bar(self) -> float:
        """The robust loss its fit must remove to be named, unconfined in time (Term.cost
        and MIN_EVIDENCE)."""
        return self.penalty * self.size + MIN_EVIDENCE

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


# ----------------------------------------------------------------------------- channels

class Problem:
    """A recording, its predictor and the channels' rows."""

    def __init__(self, rec: Recording, predictor: Predictor | None = None):
        self.rec = rec
        self.predictor = predictor or Predictor(rec)
        t0, t1 = rec.truth.t[0] + EDGE_S, rec.truth.t[-1] - EDGE_S
        d = rec.tdoa
        known = {a.id for a in rec.anchors}
        self.tdoa_rows = np.flatnonzero(np.isfinite(d.distance_diff) & (d.t >= t0) & (d.t <= t1)
                                        & np.isin(d.id_a, list(known)) & np.isin(d.id_b, list(known)))
        self.imu_rows, self.imu_blocks = {}, {}
        for name, series in (("accel", rec.accel), ("gyro", rec.gyro)):
            rows = np.flatnonzero((series.t >= t0) & (series.t <= t1) & np.all(np.isfinite(series.xyz), axis=1))
            self._set_imu_rows(name, rows, _block_index(series.t[rows] - t0, IMU_BLOCK_S[name]))
        self.gyro_block_s = IMU_BLOCK_S["gyro"]
        if len(self.imu_rows["gyro"]):
            self._choose_gyro_blocks(t0)
        self.left_out = self._leave_out_gross_errors()
        self.anchor_ids = sorted(int(k) for k in np.unique(np.concatenate([d.id_a[self.tdoa_rows],
                                                                          d.id_b[self.tdoa_rows]]))
                                 if self._anchor_rows(k).sum() >= MIN_SAMPLES)
        self._tag_positions = self.predictor.tdoa([]).tag_position[self.tdoa_rows]

    def _choose_gyro_blocks(self, t0: float) -> None:
        """The gyroscope's blocks (GYRO_BLOCKS_S) under which its scale is best
        determined: the largest log-determinant of the scale's information, a property
        of the rates and of the noise, not of any effect's fitted size."""
        rows = self.imu_rows["gyro"]
        t = self.rec.gyro.t[rows] - t0
        information = {}
        for length in GYRO_BLOCKS_S:
            self._set_imu_rows("gyro", rows, _block_index(t, length))
            self._residuals()
            scale = gyro_scale_candidate(self)
            x = design_columns(self, scale)
            information[length] = np.linalg.slogdet(x.T @ x + np.eye(scale.size) / scale.prior ** 2)[1]
        self.gyro_block_s = max(information, key=information.get)      # the first of equals
        self._set_imu_rows("gyro", rows, _block_index(t, self.gyro_block_s))

    def _set_imu_rows(self, name: str, rows: np.ndarray, block: np.ndarray) -> None:
        """An IMU channel's samples and the block each falls in (blocks too short are left out)."""
        full = np.bincount(block)[block] >= IMU_MIN_BLOCK if len(block) else np.zeros(0, bool)
        self.imu_rows[name] = rows[full]
        self.imu_blocks[name] = np.unique(block[full], return_inverse=True)[1].ravel()

    def _residuals(self) -> None:
        """The untouched simulation's residual and noise scale, used throughout."""
        self.residual_before = {name: self.recorded(name) - pred for name, pred in self.predict([]).items()}
        self.scales = {name: self._scales(name, r) for name, r in self.residual_before.items()}

    def _leave_out_gross_errors(self) -> dict[str, int]:
        """Rows GROSS_Z noise deviations from their channel's median are corrupt
        measurements or glitches of the ground truth (a motion-capture attitude that
        flips for a moment reads as a yaw rate of 10 rad/s): no effect of the catalog
        makes them, and a fit confined to their few seconds would chase them. They are
        left out, counted in the report. A glitch of the attitude corrupts what both
        IMU channels are predicted from, so an IMU block found gross leaves out the
        other channel's blocks over the same time too. Returns the count left out per
        channel, in the unit of its `samples` (IMU: block means of each axis)."""
        self._residuals()
        gross = {name: self._gross(name, r) for name, r in self.residual_before.items()}
        spans = {name: self._block_spans(name) for name in gross if name != "tdoa"}
        glitches = np.concatenate([span[gross[name]] for name, span in spans.items()] or [np.zeros((0, 2))])
        for name, span in spans.items():
            gross[name] |= np.any((span[:, :1] <= glitches[:, 1]) & (span[:, 1:] >= glitches[:, 0]), axis=1)
            kept = ~gross[name][self.imu_blocks[name]]
            self._set_imu_rows(name, self.imu_rows[name][kept], self.imu_blocks[name][kept])
        if "tdoa" in gross:
            self.tdoa_rows = self.tdoa_rows[~gross["tdoa"]]
        left_out = {name: int(g.sum()) * _row_width(name) for name, g in gross.items()}
        if any(left_out.values()):
            log.warning("left out as gross errors (over %g noise deviations): %s", GROSS_Z, left_out_text(left_out))
            self._residuals()
        return left_out

    def _gross(self, name: str, residual: np.ndarray) -> np.ndarray:
        """Which rows (IMU: blocks, any axis) lie GROSS_Z noise deviations from the median."""
        width = _row_width(name)
        values = residual.reshape(-1, width)
        z = np.abs(values - np.median(values, axis=0)) / self.scales[name].reshape(-1, width)
        return np.any(z > GROSS_Z, axis=1)

    def _block_spans(self, name: str) -> np.ndarray:
        """First and last sample time of each of an IMU channel's blocks."""
        t, block = self._series(name).t[self.imu_rows[name]], self.imu_blocks[name]
        first, last = np.full(block.max() + 1, np.inf), np.full(block.max() + 1, -np.inf)
        np.minimum.at(first, block, t)
        np.maximum.at(last, block, t)
        return np.column_stack([first, last])

    def _series(self, name: str) -> Vec3Series:
        """An IMU channel's recorded series."""
        return self.rec.accel if name == "accel" else self.rec.gyro

    def _anchor_rows(self, k: int) -> np.ndarray:
        d = self.rec.tdoa
        return (d.id_a[self.tdoa_rows] == k) | (d.id_b[self.tdoa_rows] == k)

    def anchor_sign(self, k: int) -> np.ndarray:
        d = self.rec.tdoa
        return (d.id_b[self.tdoa_rows] == k).astype(float) - (d.id_a[self.tdoa_rows] == k).astype(float)

    def recorded(self, name: str) -> np.ndarray:
        if name == "tdoa":
            return self.rec.tdoa.distance_diff[self.tdoa_rows]
        return self.recorded_under(name, [])

    def recorded_under(self, name: str, effects: list[fx.Effect]) -> np.ndarray:
        """An IMU channel's recorded rows with `effects` applied to the readings."""
        accel, gyro = self.predictor.imu(effects, accel=self.rec.accel.xyz, gyro=self.rec.gyro.xyz)
        return self._rows_of(name, (accel if name == "accel" else gyro)[self.imu_rows[name]])

    def _rows_of(self, name: str, readings: np.ndarray) -> np.ndarray:
        """An IMU channel's rows from readings at its sample rows: smoothed like the
        ground truth's rates (IMU_SMOOTHING_S), then block means."""
        t, window = self._series(name).t[self.imu_rows[name]], IMU_SMOOTHING_S[name]
        return self._block_means(name, window_mean(t, readings, t, window) if window > 0 else readings)

    def truth_noise_share(self, name: str) -> np.ndarray:
        """Per axis, the share of the noise of an IMU channel's residual (recorded −
        predicted) that is the ground truth's: all but the recorded readings' own. The
        readings' own is their sample-to-sample noise (differences / √2, given random
        signs: white noise of that size) carried through the rows' smoothing and
        block means; a slow wobble the ground truth misses counts as the truth's."""
        readings = self._series(name).xyz[self.imu_rows[name]]
        steps = np.diff(readings, axis=0, prepend=readings[:1]) / np.sqrt(2.0)
        white = steps * np.random.default_rng(0).choice([-1.0, 1.0], size=steps.shape)
        rows = self._rows_of(name, white).reshape(-1, 3)
        own = np.array([mad_scale(rows[:, axis]) for axis in range(3)])
        total = self.scales[name][:3]
        return np.clip(1.0 - (own / total) ** 2, 0.0, 1.0)

    def _block_means(self, name: str, values: np.ndarray) -> np.ndarray:
        """IMU rows are block means (axis-interleaved): the vibration noise of a flying
        drone and the ground truth's differentiation noise average out, the slower
        physics stays."""
        block = self.imu_blocks[name]
        counts = np.bincount(block)
        values = np.atleast_2d(values.T).T
        return np.stack([np.bincount(block, weights=values[:, a]) / counts for a in range(values.shape[1])],
                        axis=1).ravel()

    def vibration(self) -> np.ndarray:
        """The recorded vibration level (`effects.vibration_level`) of each accelerometer
        row, block means like the rows."""
        return self._block_means("accel", self.predictor.accel_vibration[self.imu_rows["accel"]])

    def predict(self, effects: list[fx.Effect]) -> dict[str, np.ndarray]:
        """The prediction of every channel's rows under `effects`."""
        out = {}
        if len(self.tdoa_rows):
            out["tdoa"] = self.predictor.tdoa(effects).value[self.tdoa_rows]
        accel, gyro = self.predictor.imu(effects)
        for name, values in (("accel", accel), ("gyro", gyro)):
            if len(self.imu_rows[name]):
                out[name] = self._block_means(name, values[self.imu_rows[name]])
        return out

    def predict_channel(self, name: str, effects: list[fx.Effect]) -> np.ndarray:
        if name == "tdoa":
            return self.predictor.tdoa(effects).value[self.tdoa_rows]
        accel, gyro = self.predictor.imu(effects)
        return self._block_means(name, (accel if name == "accel" else gyro)[self.imu_rows[name]])

    def _scales(self, name: str, residual: np.ndarray) -> np.ndarray:
        """Noise scale of each row. IMU block means follow each other in time, so the
        spread of their differences (/√2) measures the noise without the slowly varying
        effects the diagnosis looks for (an effect larger than the noise would otherwise
        inflate the scale and hide itself). Consecutive TDOA rows are different anchor
        pairs, whose biases differ: there the plain robust spread is used."""
        if name == "tdoa":
            return np.full(len(residual), mad_scale(residual))
        per_axis = [mad_scale(np.diff(residual[axis::3])) / np.sqrt(2.0) for axis in range(3)]
        return np.tile(per_axis, len(residual) // 3)

    def times(self, name: str) -> np.ndarray:
        if name == "tdoa":
            return self.rec.tdoa.t[self.tdoa_rows]
        return np.repeat(self._block_means(name, self._series(name).t[self.imu_rows[name]]), 3)

    def tag_positions(self) -> np.ndarray:
        """The tag's true position at each TDOA row (untouched simulation)."""
        return self._tag_positions

    def channel(self, name: str) -> Channel:
        """The channel's rows against the untouched simulation."""
        return Channel(name, self.times(name), self.residual_before[name], self.scales[name])


# ----------------------------------------------------------------------------- candidates

def candidates(problem: Problem) -> list[Candidate]:
    """The catalog's mean effects, one per anchor where they have one."""
    out = []
    if len(problem.tdoa_rows):
        out += [Candidate("time_offset", "tdoa", "seconds", 1, step=0.005, prior=0.2, bound=0.5),
                Candidate("clock_drift", "tdoa", "ppm", 1, step=200.0, prior=2000.0, bound=20000.0),
                Candidate("lever_arm", "tdoa", "offset_m", 3, prior=0.3, bound=0.5)]
        for k in problem.anchor_ids:
            out += [Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": k}, bound=1.5),
                    Candidate("anchor_position", "tdoa", "offset_m", 3, {"anchor": k}, prior=0.3, bound=1.0,
                              penalty=2 * PENALTY_PER_PARAMETER),     # a delay wins a tie
                    Candidate("antenna_pattern", "tdoa", "coeffs_m", 3, {"anchor": k}, prior=0.3, bound=1.0,
                              penalty=3 * PENALTY_PER_PARAMETER)]    # the least specific: pays most
    if len(problem.imu_rows["accel"]):
        out += [Candidate("imu_accel_bias", "accel", "bias_mps2", 3, prior=3.0, bound=6.0),
                Candidate("imu_accel_scale", "accel", "scale", 3, neutral=1.0, step=1e-3, prior=0.2, bound=0.5),
                Candidate("imu_vibration_rectification", "accel", "gain", 3, step=1.0, prior=5.0, bound=20.0)]
    if len(problem.imu_rows["gyro"]):
        out += [Candidate("imu_gyro_bias", "gyro", "bias_rps", 3, step=1e-3, prior=0.2, bound=0.5),
                gyro_scale_candidate(problem)]
    for c in out:
        c.columns = design_columns(problem, c)
    return out


def gyro_scale_candidate(problem: Problem) -> Candidate:
    return Candidate("imu_gyro_scale", "gyro", "scale", 3, neutral=1.0, step=1e-3, prior=0.2, bound=0.5,
                     recorded_weight=problem.truth_noise_share("gyro"))


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


# ----------------------------------------------------------------------------- selection

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

    @property
    def key(self) -> str:
        return self.candidate.key

    @property
    def prior(self) -> np.ndarray:
        return np.full(self.columns.shape[1], self.candidate.prior)

    @property
    def cost(self) -> float:
        return self.candidate.penalty * self.columns.shape[1] + (2 * PENALTY_PER_PARAMETER if self.window_cost else 0)

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


def _stack(terms: list[Term]) -> tuple[np.ndarray, np.ndarray] | None:
    if not terms:
        return None
    return np.hstack([t.columns for t in terms]), np.concatenate([t.prior for t in terms])


def _refit(z: np.ndarray, terms: list[Term]) -> np.ndarray:
    """Fit all terms jointly; returns the standardised residual left."""
    if not terms:
        return z
    x, prior = _stack(terms)
    _take_fit(terms, irls(z, x, prior))
    return _left(z, terms)


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


def _left(z: np.ndarray, terms: list[Term]) -> np.ndarray:
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


def _simpler(term: Term, terms: list[Term]) -> list[Term]:
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
        self.x, prior = _stack(terms)
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


def _rank(term: Term) -> int:
    return ORDER[term.candidate.effect][1]


def _estimate(z: np.ndarray, terms: list[Term], z_simplest: np.ndarray | None = None,
              nuisance: list[Term] = (), simplest_unnamed: list[Term] = ()) -> None:
    """Each named term's estimate given the simpler explanations: its value in the
    joint fit of the named terms of its rank or a simpler one (see select), and its
    standard error in that fit; the simplest (rank 0) on `z_simplest` if given. The
    `nuisance` terms (rank 0, not named) are fitted along and not reported; so are
    the `simplest_unnamed` ones (rank 0) for the richer terms, whose estimates then do
    not depend on which of the simplest effects a recording names (0425-traj5: a
    time offset and a clock drift named with a displaced anchor injected, and not on
    the untouched flight, moved the displacement's z by 9 cm)."""
    for rank in sorted({_rank(t) for t in terms}):
        reported = [t for t in terms if _rank(t) <= rank]
        nested = reported + list(nuisance)
        if rank:
            nested += [t for t in simplest_unnamed if all(t.key != n.key for n in nested)]
        x, prior = _stack(nested)
        z_rank = z if rank or z_simplest is None else z_simplest
        theta = irls(z_rank, x, prior)
        family = {id(t) for t in _delay_family(nested)}
        gauge = np.concatenate([(np.arange(t.columns.shape[1]) == 0) & (id(t) in family) for t in nested])
        cov = _about_centre(posterior_cov(z_rank, x, prior, theta, gauge), theta, gauge)
        for t, part in zip(reported, _slices(nested)):        # the nuisance terms come last
            if _rank(t) == rank:
                m = t.param_map()
                t.estimate, t.std_err = theta[part], np.sqrt(np.diag(m @ cov[part, part] @ m.T))
    _centre_gauge(terms, "estimate")


def _free_offset(named: list[Term], pool: list[Term]) -> list[Term]:
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


@dataclass
class Unnamed:
    """A simplest TDOA effect the recording does not name, measured as a named one
    would be (report.json's `unnamed_estimates`)."""

    effect: str
    anchors: list[int]
    params: dict
    std_err: dict

    def to_json(self) -> dict:
        out = {"effect": self.effect, "params": self.params, "std_err": self.std_err}
        return out | ({"anchors": self.anchors} if self.anchors else {})


def unnamed_simplest(problem: Problem, channel: Channel, named: list[Term], pool: list[Candidate]) -> list[Unnamed]:
    """The simplest TDOA candidates (rank 0: timing, delays, lever arm) that the
    recording does not name, each estimated as it would be named: in the joint fit
    of the named simplest effects and it, on the channel as recorded (a drift about
    a free offset). A real flight's own effect below the bar is still there: on
    0425-traj5 a drift of −1126 ± 433 ppm, which an injected +2000 ppm brought to a
    named +720; compared with another recording of the flight that names it, this is
    what the flight had (rig.compare)."""
    simplest = [Term(t.candidate, t.columns, t.extra) for t in named if _rank(t) == 0]
    keys = {t.key for t in simplest}
    fresh = _fresh_terms(pool, "tdoa")
    out = []
    for term in (t for t in fresh if _rank(t) == 0 and t.key not in keys):
        _estimate(channel.z, [*simplest, term], channel.z, _free_offset([*simplest, term], fresh))
        out.append(Unnamed(term.candidate.effect, term.candidate.anchors,
                           rounded_floats(_effect_of(problem, channel, term, term.estimate).params()),
                           _uncertainty(term)[0]))
    return out


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
        _judge(z, terms, design, _free_offset(terms, pool))
        supported = {t.candidate.effect for t in terms if t.supported}
        removable = [t for t in terms if t.candidate.effect not in FAMILIES & supported and id(t) not in named_on]
        weakest = _weakest(removable)
        if weakest is None or weakest.supported:
            break
        log.debug("- %s (evidence %.1f given the others)", weakest.key, weakest.evidence)
        terms.remove(weakest)
    for t in fixed:
        t.evidence = named_on[id(t)]
    return terms


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
    terms = _fresh_terms(pool, channel.name)
    named = _name(z, terms, terms)
    shapes, simplest = [], []
    if channel.name == "tdoa":
        nlos = _nlos_terms(problem, channel, folds, terms)
        if nlos:
            terms += nlos
            named = _name(z, named + nlos, terms)
    _refit(z, named)                 # the NLOS search refits every candidate
    if channel.name == "tdoa":
        taken = {t.candidate.fixed["anchor"] for t in named if t.candidate.effect == "nlos"}
        shapes = _nlos_shapes(problem, channel, _left(z, named), taken)
        if shapes:
            residual = problem.recorded("tdoa") - problem.predict_channel("tdoa", [f.effect() for f in shapes])
            channel = replace(channel, residual=residual)
            z = channel.z
            simplest = [t for t in named if _rank(t) == 0]
            named = _name(z, terms, terms, simplest)
            _refit(z, named)
    positions = problem.tag_positions() if channel.name == "tdoa" else None
    if _confine_in_time(channel, named, positions):
        named = _name(z, named, terms, simplest)      # leaves them fitted jointly
    named_keys = {t.key for t in named}
    unnamed = [Term(t.candidate, t.candidate.columns) for t in terms
               if _rank(t) == 0 and t.key not in named_keys and channel.name == "tdoa"]
    _estimate(z, named, z_before_shapes, _free_offset(named, terms), unnamed)
    _note_look_alikes(z, named, terms)
    return named, channel, shapes


def _fresh_terms(pool: list[Candidate], channel: str) -> list[Term]:
    """The channel's candidates as unfitted terms, with their catalog columns."""
    return [Term(c, c.columns) for c in pool if c.channel == channel]


def _nlos_terms(problem: Problem, channel: Channel, folds: np.ndarray, kept: list[Term]) -> list[Term]:
    """NLOS regions, strongest first, on what the kept effects leave."""
    found = []
    while True:
        left = _refit(channel.z, kept + found)
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
    """`alike` on `axes` only, fitted with the named terms, `term` without those axes:
    its evidence given the others but its richer look-alikes and its estimate given
    the simpler ones as a named term's (_estimate: a drift about a free offset, so it
    compares with a drift named on a control), both on `z_simplest`, and what the
    whole model leaves with it on `z`. Its other axes are neutral and not identified
    (their standard error is the prior's): the flight supported the look-alike on
    none of them."""
    others = [kept for t in named
              for kept in (_without_axes(term, axes) if t is term else [Term(t.candidate, t.columns, t.extra)])]
    stand_in = Term(alike.candidate, alike.columns[:, axes])
    richer = {id(t) for t in _richer(stand_in, others)}
    evidence = _Design(z_simplest, [t for t in others if id(t) not in richer] + [stand_in]).gain(stand_in)
    reported = [t for t in others if _rank(t) <= _rank(stand_in)] + [stand_in]
    _estimate(z, reported, z_simplest, _free_offset(reported, pool))
    z_with = _refit(z, [*others, stand_in])

    def on_axes(values: np.ndarray, elsewhere: float) -> np.ndarray:
        full = np.full(alike.columns.shape[1], elsewhere)
        full[axes] = values
        return full

    fitted = Term(alike.candidate, alike.columns, theta=on_axes(stand_in.theta, 0.0), evidence=evidence,
                  estimate=on_axes(stand_in.estimate, 0.0), std_err=on_axes(stand_in.std_err, alike.candidate.prior))
    return Alternative(fitted, term, axes, z_with)


def _confine_in_time(channel: Channel, kept: list[Term], positions: np.ndarray | None = None) -> bool:
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
        z = _left(channel.z, others)
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
    return gain, Term(_nlos_candidate(k), column(region), {"region": region.to_json()})


def _nlos_candidate(k: int) -> Candidate:
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


# ----------------------------------------------------------------------------- the diagnosis

@dataclass
class Finding:
    """One effect the recording supports, as reported (report.json's contract)."""

    effect: str
    channel: str
    anchors: list[int]
    params: dict
    evidence: float
    fit_before: float
    fit_after: float
    where: dict
    look_alikes: list = field(default_factory=list)
    beyond_bound: bool = False      # larger than the effect can physically be: stands for something else, not simulated
    std_err: dict | None = None     # standard errors of the fitted parameter (None: not a fitted term)
    not_identified: list = field(default_factory=list)   # its components this trajectory does not identify
    alternative_to: dict | None = None   # {"effect", "axes"}: in place of those axes of that finding, as good

    def to_json(self) -> dict:
        out = {"effect": self.effect, "channel": self.channel, "params": self.params, "evidence": self.evidence,
               "fit_before": self.fit_before, "fit_after": self.fit_after, "where": self.where}
        if self.std_err is not None:
            out["std_err"], out["not_identified"] = self.std_err, self.not_identified
        if self.anchors:
            out["anchors"] = self.anchors
        if self.look_alikes:
            out["look_alikes"] = self.look_alikes
        if self.beyond_bound:
            out["beyond_physical_bound"] = True
        if self.alternative_to:
            out["alternative_to"] = self.alternative_to
        return out


@dataclass
class Diagnosis:
    problem: Problem
    findings: list[Finding]
    model: list[fx.Effect]
    residual_before: dict[str, np.ndarray]
    residual_after: dict[str, np.ndarray]
    identifiability: list[ident.Identifiability] = field(default_factory=list)
    cross_talk: dict[int, list[float]] = field(default_factory=dict)     # lever_arm_cross_talk
    unnamed: list[Unnamed] = field(default_factory=list)                # unnamed_simplest

    def channel_fits(self) -> dict:
        return {name: {"samples": int(len(r)), "gross_errors_left_out": self.problem.left_out[name],
                       "noise_scale": float(self.problem.scales[name][0]),
                       "fit_before": robust_rms(r, self.problem.scales[name]),
                       "fit_after": robust_rms(self.residual_after[name], self.problem.scales[name])}
                for name, r in self.residual_before.items()}

    def to_json(self) -> dict:
        rec = self.problem.rec
        return {"recording": rec.metadata.get("source", ""), "duration_s": float(rec.truth.t[-1] - rec.truth.t[0]),
                "findings": [f.to_json() for f in self.findings], "channels": self.channel_fits(),
                "mismatch": locate(self.problem, self.residual_before),
                "model": [e.to_json() for e in self.model] + self.noise_model,
                "vibration_rms_mps2": self.vibration_rms(),
                "identifiability": [i.to_json() for i in self.identifiability],
                "lever_arm_cross_talk": [{"anchor": k, "delay_m_per_m": rounded_floats(v)}
                                         for k, v in self.cross_talk.items()],
                "unnamed_estimates": [u.to_json() for u in self.unnamed]}

    def vibration_rms(self) -> list[float] | None:
        """The accelerometer's mean vibration RMS per axis over the compared rows: what
        a rectification's gain multiplies on this flight (None without accelerometer)."""
        if not len(self.problem.imu_rows["accel"]):
            return None
        return self.problem.vibration().reshape(-1, 3).mean(axis=0).tolist()

    @cached_property
    def noise_model(self) -> list[dict]:
        """The noise the fitted model leaves, per sample, so `model` simulates data like
        the recording: the TDOA residual after the effects; for the IMU, the raw
        samples' spread around their own running mean (imu_spectrum.SLOW_S) per axis:
        the vibration and sensor noise. Not the spread around the ground truth, whose
        attitude noise, differentiated, is 10–50 times the gyroscope's own noise. When
        the readings were low-pass filtered before logging (their spectrum rolls off),
        the model has the filter (`imu_lowpass`) and the noise before it that comes out
        of it with that spread; when their spectrum peaks (the airframe's slow shaking),
        part of that noise goes through the peak (`imu_resonance`)."""
        out = []
        if "tdoa" in self.residual_after:
            out.append({"effect": "tdoa_noise", "params": {"std_m": mad_scale(self.residual_after["tdoa"])}})
        rec = self.problem.rec
        if not (len(rec.accel) and len(rec.gyro)):
            return out
        sensors = {"accel": rec.accel, "gyro": rec.gyro}
        fits = {name: imu_spectrum.fit_noise(series) for name, series in sensors.items()}
        corners = {name: corner for name, (corner, _) in fits.items()}
        peaks = {name: peak for name, (_, peak) in fits.items()}
        sizes = {name: imu_noise_sizes(series, corners[name], peaks[name]) for name, series in sensors.items()}
        out.append({"effect": "imu_noise", "params": {f"{name}_std": white.tolist()
                                                      for name, (white, _) in sizes.items()}})
        if any(peaks.values()):
            params = {}
            for name, (_, resonant) in sizes.items():
                peak = peaks[name]
                params |= {f"{name}_std": resonant.tolist(), f"{name}_hz": peak.hz if peak else 0.0,
                           f"{name}_q": peak.q if peak else 1.0}
            out.append({"effect": "imu_resonance", "params": params})
        if any(corners.values()):
            out.append({"effect": "imu_lowpass", "params": {"accel_hz": corners["accel"], "gyro_hz": corners["gyro"]}})
        return out


def imu_noise_sizes(series: Vec3Series, corner_hz: float,
                    peak: imu_spectrum.Resonance | None) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the white and the resonant noise before the low-pass that come out
    of it with the recorded spread (`vibration_spread`), in the proportion the
    spectrum's fit gives."""
    own, rate = vibration_spread(series), fx.sample_rate(series.t)
    if peak is None:
        return own / imu_spectrum.noise_gain(corner_hz, rate), np.zeros(3)
    white, resonant = np.sqrt(1.0 - peak.share), np.sqrt(peak.share)
    seconds = float(series.t[-1] - series.t[0])
    scale = own / np.maximum(imu_spectrum.chain_spread(rate, seconds, corner_hz, white, peak, resonant), 1e-12)
    return white * scale, resonant * scale


def vibration_spread(series: Vec3Series) -> np.ndarray:
    """RMS of an IMU series around its own running mean, per axis: what the slow
    motion of a flight leaves out. Readings GROSS_Z robust deviations out are glitches
    and left out, as in the comparison. Not the robust spread itself: the shaking
    comes and goes and its tails are heavy, and noise of the robust spread's size gave
    a 100 Hz estimator's 10 ms means 0.6–0.7 of the recorded accelerometer spread and
    0.3–0.5 of the gyroscope's (the RMS: 0.96–0.99 and 0.6–0.85). Per axis: the
    airframe shakes along some axes several times more than along others."""
    fast, _ = imu_spectrum.fast_part(series)
    if len(fast) < 3:
        return np.zeros(3)
    rms = []
    for values in fast.T:
        kept = values[np.abs(values - np.median(values)) <= GROSS_Z * max(mad_scale(values), 1e-12)]
        rms.append(np.sqrt(np.mean((kept - np.median(values)) ** 2)) if len(kept) else 0.0)
    return np.array(rms)


def diagnose(rec: Recording, progress=None) -> Diagnosis:
    problem = Problem(rec)
    pool = candidates(problem)
    before = problem.residual_before
    findings, model, names, unnamed = [], [], list(before), []
    for name in progress(names) if progress else names:
        as_recorded = problem.channel(name)
        terms, channel, shapes = select(problem, as_recorded, pool)     # fitted jointly
        if name == "tdoa":
            unnamed = unnamed_simplest(problem, as_recorded, terms, pool)
        for fit in shapes:
            findings.append(_shape_finding(problem, fit))
            model.append(fit.effect())
        z_named = _left(channel.z, terms)
        named_theta = {id(t): t.theta for t in terms}
        in_model = _model_terms(channel.z, terms)
        floor = _on_ground_term(problem, _left(channel.z, in_model)) if name == "tdoa" else None
        if floor is not None:        # the model's effects fitted with it: the floor's error is not theirs
            in_model = _model_terms(channel.z, terms, floor)
        z_model = _left(channel.z, in_model + ([floor] if floor else []))
        if floor is not None:
            on_ground = _on_ground_effect(problem, floor)
            findings.append(_on_ground_finding(channel, floor, on_ground, z_model))
            model.append(on_ground)
        simulated = {id(t) for t in in_model}
        for term in terms:
            if id(term) in simulated:
                model.append(_effect_of(problem, channel, term, term.theta))
                z_with, theta = z_model, term.theta
                peers = _simpler(term, [t for t in terms if id(t) in simulated])
            else:
                z_with, theta, peers = z_named, named_theta[id(term)], _simpler(term, terms)
            findings.append(_finding(problem, channel, term, _effect_of(problem, channel, term, term.estimate),
                                     z_with, theta, peers, id(term) in simulated))
        findings += [_alternative_finding(problem, channel, alt, terms)
                     for alt in axis_alternatives(channel.z, terms, _fresh_terms(pool, name), as_recorded.z)]
    after = {name: problem.recorded(name) - pred for name, pred in problem.predict(model).items()}
    if "tdoa" in after:
        floor = _floor_finding(problem, after["tdoa"])
        if floor is not None:
            findings.append(floor)
            model.append(fx.make_effect("multipath_floor", floor.params))
    findings.sort(key=lambda f: -f.evidence)
    return Diagnosis(problem, findings, model, before, after, identifiability(pool), lever_arm_cross_talk(pool),
                     unnamed)


def identifiability(pool: list[Candidate]) -> list[ident.Identifiability]:
    """For every candidate, how large it must be for the recording to show it, and to
    tell it from its look-alikes (rig.identifiability): those of LOOK_ALIKES on its
    anchor that are as simple or simpler (ORDER), the explanations it must beat to be
    named; a richer look-alike gives way to it."""
    out = []
    for c in pool:
        rank = ORDER[c.effect][1]
        alikes = {a.effect: a.columns for a in pool if a.effect in LOOK_ALIKES.get(c.effect, ())
                  and ORDER[a.effect][1] <= rank and a.fixed.get("anchor") == c.fixed.get("anchor")}
        out.append(ident.assess(c.effect, c.anchors, c.param, c.columns, alikes, c.naming_bar, c.bound))
    return out


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
    nlos = _nlos_candidate(anchor)
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
    fraction, mean_excess = nlos_shape(signed[inside], signed[(sign != 0) & ~inside], shift)
    return fx.make_effect("nlos", {"anchor": k, "fraction": fraction, "mean_excess_m": mean_excess,
                                   "region": term.extra["region"]})


def _model_terms(z: np.ndarray, named: list[Term], floor: Term | None = None) -> list[Term]:
    """The named terms that re-simulate the recording, refitted jointly (with `floor`,
    the ranges' change with the tag on the floor, if any). One fitted beyond its
    physical bounds stands for something the catalog does not model, and its
    linearised fit does not re-simulate (an anchor moved by metres), so it is left
    out, the furthest out first."""
    kept = list(named)
    while True:
        _refit(z, kept + ([floor] if floor else []))
        if not kept:
            break
        excess = [np.abs(t.theta).max() / t.candidate.bound for t in kept]
        if max(excess) <= 1.0:
            break
        kept.pop(int(np.argmax(excess)))
    return kept


def _finding(problem: Problem, channel: Channel, term: Term, effect: fx.Effect, z_with: np.ndarray,
             theta: np.ndarray, peers: list[Term], simulated: bool) -> Finding:
    """The effect as estimated (given the simpler explanations); fit_before/fit_after:
    the affected rows' mismatch under the re-simulating model without and with this
    effect (the whole model re-simulated is in Diagnosis.channel_fits); for an effect
    beyond its physical bounds, which the model leaves out, under all named effects
    fitted jointly (`z_with` and `theta` are the fit it is judged in, with `peers`)."""
    rows = np.any(term.columns != 0, axis=1)
    scale = channel.scale[rows]
    z_without = z_with + term.columns @ theta
    std_err, not_identified = _uncertainty(term)
    return Finding(effect.name, channel.name, term.candidate.anchors, rounded_floats(effect.params()),
                   round(float(term.evidence), 2),
                   robust_rms(z_without[rows] * scale, scale), robust_rms(z_with[rows] * scale, scale),
                   _where(problem, channel, term, rows, z_with, theta, peers),
                   [{"candidate": key, "evidence": gain} for key, gain in term.look_alikes],
                   not simulated or bool(np.abs(term.param_map() @ term.estimate).max() > term.candidate.bound),
                   std_err, not_identified)


def _alternative_finding(problem: Problem, channel: Channel, alt: Alternative, named: list[Term]) -> Finding:
    """A look-alike in place of some axes of a named effect: reported with the named
    one, not simulated with it (the model keeps the named effect)."""
    term = alt.term
    finding = _finding(problem, channel, term, _effect_of(problem, channel, term, term.estimate), alt.z_with,
                       term.theta, _simpler(term, named), True)
    instead = {"effect": alt.replaces.candidate.effect}
    if channel.name != "tdoa":
        instead["axes"] = [AXES[j] for j in alt.axes]
    return replace(finding, alternative_to=instead)


def _shape_finding(problem: Problem, fit: nlos_mixture.NlosShapeFit) -> Finding:
    """An NLOS found by its shape: its fit is the likelihood of the anchor's residuals
    inside the region (a noise-level effect, like the floor's)."""
    inside = fit.region.contains(problem.tag_positions()) & (problem.anchor_sign(fit.anchor) != 0)
    effect = fit.effect()
    return Finding("nlos", "tdoa", [fit.anchor], rounded_floats(effect.params()), round(fit.evidence, 2),
                   fit.nll_before, fit.nll_after,
                   {"time": _span(problem.times("tdoa")[inside]), "region": fit.region.to_json(),
                    "anchors": [fit.anchor], "found_by": "shape (a positive exponential tail)",
                    "fit_unit": "mean negative log-likelihood per sample (a noise-level effect)"})


def _uncertainty(term: Term) -> tuple[dict, list[str]]:
    """The estimate's standard errors, keyed like its parameter (an NLOS term fits the
    mean shift, fraction × mean excess), and the components whose standard error is
    more than IDENTIFIED_SD_SHARE of the prior: the trajectory does not tell them
    apart from the simpler explanations, and their values are mostly the prior's."""
    c = term.candidate
    name = "mean_shift_m" if c.effect == "nlos" else c.param
    sd = term.std_err
    vague = np.flatnonzero(sd > IDENTIFIED_SD_SHARE * c.prior)
    sd = sd * c.value_slope(term.estimate)      # in the parameter's unit
    if c.size == 1:
        return {name: rounded_floats(float(sd[0]))}, [name] if len(vague) else []
    return {name: rounded_floats(sd.tolist())}, [f"{name}[{i}]" for i in vague]


def _floor_finding(problem: Problem, residual: np.ndarray) -> Finding | None:
    """Floor multipath on what is left of each measurement after the running median of
    its anchor pair's (local_noise): the extra noise stays, every slowly varying
    mismatch (a bias the model leaves, or one it adds where it extrapolates) goes, so
    the finding does not depend on the rest of the model."""
    noise = local_noise(problem, residual)
    heights = problem.tag_positions()[:, 2]
    floor = floor_multipath(noise, heights, MIN_EVIDENCE + 2 * PENALTY_PER_PARAMETER)
    if floor is None:
        return None
    low = floor["low"]
    before = float(np.mean(robust_nll(noise[low], floor["sigma_one_level"])))
    after = float(np.mean(robust_nll(noise[low], floor["sigma_low"])))
    return Finding("multipath_floor", "tdoa", [], {"height_m": floor["height_m"], "std_m": round(floor["std_m"], 4)},
                   round(floor["evidence"], 2), before, after,
                   {"below_height_m": floor["height_m"], "time": _span(problem.times("tdoa")[low]),
                    "fit_unit": "mean negative log-likelihood per sample (a noise-level effect)"})


def _on_ground_term(problem: Problem, z: np.ndarray) -> Term | None:
    """The ranges' change with the tag on the floor, as a term of the TDOA model, where
    what the model leaves (`z`) supports it (on_ground_fits, at the shape of
    ON_GROUND_SHAPES that removes most): its evidence must pay for its parameters,
    one fewer than the anchors (only their differences show) and its shape. Not a
    candidate of the selection: the samples on the floor are what tells an injected
    displacement or pattern of a floor anchor apart (docs/diagnosis-experiments.md, session 32)."""
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


def rounded_floats(value, digits: int = 6):
    """`value` with every float inside (lists and dicts included) rounded: parameters as
    reported (the fit is not more precise than that)."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, list):
        return [rounded_floats(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: rounded_floats(v, digits) for k, v in value.items()}
    return value


def _span(t: np.ndarray) -> list[float]:
    return [round(float(t.min()), 3), round(float(t.max()), 3)] if len(t) else []


def _where(problem: Problem, channel: Channel, term: Term, rows: np.ndarray, z_after: np.ndarray,
           theta: np.ndarray, peers: list[Term]) -> dict:
    where: dict = {"time": term.extra.get("during") or _span(channel.t[rows])}
    if channel.name == "tdoa":
        positions = problem.tag_positions()[rows]
        where["region"] = term.extra.get("region") or {"min": np.round(positions.min(axis=0), 3).tolist(),
                                                        "max": np.round(positions.max(axis=0), 3).tolist()}
        if "anchor" in term.candidate.fixed:
            where["anchors"] = [term.candidate.fixed["anchor"]]
        return where
    where["axes"] = [AXES[j] for j in _significant_axes(term, theta, z_after, peers)]
    return where


def _significant_axes(term: Term, theta: np.ndarray, z_after: np.ndarray, peers: list[Term]) -> list[int]:
    """Axes whose parameter matters: zeroing it (all else as fitted) raises the robust
    loss by more than 4 (about 2.8 standard errors), with the simpler effects' (`peers`)
    refitted, so one that would make up for it does (simplest first, as in the
    selection): a rectification's gain on an axis that shakes evenly all flight is the
    bias's offset shared out between the two. Look-alikes of equal rank stay as fitted:
    each has its axes, as in the fit, where a bias and a scale are told apart."""
    best = huber_loss(z_after).sum()
    simpler = _stack(peers)
    out = []
    for j in range(term.columns.shape[1]):
        shifted = z_after + term.columns[:, j] * theta[j]
        if simpler is not None:
            shifted = shifted - simpler[0] @ irls(shifted, *simpler)
        if huber_loss(shifted).sum() - best > 4.0:
            out.append(j)
    return out


def locate(problem: Problem, residual: dict[str, np.ndarray]) -> dict:
    """Where the untouched simulation and the recording differ: robust mean mismatch per
    anchor (signed: positive = that anchor's ranges read long), the same with the tag
    on the floor against in flight (tdoa_on_ground_m), per IMU axis and per time
    block."""
    out: dict = {}
    if "tdoa" in residual:
        r, scale = residual["tdoa"], problem.scales["tdoa"][0]
        out["tdoa_per_anchor_m"] = {str(k): huber_mean(problem.anchor_sign(k)[problem.anchor_sign(k) != 0]
                                                        * r[problem.anchor_sign(k) != 0], scale)
                                    for k in problem.anchor_ids}
        out["tdoa_on_ground_m"] = {k: float(v * scale) for k, v in on_ground_delays(problem, r / scale).items()}
    for name in ("accel", "gyro"):
        if name in residual:
            r = residual[name]
            out[f"{name}_per_axis"] = {AXES[a]: huber_mean(r[a::3], problem.scales[name][a]) for a in range(3)}
    for name, r in residual.items():
        t = problem.times(name)
        edges = np.quantile(t, np.linspace(0, 1, TIME_BLOCKS + 1))
        block = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, TIME_BLOCKS - 1)
        out[f"{name}_per_time_block"] = [
            {"time": [round(float(edges[b]), 2), round(float(edges[b + 1]), 2)],
             "robust_rms": robust_rms(r[block == b], problem.scales[name][block == b])}
            for b in range(TIME_BLOCKS) if (block == b).any()]
    return out
