"""The spectrum of an IMU's fast readings: whether the flight controller low-pass
filtered them before logging, at what corner, and the white noise that such a filter
turns into the recorded spread. The diagnosis writes them into its model
(`imu_noise` before the filter, `imu_lowpass`), so a simulation from the model has
the recording's noise spectrum: on a real log nearly all of it lies below 50 Hz, where
block means and a 100 Hz estimator do not average it away, while white noise of the
same size would put nine tenths of its power above."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import nnls
from scipy.signal import freqz, lfilter, welch

from rig import effects as fx
from rig.recording import Vec3Series

SLOW_S = 0.2                   # the flight's own motion: the running mean this long, taken out
FIT_FROM_HZ = 10.0             # fit the spectrum above what taking out the running mean dents
SEGMENT = 512                  # Welch segment (samples): about 2 Hz resolution at 1 kHz
CORNERS = 120                  # corner frequencies tried, log-spaced up to the highest a filter can have
NO_ROLL_OFF_SHARE = 0.8        # a best corner this close to the highest: the spectrum does not roll off
ROLL_OFF_GAIN = 4.0            # the filter must fit this many times better than a flat spectrum (log misfit)


def fast_part(series: Vec3Series) -> tuple[np.ndarray, float]:
    """A series' finite readings less their SLOW_S running mean (what the slow motion
    of a flight leaves: vibration and noise), and its sample rate."""
    ok = np.all(np.isfinite(series.xyz), axis=1)
    values = series.xyz[ok]
    if len(values) < 3:
        return np.zeros((0, 3)), 0.0
    rate = fx.sample_rate(series.t[ok])
    window = int(np.clip(SLOW_S * rate, 3, len(values)))
    return values - uniform_filter1d(values, window, axis=0, mode="nearest"), rate


@dataclass
class Spectrum:
    """Power spectral density of a series' fast part, per axis."""

    freq: np.ndarray               # Hz
    power: np.ndarray              # (3, len(freq)), unit² / Hz
    rate: float                    # samples per second


def spectrum(series: Vec3Series) -> Spectrum | None:
    """The fast part's spectrum (Welch); None when the series is too short for it."""
    fast, rate = fast_part(series)
    if len(fast) < 4 * SEGMENT:
        return None
    freq, power = welch(fast, fs=rate, nperseg=SEGMENT, axis=0)
    return Spectrum(freq, power.T, rate)


def fit_band(spec: Spectrum) -> np.ndarray:
    """The frequencies a corner is fitted over: from FIT_FROM_HZ to the highest corner
    a filter can have (effects.LOWPASS_MAX_SHARE of the sample rate)."""
    return (spec.freq >= FIT_FROM_HZ) & (spec.freq <= fx.LOWPASS_MAX_SHARE * spec.rate)


def share_above(freq: np.ndarray, power: np.ndarray, hz: float) -> float:
    """The share of the power (a density over evenly spaced `freq`) above `hz`."""
    return float(power[freq >= hz].sum() / power.sum())


def filter_power(corner_hz: float, rate: float, freq: np.ndarray) -> np.ndarray:
    """|H(f)|² of the low-pass `effects.ImuLowpass` applies (1 where it filters
    nothing)."""
    design = fx.lowpass_design(corner_hz, rate)
    if design is None:
        return np.ones(len(freq))
    return np.abs(freqz(*design, worN=freq, fs=rate)[1]) ** 2


def fit_corner(series: Vec3Series) -> float:
    """The corner of the low-pass the readings went through (Hz), or 0 when their
    spectrum does not roll off (the filter fits it no better than ROLL_OFF_GAIN times
    a flat one). Each axis is fitted as white noise through the filter plus a white
    floor (quantisation), in log power so every frequency counts alike; the axes share
    the corner (one filter in the firmware) and have their own levels.
    The shaking of a real airframe is not white before the filter (it peaks at 10–25 Hz
    on the flights that shook), so this is the effective corner of what was logged."""
    spec = spectrum(series)
    if spec is None:
        return 0.0
    top = fx.LOWPASS_MAX_SHARE * spec.rate
    band = fit_band(spec)
    freq, power = spec.freq[band], np.maximum(spec.power[:, band], 1e-30)
    if len(freq) < 8:
        return 0.0
    errors = [(_log_misfit(filter_power(corner, spec.rate, freq), power), corner)
              for corner in np.geomspace(FIT_FROM_HZ / 2, top, CORNERS)]
    misfit, best = min(errors)
    flat = _log_misfit(np.zeros(len(freq)), power)
    return 0.0 if best >= NO_ROLL_OFF_SHARE * top or misfit * ROLL_OFF_GAIN > flat else float(best)


def _log_misfit(shape: np.ndarray, power: np.ndarray) -> float:
    """Sum over the axes of the squared log error of the best non-negative level ×
    `shape` + floor, each fitted in relative terms."""
    total = 0.0
    for p in power:
        design = np.column_stack([shape / p, 1.0 / p])
        level = nnls(design, np.ones(len(p)))[0]
        total += float(np.sum(np.log(np.maximum(design @ level, 1e-12)) ** 2))
    return total


def noise_gain(corner_hz: float, rate: float) -> float:
    """Standard deviation of white noise after the low-pass, per unit before it (1
    without a filter)."""
    design = fx.lowpass_design(corner_hz, rate)
    if design is None:
        return 1.0
    impulse = np.zeros(int(20 * rate / corner_hz) + 16)
    impulse[0] = 1.0
    return float(np.sqrt(np.sum(lfilter(*design, impulse) ** 2)))
