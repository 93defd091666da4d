"""The spectrum of an IMU's fast readings: whether the flight controller low-pass
filtered them before logging, at what corner, whether the noise before the filter
peaks (the airframe's slow shaking) and where, and the noise that comes out of the
filter with the recorded spread (`vibration_spread`, `imu_noise_sizes`). The diagnosis writes them into its model
(`imu_noise` and `imu_resonance` before the filter, `imu_lowpass`), so a simulation from the model has
the recording's noise spectrum: on a real log nearly all of it lies below 50 Hz, where
block means and a 100 Hz estimator do not average it away, while white noise of the
same size would put nine tenths of its power above."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import nnls
from scipy.signal import freqz, welch

from rig.data.recording import Vec3Series
from rig.diagnosis.channels import GROSS_Z
from rig.diagnosis.robust import mad_scale
from rig.sim import effects as fx

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


def fit_band(spec: Spectrum, lowest_hz: float = FIT_FROM_HZ) -> np.ndarray:
    """The frequencies a corner is fitted over: from `lowest_hz` to the highest corner
    a filter can have (effects.LOWPASS_MAX_SHARE of the sample rate)."""
    return (spec.freq >= lowest_hz) & (spec.freq <= fx.LOWPASS_MAX_SHARE * spec.rate)


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
    return 0.0 if spec is None else _corner_of(spec)


def _corner_of(spec: Spectrum) -> float:
    """`fit_corner` on a series' spectrum."""
    top = fx.LOWPASS_MAX_SHARE * spec.rate
    freq, power = _band(spec, FIT_FROM_HZ)
    if len(freq) < 8:
        return 0.0
    errors = [(_log_misfit(filter_power(corner, spec.rate, freq), power), corner)
              for corner in np.geomspace(FIT_FROM_HZ / 2, top, CORNERS)]
    misfit, best = min(errors)
    flat = _log_misfit(np.zeros(len(freq)), power)
    return 0.0 if best >= NO_ROLL_OFF_SHARE * top or misfit * ROLL_OFF_GAIN > flat else float(best)


