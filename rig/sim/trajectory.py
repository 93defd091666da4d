"""Trajectories the simulator flies: parametric ones and a recording's own ground truth.

A trajectory gives position p(t) and attitude R(t) (body→world); the acceleration
and the body-frame angular rate follow by differentiation. Parametric
trajectories take off from the floor, fly a pattern and land, all C²-smooth so that
the specific force is continuous; their attitude is a quadrotor's: body z along the
thrust direction a + g·e_z, with a prescribed yaw.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.spatial.transform import Rotation, RotationSpline

from rig.data.recording import PoseSeries

log = logging.getLogger(__name__)

GRAVITY = 9.81
RAMP = 2.0  # s over which a pattern speeds up after take-off and slows down before landing
_H = 1e-3  # step of the central differences (s)
# Motion-capture attitude is averaged over this long (s) before it is differentiated:
# see RecordedTrajectory. A comparison with the gyroscope averages it over as long.
ATTITUDE_WINDOW_S = 0.2
AIRBORNE_M = 0.05  # a recorded flight is airborne (motors running) this high above its lowest point


class Trajectory:
    """Base class: subclasses give `position` and `rotation`; derivatives are numeric."""

    t_start: float = 0.0
    t_end: float = 0.0

    def position(self, t: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        return (self.position(t + _H) - 2 * self.position(t) + self.position(t - _H)) / _H**2

    def rotation(self, t: np.ndarray) -> Rotation:
        raise NotImplementedError

    def angular_rate(self, t: np.ndarray) -> np.ndarray:
        """Body-frame angular rate: log(R(t-h)ᵀ R(t+h)) / 2h."""
        t = np.asarray(t, float)
        return (self.rotation(t - _H).inv() * self.rotation(t + _H)).as_rotvec() / (2 * _H)

    def body_velocity(self, t: np.ndarray) -> np.ndarray:
        """Velocity in the body frame: Rᵀ dp/dt."""
        t = np.asarray(t, float)
        return self.rotation(t).inv().apply((self.position(t + _H) - self.position(t - _H)) / (2 * _H))

    def body_velocity_rate(self, t: np.ndarray) -> np.ndarray:
        """d/dt of the body-frame velocity (what a lean that follows it turns at)."""
        t = np.asarray(t, float)
        return (self.body_velocity(t + _H) - self.body_velocity(t - _H)) / (2 * _H)

    def specific_force(self, t: np.ndarray) -> np.ndarray:
        """What an ideal accelerometer reads: Rᵀ (a − g), g = (0, 0, −9.81)."""
        force_world = self.acceleration(t) + np.array([0.0, 0.0, GRAVITY])
        return self.rotation(t).inv().apply(force_world)

    def motors_on(self, t: np.ndarray) -> np.ndarray:
        """Whether the motors run at each time (a base trajectory flies all along)."""
        return np.ones(np.shape(t), bool)

    def rotor_speed(self, t: np.ndarray, force: np.ndarray | None = None) -> np.ndarray:
        """The rotors' speed relative to hover, 0 with the motors stopped: thrust goes
        as the speed squared and equals the mass times the specific force's norm."""
        force = self.specific_force(t) if force is None else force
        return np.where(self.motors_on(t), np.sqrt(np.linalg.norm(force, axis=-1) / GRAVITY), 0.0)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """Septic smoothstep 0→1 with zero 1st–3rd derivatives at both ends (C³)."""
    x = np.clip(x, 0.0, 1.0)
    return x**4 * (35 - 84 * x + 70 * x**2 - 20 * x**3)


def _smoothstep_integral(x: np.ndarray) -> np.ndarray:
    """∫₀ˣ smoothstep: a polynomial on [0, 1], then x − 1/2; zero for x ≤ 0."""
    x = np.asarray(x, float)
    inner = np.clip(x, 0.0, 1.0)
    poly = inner**5 * (7 - 14 * inner + 10 * inner**2 - 2.5 * inner**3)
    return np.where(x > 1.0, x - 0.5, poly)


def _thrust_attitude(accel: np.ndarray, yaw: np.ndarray) -> Rotation:
    z_b = accel + np.array([0.0, 0.0, GRAVITY])
    z_b /= np.linalg.norm(z_b, axis=-1, keepdims=True)
    x_c = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=-1)
    y_b = np.cross(z_b, x_c)
    y_b /= np.linalg.norm(y_b, axis=-1, keepdims=True)
    x_b = np.cross(y_b, z_b)
    return Rotation.from_matrix(np.stack([x_b, y_b, z_b], axis=-1))


@dataclass
class FlightPlan:
    """Timing of a parametric flight: on the ground, climb, pattern, descent, on the ground."""

    ground_before: float = 2.0
    climb: float = 3.0
    pattern: float = 30.0
    descent: float = 3.0
    ground_after: float = 1.0
    floor_z: float = 0.03

    @property
    def duration(self) -> float:
        return self.ground_before + self.climb + self.pattern + self.descent + self.ground_after


