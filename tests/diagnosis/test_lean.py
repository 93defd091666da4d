"""The airframe's lean as each IMU sensor measures it against the ground truth
(rig.diagnosis.lean): a simulated lean is read alike by both, an upright flight reads
none, and a flight too short in the air is not measured."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import simulate_exact

from rig.diagnosis.lean import measure_lean
from rig.sim.trajectory import RecordedTrajectory


def _lean_of(rec):
    return measure_lean(rec, RecordedTrajectory(rec.truth))


@pytest.mark.parametrize("lean", [[0.0, 0.0], [0.01, -0.006]])
def test_both_sensors_read_the_simulated_lean(survey_0425: Path, lean: list[float]) -> None:
    rec = simulate_exact(survey_0425, "circle", [{"effect": "attitude_lean", "params": {"rad_per_mps": lean}}],
                         duration=40.0)
    measured = _lean_of(rec)
    np.testing.assert_allclose(measured.gyroscope, lean, atol=5e-4)
    np.testing.assert_allclose(measured.accelerometer, lean, atol=5e-4)
    assert set(measured.to_json()) == {"gyroscope_rad_per_mps", "accelerometer_rad_per_mps"}


def test_a_flight_too_short_in_the_air_is_not_measured(survey_0425: Path) -> None:
    rec = simulate_exact(survey_0425, "circle", duration=40.0)
    short = replace(rec, gyro=replace(rec.gyro, t=rec.gyro.t[:2000], xyz=rec.gyro.xyz[:2000]))
    assert _lean_of(short) is None


def test_lost_readings_are_flown_through(survey_0425: Path) -> None:
    """An accelerometer reading that is not finite (a corrupt log row) and a lost motion
    capture pose leave the lean measured on the rest."""
    rec = simulate_exact(survey_0425, "circle", [{"effect": "attitude_lean", "params": {"rad_per_mps": [0.01, 0.0]}}],
                         duration=40.0)
    accel = rec.accel.xyz.copy()
    accel[5000] = np.nan
    position = rec.truth.position.copy()
    position[100] = np.nan
    damaged = replace(rec, accel=replace(rec.accel, xyz=accel), truth=replace(rec.truth, position=position))
    np.testing.assert_allclose(_lean_of(damaged).accelerometer, [0.01, 0.0], atol=5e-4)
