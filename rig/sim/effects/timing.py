"""Timing effects: the UWB timestamps against the IMU and ground-truth clock."""

from __future__ import annotations

import numpy as np

from rig.sim.effects.base import TIMING, Effect, TdoaBatch, World, _finite


class _UwbClock(Effect):
    """A timing effect: moves the UWB stamps by `stamp`."""

    stage = TIMING

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        tdoa.t = self.stamp(tdoa.t)


class TimeOffset(_UwbClock):
    """UWB timestamps are late by `seconds` relative to the IMU and ground-truth clock."""

    name, bounds = "time_offset", {"seconds": 0.5}

    def __init__(self, seconds: float = 0.0):
        self.seconds = _finite(seconds, "seconds")

    def params(self) -> dict:
        return {"seconds": self.seconds}

    def stamp(self, t: np.ndarray) -> np.ndarray:
        return t + self.seconds


class ClockDrift(_UwbClock):
    """The UWB timestamps run fast by `ppm` relative to the IMU clock (zero at t = 0 of
    the recording's clock)."""

    name, bounds = "clock_drift", {"ppm": 20000.0}

    def __init__(self, ppm: float = 0.0):
        self.ppm = _finite(ppm, "ppm")

    def params(self) -> dict:
        return {"ppm": self.ppm}

    def stamp(self, t: np.ndarray) -> np.ndarray:
        return t * (1.0 + self.ppm * 1e-6)
