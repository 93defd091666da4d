"""A recording's channels as the diagnosis (rig.diagnosis.diagnose) sees them: TDOA, accelerometer
and gyroscope rows, each the recorded value less a simulation of the recording's own
flight with the simulator's current physics (simulate.Predictor, along the ground
truth), standardised by a robust noise scale (MAD; per axis for the IMU, whose rows
are block means); rows that are gross errors are left out and counted."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rig.data.recording import Recording, Vec3Series
from rig.diagnosis.candidates import design_columns, gyro_scale_candidate
from rig.diagnosis.robust import MIN_SAMPLES, mad_scale
from rig.sim import effects as fx
from rig.sim.simulate import Predictor
from rig.sim.trajectory import ATTITUDE_WINDOW_S, window_mean

log = logging.getLogger(__name__)

FOLDS = 5                      # contiguous time blocks for cross-validation
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

    def slow_error_times(self) -> np.ndarray | None:
        """The rows' times where the channel's error varies slowly (TDOA: its standard
        errors count that, rig.diagnosis.terms.estimate_terms); None for the IMU
        channels, whose rows are block means that share little noise."""
        return self.t if self.name == "tdoa" else None

    def folds(self) -> np.ndarray:
        edges = np.quantile(self.t, np.linspace(0, 1, FOLDS + 1))
        return np.clip(np.searchsorted(edges, self.t, side="right") - 1, 0, FOLDS - 1)



class Problem:
    """A recording, its predictor and the channels' rows."""

    def __init__(self, rec: Recording, predictor: Predictor | None = None):
        self.rec = rec
        self.predictor = predictor or Predictor(rec)
        t0, t1 = rec.truth.t[0] + EDGE_S, rec.truth.t[-1] - EDGE_S
        d = rec.tdoa
        known = [a.id for a in rec.anchors]
        in_window = (d.t >= t0) & (d.t <= t1)
        usable = np.isfinite(d.distance_diff) & np.isin(d.id_a, known) & np.isin(d.id_b, known)
        self.tdoa_rows = np.flatnonzero(in_window & usable)
        self.unusable = {"tdoa": int(np.sum(in_window & ~usable))}
        self.unknown_anchors = sorted(int(k) for k in set(np.concatenate([d.id_a[in_window], d.id_b[in_window]]))
                                      - set(known))
        self.imu_rows, self.imu_blocks = {}, {}
        for name, series in (("accel", rec.accel), ("gyro", rec.gyro)):
            in_window = (series.t >= t0) & (series.t <= t1)
            finite = np.all(np.isfinite(series.xyz), axis=1)
            rows = np.flatnonzero(in_window & finite)
            self.unusable[name] = int(np.sum(in_window & ~finite))
            self._set_imu_rows(name, rows, _block_index(series.t[rows] - t0, IMU_BLOCK_S[name]))
        if any(self.unusable.values()):
            log.warning("left out as unusable (not finite%s): %s", self._unknown_text(),
                        left_out_text(self.unusable))
        self.gyro_block_s = IMU_BLOCK_S["gyro"]
        if len(self.imu_rows["gyro"]):
            self._choose_gyro_blocks(t0)
        self.left_out = self._leave_out_gross_errors()
        self.anchor_ids = sorted(int(k) for k in np.unique(np.concatenate([d.id_a[self.tdoa_rows],
                                                                          d.id_b[self.tdoa_rows]]))
                                 if self._anchor_rows(k).sum() >= MIN_SAMPLES)
        self._tag_positions = self.predictor.tdoa([]).tag_position[self.tdoa_rows]

    def _unknown_text(self) -> str:
        return (f", or a range from anchor {', '.join(map(str, self.unknown_anchors))}, which the recording's "
                f"anchor set lacks" if self.unknown_anchors else "")

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
        return fx.anchor_sign(d.id_a[self.tdoa_rows], d.id_b[self.tdoa_rows], k)

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
