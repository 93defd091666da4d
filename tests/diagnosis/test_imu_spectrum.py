"""The IMU's noise spectrum: the low-pass the flight controller runs on the readings
before logging them (effects.ImuLowpass), found again from the readings alone
(imu_spectrum.fit_corner), with the white noise it turns into the recorded spread, and
the peak the airframe's slow shaking puts before it (effects.ImuResonance,
imu_spectrum.fit_noise)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.data.recording import Vec3Series
from rig.diagnosis import imu_spectrum
from rig.sim.effects import ImuBatch, lowpass, make_effect

pytestmark = pytest.mark.slow        # left out of `make test-fast`

RATE = 1000.0
T = np.arange(0.0, 40.0, 1.0 / RATE)


def white(std: float = 0.5, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, std, (len(T), 3))


def test_the_lowpass_passes_the_motion_and_takes_the_noise_above_its_corner() -> None:
    """A 1 Hz manoeuvre passes whole; a 120 Hz tone loses a second-order filter's
    (30/120)² (to 6 %); white noise keeps its share below the corner (about a quarter
    of its spread at 30 Hz of 500). Both streams are filtered, each at its corner."""
    slow, tone = np.sin(2 * np.pi * 1.0 * T), np.sin(2 * np.pi * 120.0 * T)
    imu = ImuBatch(T, np.column_stack([slow, tone, white()[:, 0]]), np.column_stack([tone, tone, tone]))
    make_effect("imu_lowpass", {"accel_hz": 30.0, "gyro_hz": 240.0}).apply_imu(imu, None)
    settled = T > 1.0
    gain = imu.accel[settled].std(axis=0) / np.array([slow, tone, white()[:, 0]]).T[settled].std(axis=0)
    assert gain[0] == pytest.approx(1.0, abs=0.01)
    assert gain[1] == pytest.approx(1 / np.hypot(1, 4 ** 2), rel=0.1)
    assert gain[2] == pytest.approx(imu_spectrum.noise_gain(30.0, RATE), rel=0.03)
    assert 0.2 < gain[2] < 0.3
    assert imu.gyro[settled].std() == pytest.approx(np.sqrt(0.5) / np.hypot(1, 0.5 ** 2), rel=0.05)


def test_the_lowpass_starts_settled_and_skips_bad_readings() -> None:
    """No start-up transient (a reading held from the start stays put); a reading that
    is not a number stays as it is and does not spread into the rest; a corner at or
    above 0.45 × the sample rate, or 0, leaves the readings as they are."""
    held = np.tile([0.1, -0.2, 9.81], (len(T), 1))
    np.testing.assert_allclose(lowpass(T, held, 30.0), held, rtol=1e-12)
    broken = white()
    broken[500] = np.nan
    out = lowpass(T, broken, 30.0)
    assert np.isnan(out[500]).all() and np.isfinite(np.delete(out, 500, axis=0)).all()
    for corner in (0.0, 450.0, 2000.0):
        assert lowpass(T, broken, corner) is broken


def test_a_negative_or_non_finite_corner_is_refused() -> None:
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="corner frequency"):
            make_effect("imu_lowpass", {"accel_hz": bad})


@pytest.mark.parametrize("corner", [20.0, 30.0, 80.0, 200.0])
def test_the_corner_of_filtered_noise_is_found(corner: float) -> None:
    readings = Vec3Series(T, lowpass(T, white() * [1.0, 0.3, 2.0], corner))
    assert imu_spectrum.fit_corner(readings) == pytest.approx(corner, rel=0.08)


def test_white_noise_has_no_corner_and_a_short_series_is_not_fitted() -> None:
    assert imu_spectrum.fit_corner(Vec3Series(T, white())) == 0.0
    assert imu_spectrum.fit_corner(Vec3Series(T[:1000], white()[:1000])) == 0.0
    assert imu_spectrum.noise_gain(0.0, RATE) == 1.0


def test_resonant_noise_has_its_size_per_axis_and_its_power_at_the_peak() -> None:
    """imu_resonance: noise of the given standard deviation on each axis, nearly all
    of its power within a few bandwidths (hz / q) of the peak; nothing on a sensor
    whose frequency is 0. Bad frequencies and quality factors are refused."""
    imu = ImuBatch(T, np.zeros((len(T), 3)), np.zeros((len(T), 3)))
    make_effect("imu_resonance", {"gyro_std": [0.1, 0.05, 0.0], "gyro_hz": 8.0, "gyro_q": 3.0}).apply_imu(
        imu, np.random.default_rng(0))
    assert imu.gyro.std(axis=0) == pytest.approx([0.1, 0.05, 0.0], rel=0.05, abs=1e-12)
    assert np.all(imu.accel == 0.0)
    spec = imu_spectrum.spectrum(Vec3Series(T, imu.gyro))
    near = (spec.freq > 4.0) & (spec.freq < 16.0)
    assert spec.power[0, near].sum() / spec.power[0].sum() > 0.8
    for bad in ({"gyro_hz": -1.0}, {"gyro_q": 0.0}, {"accel_std": [1.0, 2.0]}):
        with pytest.raises(ValueError):
            make_effect("imu_resonance", bad)


@pytest.mark.parametrize("hz", [5.0, 10.0])
def test_a_peak_before_the_filter_is_found_with_the_filters_corner(hz: float) -> None:
    """White noise and a peak on x and y, through a 30 Hz low-pass: the peak is found
    within 10 % with its share of each axis's power within 0.15 (none on z), and the corner within
    10 %, which the peak's flank alone would pull down."""
    imu = ImuBatch(T, white(0.5), np.zeros((len(T), 3)))
    make_effect("imu_resonance", {"accel_std": [1.0, 0.5, 0.0], "accel_hz": hz, "accel_q": 2.0}).apply_imu(
        imu, np.random.default_rng(1))
    logged = Vec3Series(T, lowpass(T, imu.accel, 30.0))
    corner, peak = imu_spectrum.fit_noise(logged)
    assert corner == pytest.approx(30.0, rel=0.1)
    assert peak is not None and peak.hz == pytest.approx(hz, rel=0.1)
    assert peak.share == pytest.approx([1.0 / 1.25, 0.25 / 0.5, 0.0], abs=0.15)


def test_white_noise_has_no_peak() -> None:
    """White noise through a low-pass fits without a peak (its spectrum is within the
    Welch estimate's scatter of the filter's shape)."""
    logged = Vec3Series(T, lowpass(T, white(0.5), 30.0))
    assert imu_spectrum.fit_noise(logged)[1] is None