def _band(spec: Spectrum, lowest_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The spectrum's frequencies in `fit_band` and each axis's power there, floored
    above zero for the log fits."""
    band = fit_band(spec, lowest_hz)
    return spec.freq[band], np.maximum(spec.power[:, band], 1e-30)


def _log_misfit(shape: np.ndarray, power: np.ndarray) -> float:
    """Sum over the axes of the squared log error of the best non-negative level ×
    `shape` + floor, each fitted in relative terms."""
    return sum(_levels([shape, np.ones(len(shape))], p)[0] for p in power)


def noise_gain(corner_hz: float, rate: float) -> float:
    """Standard deviation of white noise after the low-pass, per unit before it (1
    without a filter)."""
    design = fx.lowpass_design(corner_hz, rate)
    if design is None:
        return 1.0
    return fx.filter_noise_gain(design, int(20 * rate / corner_hz))


# The slow shaking before the filter: a resonance (effects.ImuResonance) fitted to the
# spectrum from RESONANCE_FROM_HZ, where taking out the running mean dents it (the dent
# is part of the fitted shape), over a grid of frequencies and quality factors.
RESONANCE_FROM_HZ = 2.0
RESONANCE_HZ = np.geomspace(3.0, 40.0, 40)
RESONANCE_Q = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
RESONANCE_GAIN = 1.05          # the peak must fit this many times better than the filtered white noise alone
RESONANCE_MIN_DROP = 0.05      # and take this much off the squared log error per frequency and axis: a
                               # spectrum white noise fits to within its estimate's own scatter has no peak
CORNER_RAISE = 1.5             # how far a peak's flank may have pulled the corner's first fit down


@dataclass
class Resonance:
    """A peak in a sensor's noise before its low-pass."""

    hz: float
    q: float
    share: np.ndarray              # per axis, the peak's share of the noise power before the filter


def fit_noise(series: Vec3Series) -> tuple[float, Resonance | None]:
    """The low-pass corner (`fit_corner`) and the resonance (`fit_resonance`) of a
    series' noise, from one spectrum (0 and None for a series too short for one). A
    peak's flank above it reads to the corner's fit, which takes white noise before
    the filter, as a lower corner (a 7 Hz peak: 65 Hz for 80), so with a peak found
    the corner is fitted again beside it, then the peak again."""
    spec = spectrum(series)
    if spec is None:
        return 0.0, None
    corner = _corner_of(spec)
    peak = fit_resonance(spec, corner)
    if peak is None or corner == 0.0:
        return corner, peak
    corner = _corner_beside(spec, peak, corner)
    return corner, fit_resonance(spec, corner)


def _corner_beside(spec: Spectrum, peak: Resonance, first: float) -> float:
    """The corner, from the `first` fit up to CORNER_RAISE times it, that fits best
    with white noise and the peak before the filter. Not further: above the corner a
    real log falls faster than a second-order filter, and a free corner lets the
    peak's flank take the whole spectrum (300 Hz and more on the gyroscopes)."""
    freq, power = _band(spec, RESONANCE_FROM_HZ)
    shape = _peak_power(peak.hz, peak.q, spec.rate, freq)
    trials = []
    for corner in np.geomspace(first, CORNER_RAISE * first, CORNERS // 4):
        white = _logged_shape(corner, spec.rate, freq)
        trials.append((sum(_levels([white, white * shape, np.ones(len(freq))], p)[0] for p in power), corner))
    return float(min(trials)[1])


def fit_resonance(spec: Spectrum, corner_hz: float) -> Resonance | None:
    """The resonance that, with white noise, through the low-pass at `corner_hz`,
    fits a series' spectrum best in log power (the axes share it and have their own
    levels), or None when it fits no better than RESONANCE_GAIN times the white noise
    alone, or by less than RESONANCE_MIN_DROP (a white spectrum, fitted to within the
    Welch estimate's scatter), or takes no axis's power."""
    freq, power = _band(spec, RESONANCE_FROM_HZ)
    white = _logged_shape(corner_hz, spec.rate, freq)
    plain = _log_misfit(white, power)
    trials = []
    for hz in RESONANCE_HZ[RESONANCE_HZ < fx.LOWPASS_MAX_SHARE * spec.rate]:
        for q in RESONANCE_Q:
            peak = white * _peak_power(hz, q, spec.rate, freq)
            fits = [_levels([white, peak, np.ones(len(freq))], p) for p in power]
            trials.append((sum(misfit for misfit, _ in fits), hz, q, fits))
    misfit, hz, q, fits = min(trials, key=lambda trial: trial[0])
    # the fitted densities at the peak, as powers: white noise of the whole band, the peak's of its own
    white_power = np.array([level[0] for _, level in fits]) * spec.rate / 2
    peak_power = np.array([level[1] for _, level in fits]) * _peak_band(hz, q, spec.rate)
    share = peak_power / np.maximum(white_power + peak_power, 1e-30)
    if misfit * RESONANCE_GAIN > plain or plain - misfit < RESONANCE_MIN_DROP * power.size or not np.any(share > 0):
        return None
    return Resonance(float(hz), float(q), share)


def _levels(shapes: list[np.ndarray], power: np.ndarray) -> tuple[float, np.ndarray]:
    """The non-negative levels of `shapes` whose sum fits `power` best in relative
    terms, and the squared log error left."""
    design = np.column_stack([shape / power for shape in shapes])
    level = nnls(design, np.ones(len(power)))[0]
    return float(np.sum(np.log(np.maximum(design @ level, 1e-12)) ** 2)), level


def _logged_shape(corner_hz: float, rate: float, freq: np.ndarray) -> np.ndarray:
    """What a log's fast part shows of a flat density before the low-pass at
    `corner_hz`: the filter's |H(f)|² and the running mean's dent."""
    return filter_power(corner_hz, rate, freq) * _running_mean_dent(freq, rate)


def _running_mean_dent(freq: np.ndarray, rate: float) -> np.ndarray:
    """|1 − the SLOW_S running mean's response|²: what `fast_part` keeps of each frequency."""
    n = max(3, int(SLOW_S * rate))
    mean = np.sinc(freq * n / rate) / np.sinc(freq / rate)
    return (1.0 - mean) ** 2


def _peak_band(hz: float, q: float, rate: float) -> float:
    """The peak's noise bandwidth (Hz): the white density that, over it, has the power
    of the peak's output."""
    return fx.resonance_gain(hz, q, rate) ** 2 * rate / 2


def model_density(freq: np.ndarray, rate: float, model: dict, sensor: str) -> np.ndarray:
    """The one-sided density of a model's IMU noise (`imu_noise`, `imu_resonance`,
    `imu_lowpass` of a model.json), mean over the axes, as the fast part of a log
    shows it (`fast_part`, whose running mean dents it below a few Hz)."""
    white = np.mean(np.square(model["imu_noise"][f"{sensor}_std"]))
    density = np.full(len(freq), 2 * white / rate)
    peak = model.get("imu_resonance", {})
    hz, q = peak.get(f"{sensor}_hz", 0.0), peak.get(f"{sensor}_q", 1.0)
    if fx.resonance_design(hz, q, rate) is not None:
        resonant = np.mean(np.square(peak[f"{sensor}_std"])) / fx.resonance_gain(hz, q, rate) ** 2
        density += 2 * resonant / rate * _peak_power(hz, q, rate, freq)
    corner = model.get("imu_lowpass", {}).get(f"{sensor}_hz", 0.0)
    return density * _logged_shape(corner, rate, freq)


def _peak_power(hz: float, q: float, rate: float, freq: np.ndarray) -> np.ndarray:
    return np.abs(freqz(*fx.resonance_design(hz, q, rate), worN=freq, fs=rate)[1]) ** 2


def logged_noise(rng: np.random.Generator, t: np.ndarray, corner_hz: float, white_std,
                 resonance: Resonance | None = None, resonant_std=None) -> np.ndarray:
    """The model's IMU noise as a log at stamps `t` shows it: white noise of
    `white_std` plus the resonance's of `resonant_std` (per axis), through the
    low-pass at `corner_hz` (effects.ImuNoise, ImuResonance and ImuLowpass)."""
    rate = fx.sample_rate(t)
    noise = rng.normal(0.0, 1.0, (len(t), 3)) * white_std
    if resonance is not None:
        noise += fx.resonant_noise(rng, len(t), rate, resonance.hz, resonance.q) * resonant_std
    return fx.lowpass(t, noise, corner_hz)


def means_spread(values: np.ndarray, rate: float, seconds: float) -> np.ndarray:
    """Per axis, the spread of the means of `values` (samples at `rate`) over
    consecutive `seconds`: what an estimator stepping that often takes in of them."""
    n = max(1, int(round(seconds * rate)))
    return values[: len(values) // n * n].reshape(-1, n, values.shape[1]).mean(axis=1).std(axis=0)


def chain_spread(rate: float, seconds: float, corner_hz: float, white_std: np.ndarray,
                 resonance: Resonance | None = None, resonant_std: np.ndarray | None = None) -> np.ndarray:
    """Per axis, the RMS of the fast part of `logged_noise`, as `seconds` of a log at
    `rate` would show it (drawn with a fixed seed)."""
    t = np.arange(max(int(seconds * rate), 4 * SEGMENT)) / rate
    noise = logged_noise(np.random.default_rng(0), t, corner_hz, white_std, resonance, resonant_std)
    fast, _ = fast_part(Vec3Series(t, noise))
    return np.sqrt(np.mean(fast ** 2, axis=0))


def imu_noise_sizes(series: Vec3Series, corner_hz: float,
                    peak: Resonance | None) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the white and the resonant noise before the low-pass that come out
    of it with the recorded spread (`vibration_spread`), in the proportion the
    spectrum's fit gives."""
    own, rate = vibration_spread(series), fx.sample_rate(series.t)
    if peak is None:
        return own / noise_gain(corner_hz, rate), np.zeros(3)
    white, resonant = np.sqrt(1.0 - peak.share), np.sqrt(peak.share)
    seconds = float(series.t[-1] - series.t[0])
    scale = own / np.maximum(chain_spread(rate, seconds, corner_hz, white, peak, resonant), 1e-12)
    return white * scale, resonant * scale


def vibration_spread(series: Vec3Series) -> np.ndarray:
    """RMS of an IMU series around its own running mean, per axis: what the slow
    motion of a flight leaves out. Readings GROSS_Z robust deviations out are glitches
    and left out, as in the comparison. Not the robust spread itself: the shaking
    comes and goes and its tails are heavy, and noise of the robust spread's size gave
    a 100 Hz estimator's 10 ms means 0.6–0.7 of the recorded accelerometer spread and
    0.3–0.5 of the gyroscope's (the RMS: 0.96–0.99 and 0.6–0.85). Per axis: the
    airframe shakes along some axes several times more than along others."""
    fast, _ = fast_part(series)
    if len(fast) < 3:
        return np.zeros(3)
    rms = []
    for values in fast.T:
        kept = values[np.abs(values - np.median(values)) <= GROSS_Z * max(mad_scale(values), 1e-12)]
        rms.append(np.sqrt(np.mean((kept - np.median(values)) ** 2)) if len(kept) else 0.0)
    return np.array(rms)
