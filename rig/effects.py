"""Composable physical effects for the simulator.

The simulator first builds the ideal world (true anchor positions, tag antenna
offset), computes ideal IMU readings and ideal TDOA geometry, then hands the
batches to each effect in stage order. Every effect is a small class with a
catalog `name`, JSON `params` and hooks that change a batch in place; effects
that do not touch a stream leave its hook as the no-op default. `make_effect`
builds one from its catalog name and parameters, so a simulation (or a fitted
model from the diagnosis) is a plain JSON list of effects.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import butter, iirpeak, lfilter, lfilter_zi
from scipy.spatial.transform import Rotation

from rig import native
from rig.bias_model import DEFAULT_NETWORK, BiasNet

# Stages, in order of application.
WORLD = 0       # changes what is physically true (anchor positions, lever arm)
SCALE = 1       # multiplicative sensor errors (scale factors), before any additive one
SIGNAL = 2      # deterministic additive sensor errors (biases, delays, antenna pattern)
NOISE = 3       # random errors (white noise, NLOS excess delays)
RECTIFIED = 4   # errors made of the noise itself (vibration rectification)
CORRUPTION = 5  # rare gross errors (outliers)
FILTERED = 6    # what the flight controller does to the readings before logging them (low-pass)
TIMING = 7      # timestamps (offsets, drift)

VIBRATION_HIGHPASS_S = 0.02    # vibration: the accelerometer less its running mean this long ...
VIBRATION_RMS_S = 0.2          # ... as a running RMS this long


@dataclass
class World:
    """What is physically true in a simulation, as effects of stage WORLD leave it."""

    anchor_positions: dict[int, np.ndarray]
    anchor_rotations: dict[int, Rotation]
    lever_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def surveyed(cls, anchors) -> "World":
        """The world as the survey has it (`survey.Anchor`s), before any effect."""
        return cls(anchor_positions={a.id: np.array(a.position, float) for a in anchors},
                   anchor_rotations={a.id: a.rotation for a in anchors})

    def known_pairs(self, id_a: np.ndarray, id_b: np.ndarray) -> np.ndarray:
        """Which measurements are between two anchors of this world."""
        return np.isin(id_a, list(self.anchor_positions)) & np.isin(id_b, list(self.anchor_positions))

    def anchor_poses(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position and rotation matrix of anchor ids[k] for every k (each anchor converted once)."""
        unique, index = np.unique(np.asarray(ids), return_inverse=True)
        positions = np.array([self.anchor_positions[int(k)] for k in unique], float).reshape(-1, 3)
        rotations = np.array([self.anchor_rotations[int(k)].as_matrix() for k in unique]).reshape(-1, 3, 3)
        return positions[index.ravel()], rotations[index.ravel()]


@dataclass
class ImuBatch:
    """IMU samples being simulated: true values in, measured values out."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    # RMS of the accelerometer's vibration at each sample and axis when it is known
    # (a recording's, see vibration_level); otherwise measured on `accel` as it stands
    vibration: np.ndarray | None = None
    # the rotors' speed at each sample relative to hover, 0 with the motors stopped
    # (Trajectory.rotor_speed); None when not known: taken as hover all along
    rotor: np.ndarray | None = None


@dataclass
class TdoaBatch:
    """TDOA samples being simulated, with the geometry effects may need."""

    t: np.ndarray
    id_a: np.ndarray
    id_b: np.ndarray
    tag_position: np.ndarray   # true tag antenna position at each sample (m)
    tag_rotation: Rotation     # true body attitude at each sample
    value: np.ndarray          # distance_diff being built up (m)

    def range_to(self, world: World, ids: np.ndarray) -> np.ndarray:
        return ranges(self.tag_position, world, ids)


def ranges(tag_position: np.ndarray, world: World, ids: np.ndarray) -> np.ndarray:
    """Distance from each tag position to the true position of the matching anchor."""
    anchors = np.array([world.anchor_positions[int(k)] for k in ids]).reshape(-1, 3)
    return np.linalg.norm(tag_position - anchors, axis=1)


class Effect:
    """Base class; subclasses set `name`, `stage` and override the hooks they need."""

    name: ClassVar[str] = ""
    stage: ClassVar[int] = SIGNAL

    def params(self) -> dict:
        return {}

    def to_json(self) -> dict:
        return {"effect": self.name, "params": self.params()}

    def apply_world(self, world: World) -> None:
        """Change the true world before any measurement is computed."""

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator) -> None:
        """Change IMU readings in place."""

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        """Change TDOA values (or timestamps) in place. With `rng` None, random effects add
        their expected value (the diagnosis predicts; the simulator draws)."""

    def stamp(self, t: np.ndarray) -> np.ndarray:
        """Timing effects: the UWB timestamp of a measurement made at true time `t`."""
        return t


def _finite(value, name: str, what: str = "a finite number", valid=None) -> float:
    """A parameter that must be one finite number, `valid` if given (NaN would pass
    every range check: each comparison is false)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = np.nan
    if not np.isfinite(x) or (valid is not None and not valid(x)):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return x


