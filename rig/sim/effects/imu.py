"""IMU effects: the airframe's lean into its motion, biases, scale factors, vibration
rectification, noise (white, vibration, the airframe's resonance) and the flight
controller's low-pass before logging."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import butter, iirpeak, lfilter, lfilter_zi
from scipy.spatial.transform import Rotation

from rig.sim.effects.base import (
    FILTERED,
    NOISE,
    RECTIFIED,
    SCALE,
    SIGNAL,
    WORLD,
    Effect,
    ImuBatch,
    _finite,
    _non_negative,
    _positive,
    _vec3,
    _Windowed,
    staged,
)

VIBRATION_HIGHPASS_S = 0.02    # vibration: the accelerometer less its running mean this long ...
VIBRATION_RMS_S = 0.2          # ... as a running RMS this long


class _ImuVectorEffect(_Windowed, Effect):
    """One vector parameter acting on one IMU stream (body frame)."""

    stream: ClassVar[str] = ""   # "accel" or "gyro"
    param: ClassVar[str] = ""    # the catalog's parameter name

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


# A MEMS sensor's scale is within about 10 % of nominal: the Crazyflie's MPU-9250 gives
# ±3 % tolerance, ±4 % over temperature (gyroscope) and ±2 % cross-axis. The bound adds
# half again for the fit's own error; a larger fit stands for something else (on the
# real flights, rotor drag read more strongly than the ground truth's: benchmarks/accel_drag.py).
SCALE_BOUND = 0.15


class ImuAccelScale(_ImuScale):
    """Accelerometer scale factors."""

    name, stream, bounds = "imu_accel_scale", "accel", {"scale": SCALE_BOUND}


class ImuGyroScale(_ImuScale):
    """Gyroscope scale factors."""

    name, stream, bounds = "imu_gyro_scale", "gyro", {"scale": SCALE_BOUND}


# The lean is a share of the tilt rotor drag asks for at speed v, k·v/g: at most all of
# it, with k ≤ 0.5 /s for a Crazyflie-class airframe (the ground truth's own k is
# 0.33–0.39 /s on the 0426 flights: benchmarks/accel_drag.py).
LEAN_BOUND = 0.05


class AttitudeLean(Effect):
    """The airframe leans into its horizontal motion by `rad_per_mps` × its body velocity
    (x, y) more than the ground truth's attitude shows: about body y by c_x·v_x, about
    body x by −c_y·v_y, each axis tilting body z towards the motion. Both IMU sensors
    feel the lean: the accelerometer reads g·c·v more drag on each axis, the gyroscope
    the lean's rate. On the real flights both sensors show it alike, against the
    motion capture's attitude (benchmarks/accel_drag.py); which of the two attitudes
    carries it is not identified. Needs the batch's body velocity (ImuBatch.velocity).
    Simulator only: fitted by the diagnosis it cost concealed cases, and was not kept
    (docs/notebook/diagnosis-experiments.md, session 75)."""

    name, stage, bounds = "attitude_lean", WORLD, {"rad_per_mps": LEAN_BOUND}

    def __init__(self, rad_per_mps=(0.0, 0.0)):
        value = np.asarray(rad_per_mps, float)
        if value.shape != (2,) or not np.all(np.isfinite(value)):
            raise ValueError(f"rad_per_mps must be two finite numbers (x, y), got {rad_per_mps!r}")
        self.value = value

    def params(self) -> dict:
        return {"rad_per_mps": self.value.tolist()}

    def lean(self, velocity: np.ndarray) -> np.ndarray:
        """The lean as a rotation vector in the body frame, per sample."""
        cx, cy = self.value
        return np.column_stack([-cy * velocity[:, 1], cx * velocity[:, 0], np.zeros(len(velocity))])

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator | None) -> None:
        if imu.velocity is None or imu.velocity_rate is None:
            raise ValueError("attitude_lean needs the body velocity of the IMU's samples (a batch from a trajectory)")
        imu.accel[:] = Rotation.from_rotvec(self.lean(imu.velocity)).inv().apply(imu.accel)
        imu.gyro += self.lean(imu.velocity_rate)


class ImuAccelBias(_ImuConstantBias):
    """Accelerometer bias (m/s²)."""

    name, stream, param, bounds = "imu_accel_bias", "accel", "bias_mps2", {"bias_mps2": 6.0}


class ImuGyroBias(_ImuConstantBias):
    """Gyroscope bias (rad/s)."""

    name, stream, param, bounds = "imu_gyro_bias", "gyro", "bias_rps", {"bias_rps": 0.5}


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
    bounds = {"gain": 20.0}

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
