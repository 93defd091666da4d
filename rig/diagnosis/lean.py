"""The airframe's lean into its motion against the ground truth's attitude, as each IMU
sensor measures it on its own: the catalog's `attitude_lean` (c rad per m/s of body
velocity, x and y), which the diagnosis does not fit (docs/notebook/diagnosis-experiments.md,
session 75) but reports beside an accelerometer scale it explains.

Over the longest stretch in the air (0.5 m above the flight's lowest point, 3 s cut at
each end): the gyroscope's rates and the ground truth's, each integrated, a slow cubic
trend taken out (the gyroscope's bias), their difference regressed on the body velocity
(about body y for x, about −x for y); and the accelerometer's excess over the truth's
specific force regressed on −g·v. A lean shows alike in both. What only the
accelerometer shows is not a lean. Slopes only: the integrated rates' error is slow,
so a regression's standard error would not mean much."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.data.recording import Recording
from rig.sim.trajectory import GRAVITY, RecordedTrajectory

AIRBORNE_M = 0.5         # above the flight's lowest point
CUT_S = 3.0              # left out at each end of the time in the air (take-off, landing)
GAP_S = 0.1              # a longer gap between IMU samples ends a stretch
MIN_STRETCH_S = 10.0     # shorter: no lean measured
DECIMATE = 5             # of a 1 kHz IMU: the lean is slow


@dataclass
class Lean:
    """c (rad per m/s) on x and y, as each sensor reads it against the ground truth."""

    gyroscope: np.ndarray
    accelerometer: np.ndarray

    def to_json(self) -> dict:
        return {"gyroscope_rad_per_mps": np.round(self.gyroscope, 5).tolist(),
                "accelerometer_rad_per_mps": np.round(self.accelerometer, 5).tolist()}


def measure_lean(rec: Recording, truth: RecordedTrajectory) -> Lean | None:
    """The lean by each sensor; None without both IMU streams or MIN_STRETCH_S in the air."""
    t = rec.gyro.t
    if not len(t) or not len(rec.accel.t):
        return None
    lowest = np.nanpercentile(rec.truth.position[:, 2], 1)
    air = ((t > truth.t_start + CUT_S) & (t < truth.t_end - CUT_S)
           & (truth.position(t)[:, 2] > lowest + AIRBORNE_M) & np.all(np.isfinite(rec.gyro.xyz), axis=1))
    run = np.flatnonzero(air)[longest_stretch(t[air])][::DECIMATE]
    if len(run) < 10 or t[run[-1]] - t[run[0]] < MIN_STRETCH_S:
        return None
    t, gyro = t[run], rec.gyro.xyz[run]
    finite = np.all(np.isfinite(rec.accel.xyz), axis=1)
    if finite.sum() < 2:
        return None
    accel = np.column_stack([np.interp(t, rec.accel.t[finite], rec.accel.xyz[finite, i]) for i in range(3)])
    turned = integrated(t, gyro) - integrated(t, truth.angular_rate(t))
    excess = accel - truth.specific_force(t)
    velocity = truth.body_velocity(t)
    s = (t - t[0]) / (t[-1] - t[0])
    trend = np.column_stack([np.ones_like(s), s, s ** 2, s ** 3])
    by_gyro, by_accel = np.zeros(2), np.zeros(2)
    for k, (about, sign) in enumerate(((1, 1.0), (0, -1.0))):
        design = np.column_stack([velocity[:, k], trend])
        by_gyro[k] = np.linalg.lstsq(design, sign * turned[:, about], rcond=None)[0][0]
        by_accel[k] = -np.linalg.lstsq(design, excess[:, k] / GRAVITY, rcond=None)[0][0]
    return Lean(by_gyro, by_accel)


def longest_stretch(t: np.ndarray, gap_s: float = GAP_S) -> np.ndarray:
    """The indices of the longest run of samples without a gap longer than `gap_s`."""
    if not len(t):
        return np.arange(0)
    runs = np.split(np.arange(len(t)), np.flatnonzero(np.diff(t) > gap_s) + 1)
    return max(runs, key=len)


def integrated(t: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """The angle each rate turns through from the first sample (trapezoids)."""
    steps = (rates[1:] + rates[:-1]) / 2 * np.diff(t)[:, None]
    return np.vstack([np.zeros(rates.shape[1]), np.cumsum(steps, axis=0)])