class PatternTrajectory(Trajectory):
    """Take off, fly `pattern(t)` (a smooth function of time), land where it ends.

    Position blends the floor spot under the pattern's start (end) with the pattern
    through a smoothstep, so the flight is smooth from the first to the last sample.
    """

    def __init__(self, plan: FlightPlan, yaw_rate: float = 0.0, yaw_amplitude: float = 0.0, yaw_omega: float = 1.0):
        self.plan = plan
        self.yaw_rate = yaw_rate
        self.yaw_amplitude, self.yaw_omega = yaw_amplitude, yaw_omega   # a yaw swing excites the gyro
        self.t_start = 0.0
        self.t_end = plan.duration
        self._t_on = plan.ground_before + plan.climb  # pattern phase starts here
        self._t_off = self._t_on + plan.pattern

    def pattern(self, tau: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _blend(self, t: np.ndarray) -> np.ndarray:
        up = _smoothstep((t - self.plan.ground_before) / self.plan.climb)
        down = _smoothstep((self._t_off + self.plan.descent - t) / self.plan.descent)
        return np.minimum(up, down)

    def _warp(self, tau: np.ndarray) -> np.ndarray:
        """Pattern time that starts and ends at rest: its rate ramps 0→1 over `RAMP`
        seconds after take-off and 1→0 before landing (integrals of the smoothstep)."""
        r, total = min(RAMP, self.plan.pattern / 2), self.plan.pattern
        return r * _smoothstep_integral(tau / r) - r * _smoothstep_integral((total - tau) / r) - tau + total - r / 2

    def position(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        tau = np.clip(t - self._t_on, 0.0, self.plan.pattern)  # the pattern holds still outside
        target = self.pattern(self._warp(tau))
        floor = target.copy()
        floor[..., 2] = self.plan.floor_z
        s = self._blend(t)[..., None]
        return floor + s * (target - floor)

    def motors_on(self, t: np.ndarray) -> np.ndarray:
        """From take-off to touch-down."""
        t = np.asarray(t, float)
        return (t > self.plan.ground_before) & (t < self._t_off + self.plan.descent)

    def rotation(self, t: np.ndarray) -> Rotation:
        t = np.asarray(t, float)
        yaw = self.yaw_rate * (t - self.t_start)
        if self.yaw_amplitude:
            yaw = yaw + self.yaw_amplitude * np.sin(self.yaw_omega * (t - self.t_start))
        return _thrust_attitude(self.acceleration(t), yaw)


class CircleTrajectory(PatternTrajectory):
    """Circle of `radius` around `center` at angular rate `omega`, optional vertical sine."""

    def __init__(self, plan: FlightPlan, radius: float = 1.5, omega: float = 0.6, height: float = 1.5,
                 center: tuple[float, float] = (0.0, 0.0), z_amplitude: float = 0.0, z_omega: float = 0.0,
                 yaw_rate: float = 0.0, yaw_amplitude: float = 0.0, yaw_omega: float = 1.0):
        super().__init__(plan, yaw_rate, yaw_amplitude, yaw_omega)
        self.radius, self.omega, self.height = radius, omega, height
        self.center = np.asarray(center, float)
        self.z_amplitude, self.z_omega = z_amplitude, z_omega

    def pattern(self, tau: np.ndarray) -> np.ndarray:
        phase = self.omega * tau
        zr = self.z_amplitude * np.sin(self.z_omega * tau)
        return np.stack([
            self.center[0] + self.radius * np.cos(phase),
            self.center[1] + self.radius * np.sin(phase),
            self.height + zr,
        ], axis=-1)


class SmoothRandomTrajectory(PatternTrajectory):
    """A sum of random sinusoids per axis inside a box: smooth, seeded, covers space."""

    def __init__(self, plan: FlightPlan, seed: int = 0, box_min=(-2.0, -2.0, 0.8), box_max=(2.0, 2.0, 2.2),
                 components: int = 4, max_omega: float = 0.8, yaw_rate: float = 0.0, yaw_amplitude: float = 0.0,
                 yaw_omega: float = 1.0):
        super().__init__(plan, yaw_rate, yaw_amplitude, yaw_omega)
        rng = np.random.default_rng(seed)
        self.lo, self.hi = np.asarray(box_min, float), np.asarray(box_max, float)
        self.omegas = rng.uniform(0.1, max_omega, size=(components, 3))
        self.phases = rng.uniform(0, 2 * np.pi, size=(components, 3))
        self.amps = rng.uniform(0.5, 1.0, size=(components, 3))
        self.amps /= self.amps.sum(axis=0)

    def pattern(self, tau: np.ndarray) -> np.ndarray:
        tau = np.asarray(tau, float)[..., None, None]
        wave = np.sum(self.amps * np.sin(self.omegas * tau + self.phases), axis=-2)  # in [-1, 1]
        return self.lo + (self.hi - self.lo) * (wave + 1) / 2


class RecordedTrajectory(Trajectory):
    """A recording's ground truth made smooth: smoothing splines on position,
    a rotation spline on attitude averaged over short windows.

    `smoothing` is the spline's penalty weight (s⁴·m⁻² scale); the GCV choice
    follows the motion-capture noise and makes accelerations far too rough.
    Motion-capture attitude carries white noise of a few tenths of a degree per
    pose: a spline through single poses turns it into rate noise that, over the
    small rotations of these flights, dilutes a fitted gyroscope scale by ~10 %.
    Averaging over `attitude_window` seconds divides it by √(poses in a window); the
    rates it leaves are the true ones averaged over as long."""

    def __init__(self, truth: PoseSeries, attitude_step: float = 0.02, attitude_window: float = ATTITUDE_WINDOW_S,
                 smoothing: float = 1e-3):
        valid = (np.isfinite(truth.t) & np.all(np.isfinite(truth.position), axis=1)
                 & np.all(np.isfinite(truth.quaternion), axis=1) & (np.linalg.norm(truth.quaternion, axis=1) > 0.5))
        if (~valid).any():           # a motion-capture frame lost (occlusion): flown through, not fatal
            log.warning("ground truth: %d of %d poses are not finite or not rotations; left out",
                        int((~valid).sum()), len(valid))
        if valid.sum() < 10:
            raise ValueError("ground truth too short to fly (fewer than 10 valid poses)")
        t, keep = np.unique(truth.t[valid], return_index=True)
        pos = truth.position[valid][keep]
        quat = truth.quaternion[valid][keep]
        self.t_start, self.t_end = float(t[0]), float(t[-1])
        self._floor_z = float(np.percentile(pos[:, 2], 1))
        self._splines = [make_smoothing_spline(t, pos[:, i], lam=smoothing) for i in range(3)]
        knots = np.arange(self.t_start, self.t_end, attitude_step)
        self._rot = RotationSpline(knots, Rotation.from_quat(windowed_mean_quaternion(t, quat, knots,
                                                                                      attitude_window)))
        self._rot_span = (knots[0], knots[-1])

    def position(self, t: np.ndarray) -> np.ndarray:
        return np.stack([s(t) for s in self._splines], axis=-1)

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        return np.stack([s.derivative(2)(t) for s in self._splines], axis=-1)

    def motors_on(self, t: np.ndarray) -> np.ndarray:
        """Airborne: AIRBORNE_M above the flight's lowest point (its 1st percentile, the
        floor it takes off from; a recording that starts in the air counts its lowest
        few centimetres as on the ground)."""
        return self.position(t)[..., 2] > self._floor_z + AIRBORNE_M

    def rotation(self, t: np.ndarray) -> Rotation:
        return self._rot(np.clip(np.asarray(t, float), *self._rot_span))


def window_mean(t: np.ndarray, values: np.ndarray, at: np.ndarray, window: float) -> np.ndarray:
    """The mean of the rows of `values` (samples at sorted times `t`) within ±window/2
    of each time in `at`; where a window holds none, the next row."""
    cumulative = np.vstack([np.zeros(values.shape[1]), np.cumsum(values, axis=0)])
    lo = np.searchsorted(t, at - window / 2, side="left")
    hi = np.maximum(np.searchsorted(t, at + window / 2, side="right"), lo + 1).clip(max=len(t))
    lo = np.minimum(lo, hi - 1)
    return (cumulative[hi] - cumulative[lo]) / (hi - lo)[:, None]


def windowed_mean_quaternion(t: np.ndarray, quat: np.ndarray, at: np.ndarray, window: float) -> np.ndarray:
    """The mean attitude of the poses within ±window/2 of each time in `at` (see
    window_mean). Quaternions are made sign-continuous first, so a normalised mean
    over a window of small rotations is their mean."""
    q = np.array(quat, float)
    flip = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2 == 1
    q[1:][flip] *= -1.0
    mean = window_mean(t, q, at, window)
    return mean / np.linalg.norm(mean, axis=1, keepdims=True)


TRAJECTORIES = {"circle", "circle-sine", "smooth-random"}


def parametric(kind: str, duration: float = 30.0, seed: int = 0, **kwargs) -> Trajectory:
    """Build a parametric trajectory by name, with `duration` seconds of pattern."""
    try:
        return _parametric(kind, FlightPlan(pattern=duration), seed, **kwargs)
    except TypeError as exc:        # a parameter the trajectory does not have
        raise ValueError(f"trajectory {kind!r}: {exc}") from exc


def _parametric(kind: str, plan: FlightPlan, seed: int, **kwargs) -> Trajectory:
    if kind == "circle":
        return CircleTrajectory(plan, **kwargs)
    if kind == "circle-sine":
        kwargs.setdefault("z_amplitude", 0.5)
        kwargs.setdefault("z_omega", 0.8)
        return CircleTrajectory(plan, **kwargs)
    if kind == "smooth-random":
        return SmoothRandomTrajectory(plan, seed=seed, **kwargs)
    raise ValueError(f"unknown trajectory {kind!r}; choose one of {sorted(TRAJECTORIES)}")