FRACTION, HEIGHT = "a fraction within [0, 1]", "a height > 0"


def _fraction(x: float) -> bool:
    return 0.0 <= x <= 1.0


def _positive(x: float) -> bool:
    return x > 0.0


def _non_negative(x: float) -> bool:
    return x >= 0.0


def _vec3(value, name: str) -> np.ndarray:
    v = np.asarray(value, float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be three finite numbers, got {value!r}")
    return v


class _Windowed:
    """An effect that may act during part of the flight only: optional parameter
    `during` = [t_start, t_end] on the recording's clock."""

    during: tuple[float, float] | None = None

    def _set_during(self, during) -> None:
        if during is not None:
            t0, t1 = map(float, during)
            if not t1 > t0:
                raise ValueError(f"during must be [start, end] with end > start, got {during!r}")
            self.during = (t0, t1)

    def _window_params(self) -> dict:
        return {} if self.during is None else {"during": list(self.during)}

    def active(self, t: np.ndarray) -> np.ndarray:
        if self.during is None:
            return np.ones(len(t), bool)
        return (t >= self.during[0]) & (t < self.during[1])


class _ImuVectorEffect(_Windowed, Effect):
    """One vector parameter acting on one IMU stream (body frame)."""

    stream: ClassVar[str] = ""   # "accel" or "gyro"
    param: ClassVar[str] = ""    # the catalog's parameter name
    neutral: ClassVar[float] = 0.0

    def __init__(self, during=None, **params):
        unknown = set(params) - {self.param}
        if unknown:
            raise TypeError(f"unexpected parameter(s) {sorted(unknown)}")
        self.value = _vec3(params.get(self.param, (self.neutral,) * 3), self.param)
        self._set_during(during)

    def params(self) -> dict:
        return {self.param: self.value.tolist(), **self._window_params()}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        stream = getattr(imu, self.stream)
        stream[self.active(imu.t)] = self._apply(stream[self.active(imu.t)])

    def _apply(self, values: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class _ImuConstantBias(_ImuVectorEffect):
    """measured = true + bias."""

    stage = SIGNAL

    def _apply(self, values: np.ndarray) -> np.ndarray:
        return values + self.value


class _ImuScale(_ImuVectorEffect):
    """measured = scale × true, per axis."""

    stage, param, neutral = SCALE, "scale", 1.0

    def _apply(self, values: np.ndarray) -> np.ndarray:
        return values * self.value


class ImuAccelScale(_ImuScale):
    """Accelerometer scale factors."""

    name, stream = "imu_accel_scale", "accel"


class ImuGyroScale(_ImuScale):
    """Gyroscope scale factors."""

    name, stream = "imu_gyro_scale", "gyro"


class ImuAccelBias(_ImuConstantBias):
    """Accelerometer bias (m/s²)."""

    name, stream, param = "imu_accel_bias", "accel", "bias_mps2"


class ImuGyroBias(_ImuConstantBias):
    """Gyroscope bias (rad/s)."""

    name, stream, param = "imu_gyro_bias", "gyro", "bias_rps"


def sample_rate(t: np.ndarray) -> float:
    """Mean samples per second of a series' stamps."""
    return (len(t) - 1) / max(float(t[-1] - t[0]), 1e-9)


def vibration_level(t: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """RMS of the accelerometer's vibration around each sample, per axis: the readings
    less their VIBRATION_HIGHPASS_S running mean (the airframe shaking at the rotor
    frequencies, not the flight's motion), as a VIBRATION_RMS_S running RMS. Rows that
    are not finite read 0."""
    level = np.zeros(np.shape(accel))
    ok = np.all(np.isfinite(accel), axis=1)
    if ok.sum() < 3:
        return level
    rate = sample_rate(t[ok])
    window = max(3, int(round(VIBRATION_HIGHPASS_S * rate)))
    fast = accel[ok] - uniform_filter1d(accel[ok], window, axis=0, mode="nearest")
    window = max(1, int(round(VIBRATION_RMS_S * rate)))
    power = uniform_filter1d(fast ** 2, window, axis=0, mode="nearest")
    level[ok] = np.sqrt(np.maximum(power, 0.0))      # a running sum's rounding can dip below 0
    return level


def logged_vibration(imu: ImuBatch, effects: list["Effect"]) -> np.ndarray:
    """The vibration level (`vibration_level`) the log will show of the readings as
    they stand: after the effects that filter them before logging (FILTERED). A
    rectification's gain is measured against a log's vibration, so a simulation feeds
    it the same: the shaking before a 30 Hz low-pass reads about 8 times larger."""
    logged = ImuBatch(imu.t, imu.accel.copy(), imu.gyro.copy())
    for effect in effects:
        if effect.stage == FILTERED:
            effect.apply_imu(logged, None)
    return vibration_level(imu.t, logged.accel)


def staged(effects: list["Effect"]) -> list["Effect"]:
    """The effects in the order they act: by stage."""
    return sorted(effects, key=lambda e: e.stage)


def apply_imu(effects: list["Effect"], rng: np.random.Generator | None, *batches: ImuBatch) -> None:
    """The effects on IMU batches in stage order, each effect on every batch in turn
    (the random draws go in that order). Where a batch's vibration is not known (a
    simulated flight), the rectifying effects get the level the log will show
    (`logged_vibration`), measured on the readings as the stages before them leave
    them."""
    for effect in staged(effects):
        for imu in batches:
            if effect.stage == RECTIFIED and imu.vibration is None:
                imu.vibration = logged_vibration(imu, effects)
            effect.apply_imu(imu, rng)


class ImuVibrationRectification(_ImuVectorEffect):
    """Vibration rectification: an accelerometer axis shaken by the rotors reads `gain`
    × the RMS of its vibration (`vibration_level`) too high. A sensor or mount that
    responds unevenly to the two directions of a fast oscillation turns part of it into
    a slow offset, which follows the vibration (the propellers' balance, the motors'
    speed) and is absent with the motors off: a bias that comes and goes in flight."""

    name, stream, param, stage = "imu_vibration_rectification", "accel", "gain", RECTIFIED

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        level = imu.vibration if imu.vibration is not None else vibration_level(imu.t, imu.accel)
        active = self.active(imu.t)
        imu.accel[active] += self.value * level[active]


class ImuNoise(Effect):
    """White noise on every IMU axis (standard deviations in m/s² and rad/s): one for
    all three axes, or one per axis ([x, y, z]; an airframe shakes along some axes
    more than others)."""

    name, stage = "imu_noise", NOISE

    def __init__(self, accel_std: float | list = 0.05, gyro_std: float | list = 0.005):
        self.accel_std, self.gyro_std = _std(accel_std, "accel_std"), _std(gyro_std, "gyro_std")

    def params(self) -> dict:
        return {"accel_std": self.accel_std, "gyro_std": self.gyro_std}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        if rng is None:
            return
        imu.accel += rng.normal(0.0, self.accel_std, imu.accel.shape)
        imu.gyro += rng.normal(0.0, self.gyro_std, imu.gyro.shape)


def _std(value, name: str) -> float | list[float]:
    """A standard deviation for all three axes (a number) or one per axis (a list)."""
    what = "a standard deviation >= 0, or three"
    if np.ndim(value) == 0:
        return _finite(value, name, what, _non_negative)
    std = _vec3(value, name)
    if np.any(std < 0):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return std.tolist()


class ImuVibration(Effect):
    """The airframe shaken by the rotors: white noise per axis (standard deviations in
    m/s² and rad/s at hover) that grows with the rotors' speed and stops with the motors,
    on top of the sensor's own `imu_noise`. It is what a vibration rectification feeds
    on, so on a simulated flight too the rectification comes and goes with the motors."""

    name, stage = "imu_vibration", NOISE

    def __init__(self, accel_std=(0.0, 0.0, 0.0), gyro_std=(0.0, 0.0, 0.0)):
        self.accel_std, self.gyro_std = _vec3(accel_std, "accel_std"), _vec3(gyro_std, "gyro_std")

    def params(self) -> dict:
        return {"accel_std": self.accel_std.tolist(), "gyro_std": self.gyro_std.tolist()}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        if rng is None:
            return
        rotor = np.ones(len(imu.t)) if imu.rotor is None else imu.rotor
        imu.accel += rng.normal(0.0, 1.0, imu.accel.shape) * self.accel_std * rotor[:, None]
        imu.gyro += rng.normal(0.0, 1.0, imu.gyro.shape) * self.gyro_std * rotor[:, None]


class ImuResonance(Effect):
    """The airframe's slow shaking: white noise through a resonance (a second-order
    peak at `accel_hz` / `gyro_hz`, quality `accel_q` / `gyro_q`: bandwidth hz / q),
    of standard deviation `accel_std` / `gyro_std` [x, y, z]. Real logs
    peak at 5–10 Hz, the attitude loop's wobble and the frame's sway, which the
    ground truth does not resolve and a 100 Hz estimator takes in whole. A frequency
    of 0 leaves that sensor as it is."""

    name, stage = "imu_resonance", NOISE

    def __init__(self, accel_std=(0.0, 0.0, 0.0), gyro_std=(0.0, 0.0, 0.0), accel_hz: float = 0.0,
                 gyro_hz: float = 0.0, accel_q: float = 1.0, gyro_q: float = 1.0):
        self.accel_std, self.gyro_std = _vec3(accel_std, "accel_std"), _vec3(gyro_std, "gyro_std")
        self.accel_hz, self.gyro_hz = _corner(accel_hz, "accel_hz"), _corner(gyro_hz, "gyro_hz")
        self.accel_q, self.gyro_q = _quality(accel_q, "accel_q"), _quality(gyro_q, "gyro_q")

    def params(self) -> dict:
        return {"accel_std": self.accel_std.tolist(), "gyro_std": self.gyro_std.tolist(), "accel_hz": self.accel_hz,
                "gyro_hz": self.gyro_hz, "accel_q": self.accel_q, "gyro_q": self.gyro_q}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        if rng is None or len(imu.t) < 3:
            return
        rate = sample_rate(imu.t)
        imu.accel += resonant_noise(rng, len(imu.t), rate, self.accel_hz, self.accel_q) * self.accel_std
        imu.gyro += resonant_noise(rng, len(imu.t), rate, self.gyro_hz, self.gyro_q) * self.gyro_std


def _quality(value, name: str) -> float:
    return _finite(value, name, "a quality factor > 0", _positive)


def resonance_design(hz: float, q: float, rate: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The coefficients (b, a) of a second-order peak of unit gain at `hz`, or None
    where `_filters` says it filters nothing."""
    return iirpeak(hz, q, fs=rate) if _filters(hz, rate) else None


def resonant_noise(rng: np.random.Generator, n: int, rate: float, hz: float, q: float) -> np.ndarray:
    """n rows of noise of unit standard deviation on three axes: white noise through
    the resonance (zeros where `resonance_design` gives none), started a second early
    so it starts settled."""
    design = resonance_design(hz, q, rate)
    if design is None:
        return np.zeros((n, 3))
    lead = int(rate)
    return lfilter(*design, rng.normal(0.0, 1.0, (n + lead, 3)), axis=0)[lead:] / resonance_gain(hz, q, rate)


def resonance_gain(hz: float, q: float, rate: float) -> float:
    """Standard deviation of white noise after the resonance, per unit before it."""
    return filter_noise_gain(resonance_design(hz, q, rate), int(20 * q * rate / hz))


def filter_noise_gain(design: tuple[np.ndarray, np.ndarray], settle: int) -> float:
    """Standard deviation of white noise after the filter `design`, per unit before
    it: the RMS sum of its impulse response over `settle` samples (a few time
    constants) and a few more."""
    impulse = np.zeros(settle + 16)
    impulse[0] = 1.0
    return float(np.sqrt(np.sum(lfilter(*design, impulse) ** 2)))


class ImuLowpass(Effect):
    """The flight controller's low-pass filter on the IMU readings it logs: a causal
    second-order Butterworth filter with corners `accel_hz` and `gyro_hz` (the
    Crazyflie firmware's defaults are 30 and 80 Hz at 1 kHz), applied to everything the
    sensor reads, true motion, errors and noise alike. It gives the noise the spectrum of
    a real log: its power below the corner, where block means and a 100 Hz estimator do
    not average it away. A corner of 0, or at or above LOWPASS_MAX_SHARE of the sample
    rate, leaves that stream as it is (no roll-off to model)."""

    name, stage = "imu_lowpass", FILTERED

    def __init__(self, accel_hz: float = 0.0, gyro_hz: float = 0.0):
        self.accel_hz, self.gyro_hz = _corner(accel_hz, "accel_hz"), _corner(gyro_hz, "gyro_hz")

    def params(self) -> dict:
        return {"accel_hz": self.accel_hz, "gyro_hz": self.gyro_hz}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        imu.accel = lowpass(imu.t, imu.accel, self.accel_hz)
        imu.gyro = lowpass(imu.t, imu.gyro, self.gyro_hz)


LOWPASS_ORDER = 2
LOWPASS_MAX_SHARE = 0.45       # of the sample rate: a corner closer to Nyquist filters nothing


def _corner(value, name: str) -> float:
    return _finite(value, name, "a corner frequency >= 0 Hz (0: no filter)", _non_negative)


def lowpass_design(corner_hz: float, rate: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The coefficients (b, a) of the Butterworth low-pass of LOWPASS_ORDER at
    `corner_hz` for readings at `rate`, or None where it filters nothing: a corner of
    0, or at or above LOWPASS_MAX_SHARE of the rate (`_filters`)."""
    return butter(LOWPASS_ORDER, corner_hz, fs=rate) if _filters(corner_hz, rate) else None


def _filters(hz: float, rate: float) -> bool:
    """Whether a filter at `hz` acts on readings at `rate`: not at 0 Hz (none asked
    for), nor at or above LOWPASS_MAX_SHARE of the rate (too close to Nyquist)."""
    return 0 < hz < LOWPASS_MAX_SHARE * rate


def lowpass(t: np.ndarray, values: np.ndarray, corner_hz: float) -> np.ndarray:
    """`values` (rows in time) through the causal low-pass `lowpass_design` gives,
    started settled on the first reading (no start-up transient). Rows that are not
    finite are skipped and kept as they are, so one bad reading does not spread into
    the rest."""
    finite = np.isfinite(values)
    ok = finite.all(axis=1) if finite.ndim == 2 else finite
    design = lowpass_design(corner_hz, sample_rate(t[ok])) if ok.sum() >= 3 else None
    if design is None:
        return values
    b, a = design
    out = values.copy()
    x = values[ok]
    out[ok] = lfilter(b, a, x, axis=0, zi=np.multiply.outer(lfilter_zi(b, a), x[0]))[0]
    return out


class TdoaNoise(Effect):
    """Zero-mean Gaussian noise on every TDOA measurement (m)."""

    name, stage = "tdoa_noise", NOISE

    def __init__(self, std_m: float = 0.1):
        self.std = _finite(std_m, "std_m", "a standard deviation >= 0", _non_negative)

    def params(self) -> dict:
        return {"std_m": self.std}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is not None:
            tdoa.value += rng.normal(0.0, self.std, tdoa.value.shape)


class Outliers(Effect):
    """A `fraction` of TDOA samples gets an excess path delay on one of its two
    anchors (exponential, mean `mean_excess_m`): multipath makes a path longer,
    so the error's sign says which anchor was hit."""

    name, stage = "outliers", CORRUPTION

    def __init__(self, fraction: float = 0.05, mean_excess_m: float = 2.0):
        self.fraction = _finite(fraction, "fraction", FRACTION, _fraction)
        self.mean_excess = _finite(mean_excess_m, "mean_excess_m")

    def params(self) -> dict:
        return {"fraction": self.fraction, "mean_excess_m": self.mean_excess}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is None:        # symmetric in sign: no expected shift
            return
        hit = rng.random(len(tdoa.value)) < self.fraction
        excess = 1.0 + rng.exponential(self.mean_excess, len(tdoa.value))
        # A longer path to B raises distance_diff, a longer path to A lowers it.
        sign = np.where(rng.random(len(tdoa.value)) < 0.5, 1.0, -1.0)
        tdoa.value += np.where(hit, sign * excess, 0.0)


def anchor_sign(id_a: np.ndarray, id_b: np.ndarray, anchor: int) -> np.ndarray:
    """+1 where `anchor` is B (its range adds to distance_diff), -1 where it is A, else 0."""
    return (id_b == anchor).astype(float) - (id_a == anchor).astype(float)


def _anchor_sign(tdoa: TdoaBatch, anchor: int) -> np.ndarray:
    return anchor_sign(tdoa.id_a, tdoa.id_b, anchor)


def _anchor_id(anchor) -> int:
    if isinstance(anchor, bool) or int(anchor) != anchor or anchor < 0:
        raise ValueError(f"anchor must be a non-negative integer id, got {anchor!r}")
    return int(anchor)


class _UwbClock(Effect):
    """A timing effect: moves the UWB stamps by `stamp`."""

    stage = TIMING

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        tdoa.t = self.stamp(tdoa.t)


class TimeOffset(_UwbClock):
    """UWB timestamps are late by `seconds` relative to the IMU and ground-truth clock."""

    name = "time_offset"

    def __init__(self, seconds: float = 0.0):
        self.seconds = _finite(seconds, "seconds")

    def params(self) -> dict:
        return {"seconds": self.seconds}

    def stamp(self, t: np.ndarray) -> np.ndarray:
        return t + self.seconds


class ClockDrift(_UwbClock):
    """The UWB timestamps run fast by `ppm` relative to the IMU clock (zero at t = 0 of
    the recording's clock)."""

    name = "clock_drift"

    def __init__(self, ppm: float = 0.0):
        self.ppm = _finite(ppm, "ppm")

    def params(self) -> dict:
        return {"ppm": self.ppm}

    def stamp(self, t: np.ndarray) -> np.ndarray:
        return t * (1.0 + self.ppm * 1e-6)


class AnchorPosition(Effect):
    """The anchor's antenna is really at surveyed + `offset_m` (true minus surveyed)."""

    name, stage = "anchor_position", WORLD

    def __init__(self, anchor: int = 0, offset_m=(0.0, 0.0, 0.0)):
        self.anchor, self.offset = _anchor_id(anchor), _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"anchor": self.anchor, "offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        if self.anchor in world.anchor_positions:
            world.anchor_positions[self.anchor] = world.anchor_positions[self.anchor] + self.offset


class LeverArm(Effect):
    """The UWB antenna sits at `offset_m` from the body origin (body frame)."""

    name, stage = "lever_arm", WORLD

    def __init__(self, offset_m=(0.0, 0.0, 0.0)):
        self.offset = _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        world.lever_arm = world.lever_arm + self.offset


class AnchorDelay(_Windowed, Effect):
    """Every range from `anchor` reads `meters` too long (an antenna delay error). With
    `during`, `meters` holds in that window and `outside_m` (default 0) elsewhere: a
    delay that changes for part of the flight (TDOA sees delays only relative to each
    other, so "no delay outside the window" is rarely what a diagnosis can say)."""

    name, stage = "anchor_delay", SIGNAL

    def __init__(self, anchor: int = 0, meters: float = 0.0, during=None, outside_m: float = 0.0):
        self.anchor, self.meters = _anchor_id(anchor), _finite(meters, "meters")
        self.outside_m = _finite(outside_m, "outside_m")
        self._set_during(during)
        if self.outside_m and self.during is None:
            raise ValueError("outside_m needs a window (during)")

    def params(self) -> dict:
        window = {**self._window_params(), "outside_m": self.outside_m} if self.during else {}
        return {"anchor": self.anchor, "meters": self.meters, **window}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        delay = np.where(self.active(tdoa.t), self.meters, self.outside_m)
        tdoa.value += delay * _anchor_sign(tdoa, self.anchor)


def viewing_angles(tdoa: TdoaBatch, world: World, anchor: int) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of the tag seen in `anchor`'s own frame."""
    rel = tdoa.tag_position - world.anchor_positions[anchor]
    return _azimuth_elevation(world.anchor_rotations[anchor].inv().apply(rel))


def _azimuth_elevation(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of direction vectors given in some frame."""
    return np.arctan2(local[:, 1], local[:, 0]), np.arcsin(np.clip(local[:, 2] / np.linalg.norm(local, axis=1),
                                                                   -1.0, 1.0))


def pattern_basis(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """The antenna-pattern bias terms: the second-order real spherical harmonics that do
    not look like a displaced antenna (first order) or a delay (constant):
    sin²(el) − 1/3, cos²(el)·cos(2 az), cos²(el)·sin(2 az)."""
    c2 = np.cos(elevation) ** 2
    return np.stack([np.sin(elevation) ** 2 - 1.0 / 3.0, c2 * np.cos(2 * azimuth), c2 * np.sin(2 * azimuth)], axis=1)


class AntennaPattern(_Windowed, Effect):
    """Range bias of `anchor` depending on where the tag is seen from the anchor (its
    doughnut-shaped radiation pattern, paper Section II.B): `coeffs_m` weigh
    `pattern_basis` of the tag's azimuth and elevation in the anchor's frame."""

    name, stage = "antenna_pattern", SIGNAL

    def __init__(self, anchor: int = 0, coeffs_m=(0.0, 0.0, 0.0), during=None):
        self.anchor, self.coeffs = _anchor_id(anchor), _vec3(coeffs_m, "coeffs_m")
        self._set_during(during)

    def params(self) -> dict:
        return {"anchor": self.anchor, "coeffs_m": self.coeffs.tolist(), **self._window_params()}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if self.anchor not in world.anchor_positions:
            return
        bias = pattern_basis(*viewing_angles(tdoa, world, self.anchor)) @ self.coeffs
        tdoa.value += bias * _anchor_sign(tdoa, self.anchor) * self.active(tdoa.t)


class TagAntennaPattern(Effect):
    """Range bias depending on where each anchor is seen from the tag's own antenna, in
    the body frame (paper Section II.B: the tag's pose shapes the bias as much as the
    anchors'; the doughnut of its antenna and the airframe around it): `coeffs_m`
    weigh `pattern_basis` of the anchor's azimuth and elevation in the body frame, the
    same for every anchor. Its first order is a lever arm (catalog's `lever_arm`)."""

    name, stage = "tag_antenna_pattern", SIGNAL

    def __init__(self, coeffs_m=(0.0, 0.0, 0.0)):
        self.coeffs = _vec3(coeffs_m, "coeffs_m")

    def params(self) -> dict:
        return {"coeffs_m": self.coeffs.tolist()}

    def range_bias(self, position: np.ndarray, attitude: Rotation, world: World, ids: np.ndarray) -> np.ndarray:
        """Each range's bias from anchor ids[k], seen in the tag's body frame."""
        anchors, _ = world.anchor_poses(ids)
        return pattern_basis(*_azimuth_elevation(attitude.inv().apply(anchors - position))) @ self.coeffs

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        known = np.flatnonzero(world.known_pairs(tdoa.id_a, tdoa.id_b))
        if len(known):
            pose = tdoa.tag_position[known], tdoa.tag_rotation[known], world
            tdoa.value[known] += self.range_bias(*pose, tdoa.id_b[known]) - self.range_bias(*pose, tdoa.id_a[known])


@dataclass
class Region:
    """An axis-aligned box in the world frame."""

    low: np.ndarray
    high: np.ndarray

    @classmethod
    def from_json(cls, region) -> "Region":
        if region is None:
            return cls(np.full(3, -np.inf), np.full(3, np.inf))
        if not isinstance(region, dict) or set(region) != {"min", "max"}:
            raise ValueError(f"region must be {{'min': [x, y, z], 'max': [x, y, z]}}, got {region!r}")
        return cls(_vec3(region["min"], "region min"), _vec3(region["max"], "region max"))

    def to_json(self) -> dict | None:
        if not np.isfinite(self.low).any() and not np.isfinite(self.high).any():
            return None
        return {"min": self.low.tolist(), "max": self.high.tolist()}

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.all((points >= self.low) & (points <= self.high), axis=1)


class Nlos(_Windowed, Effect):
    """Non-line-of-sight to `anchor` while the tag is inside `region`: a `fraction` of
    those ranges gets a positive excess delay, exponential with mean `mean_excess_m`."""

    name, stage = "nlos", NOISE

    def __init__(self, anchor: int = 0, fraction: float = 1.0, mean_excess_m: float = 0.0, region=None,
                 during=None):
        self.anchor, self.fraction = _anchor_id(anchor), _finite(fraction, "fraction", FRACTION, _fraction)
        self.mean_excess = _finite(mean_excess_m, "mean_excess_m", "an excess delay >= 0", _non_negative)
        self.region = Region.from_json(region)
        self._set_during(during)

    def params(self) -> dict:
        return {"anchor": self.anchor, "fraction": self.fraction, "mean_excess_m": self.mean_excess,
                "region": self.region.to_json(), **self._window_params()}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        inside = self.region.contains(tdoa.tag_position) & self.active(tdoa.t)
        if rng is None:
            excess = np.full(len(tdoa.t), self.fraction * self.mean_excess)
        else:
            hit = rng.random(len(tdoa.t)) < self.fraction
            excess = np.where(hit, rng.exponential(max(self.mean_excess, 1e-12), len(tdoa.t)), 0.0)
        tdoa.value += excess * inside * _anchor_sign(tdoa, self.anchor)


class MultipathFloor(Effect):
    """Near the floor, reflections add error: below `height_m` every TDOA gets extra
    zero-mean noise of `std_m` (the tag's height is what matters, not the anchor).
    Optionally a second, higher step: below `upper_height_m` extra noise of
    `upper_std_m` too (independent: below both, their variances add)."""

    name, stage = "multipath_floor", NOISE

    def __init__(self, height_m: float = 0.3, std_m: float = 0.0, upper_height_m: float | None = None,
                 upper_std_m: float = 0.0):
        self.height = _finite(height_m, "height_m", HEIGHT, _positive)
        self.std = _finite(std_m, "std_m", "a standard deviation >= 0", _non_negative)
        self.upper_height = None if upper_height_m is None else _finite(
            upper_height_m, "upper_height_m", f"a height above height_m ({self.height} m)", lambda h: h > self.height)
        self.upper_std = _finite(upper_std_m, "upper_std_m", "a standard deviation >= 0", _non_negative)

    def params(self) -> dict:
        upper = {} if self.upper_height is None else {"upper_height_m": self.upper_height,
                                                        "upper_std_m": self.upper_std}
        return {"height_m": self.height, "std_m": self.std} | upper

    def low(self, tag_position: np.ndarray) -> np.ndarray:
        return tag_position[:, 2] < self.height

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is None:
            return
        tdoa.value += rng.normal(0.0, self.std, len(tdoa.t)) * self.low(tdoa.tag_position)
        if self.upper_height is not None:
            below = tdoa.tag_position[:, 2] < self.upper_height
            tdoa.value += rng.normal(0.0, self.upper_std, len(tdoa.t)) * below


def on_ground_weight(height: np.ndarray, below_m: float, fade_m: float = 0.0) -> np.ndarray:
    """How much of the floor's error a tag at `height` has: all of it below `below_m`,
    none above `below_m + fade_m`, linearly in between (0 fade: a step)."""
    if fade_m <= 0.0:
        return (height < below_m).astype(float)
    return np.clip((below_m + fade_m - height) / fade_m, 0.0, 1.0)


class OnGroundDelay(Effect):
    """With the drone on the floor (its body origin, the ground truth's position,
    below `height_m`), every range from anchor k reads `meters[k]` longer than in
    flight, fading out linearly over `fade_m` above that height: the floor lies in
    the direct paths, most to the anchors at its own height, and what arrives first
    has gone round (real flights: metres, docs/diagnosis.md). Keys are anchor ids;
    TDOA sees the values only relative to each other. The body, not the antenna: a
    lever arm fitted to a flight (decimetres on z, docs/diagnosis.md) would otherwise
    move where the floor begins."""

    name, stage = "on_ground_delay", SIGNAL

    def __init__(self, meters: dict | None = None, height_m: float = 0.2, fade_m: float = 0.0):
        self.height = _finite(height_m, "height_m", HEIGHT, _positive)
        self.fade = _finite(fade_m, "fade_m", "a width >= 0", lambda v: v >= 0.0)
        try:
            self.meters = {_anchor_id(int(k)): float(m) for k, m in (meters or {}).items()}
        except (TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"meters must map anchor ids to metres, got {meters!r}") from exc
        if not all(np.isfinite(m) for m in self.meters.values()):
            raise ValueError(f"meters must be finite, got {meters!r}")

    def params(self) -> dict:
        return {"height_m": self.height, "fade_m": self.fade,
                "meters": {str(k): m for k, m in sorted(self.meters.items())}}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        body = tdoa.tag_position - tdoa.tag_rotation.apply(world.lever_arm)
        low = on_ground_weight(body[:, 2], self.height, self.fade)
        for anchor, meters in self.meters.items():
            tdoa.value += meters * low * _anchor_sign(tdoa, anchor)


class LearnedBias(Effect):
    """The pose-dependent TDOA bias that the bias network (paper Section III,
    `rig train`) learned from the shared flights, times `gain`: the network's
    prediction at the tag's true pose and the anchors' true poses. It stands for the
    bias of the antennas' patterns, of the airframe and of the room that the catalog's
    per-anchor effects do not carry, in a form that transfers to any trajectory.
    `network` is a `rig train` output (default: the shipped one)."""

    name, stage = "learned_bias", SIGNAL

    def __init__(self, gain: float = 1.0, network: str | None = None):
        path = Path(network) if network else DEFAULT_NETWORK
        if not path.is_file():
            raise ValueError(f"no bias network at {path} (write one with `rig train --out`)")
        self.gain, self.network, self.net = _finite(gain, "gain"), network, BiasNet.load(path)

    def params(self) -> dict:
        return {"gain": self.gain, **({"network": self.network} if self.network else {})}

    def bias(self, tdoa: TdoaBatch, world: World) -> np.ndarray:
        """The network's prediction for each sample (0 where an anchor is unknown)."""
        out = np.zeros(len(tdoa.t))
        known = np.flatnonzero(world.known_pairs(tdoa.id_a, tdoa.id_b))
        if not len(known):
            return out
        poses = [world.anchor_poses(ids[known]) for ids in (tdoa.id_a, tdoa.id_b)]
        features = native.features_batch(tdoa.tag_position[known], tdoa.tag_rotation[known].as_matrix(),
                                          *poses[0], *poses[1])
        out[known] = self.net.predict(features)
        return out

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        tdoa.value += self.gain * self.bias(tdoa, world)


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (ImuAccelBias, ImuGyroBias, ImuAccelScale, ImuGyroScale, ImuVibrationRectification,
                              ImuNoise, ImuVibration, ImuResonance, ImuLowpass, TdoaNoise, Outliers,
                              TimeOffset, ClockDrift, AnchorPosition, LeverArm, AnchorDelay, AntennaPattern,
                              TagAntennaPattern, Nlos, MultipathFloor, OnGroundDelay, LearnedBias)
}


def make_effect(name: str, params: dict | None = None) -> Effect:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    try:
        return EFFECTS[name](**(params or {}))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"bad parameters for effect {name!r}: {exc}") from exc


def effects_from_json(items: list[dict], anchors: Iterable[int] | None = None) -> list[Effect]:
    """The effects listed as JSON; with the flight's `anchors` (ids), an effect on any
    other anchor is refused: it would change nothing, silently."""
    effects = [make_effect(item["effect"], item.get("params", {})) for item in items]
    if anchors is not None:
        known = sorted(set(anchors))
        for effect in effects:
            if getattr(effect, "anchor", None) is not None and effect.anchor not in known:
                raise ValueError(f"{effect.name}: anchor {effect.anchor} is not one of the flight's anchors {known}")
    return effects


def params_by_name(items: list[dict]) -> dict[str, dict]:
    """The parameters of effects listed as JSON, by effect name: for the effects a
    model has once (its noise, low-pass, resonance); of one per anchor, the last."""
    return {item["effect"]: item.get("params", {}) for item in items}
