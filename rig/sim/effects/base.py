"""The simulator's building blocks: the stages effects act in, the world and the
batches they change, the `Effect` base class and the checks of its parameters.

The simulator first builds the ideal world (true anchor positions, tag antenna
offset), computes ideal IMU readings and ideal TDOA geometry, then hands the
batches to each effect in stage order. Every effect is a small class with a
catalog `name`, JSON `params` and hooks that change a batch in place; effects
that do not touch a stream leave its hook as the no-op default.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

# Stages, in order of application.
WORLD = 0       # changes what is physically true (anchor positions, lever arm)
SCALE = 1       # multiplicative sensor errors (scale factors), before any additive one
SIGNAL = 2      # deterministic additive sensor errors (biases, delays, antenna pattern)
NOISE = 3       # random errors (white noise, NLOS excess delays)
RECTIFIED = 4   # errors made of the noise itself (vibration rectification)
CORRUPTION = 5  # rare gross errors (outliers)
FILTERED = 6    # what the flight controller does to the readings before logging them (low-pass)
TIMING = 7      # timestamps (offsets, drift)


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
    # the body-frame velocity (m/s) and its rate of change at each sample, when the
    # batch comes from a trajectory (Trajectory.body_velocity); None otherwise
    velocity: np.ndarray | None = None
    velocity_rate: np.ndarray | None = None


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
    # The largest size each parameter can physically have (`size`): what a real flight can
    # carry. The diagnosis reports a fit beyond it as not explained; a configuration
    # beyond it is simulated, with a warning.
    bounds: ClassVar[dict[str, float]] = {}
    neutral: ClassVar[float] = 0.0
    # The parameters that are displacements in space: their bound is on their length
    # (an anchor 0.8 m off its survey along each axis has moved 1.4 m).
    lengths: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def size(cls, param: str, deviation) -> float:
        """How large a deviation from neutral of `param` is, as its bound measures it
        (`size_weights`)."""
        deviation = np.ravel(np.asarray(deviation, float))
        return float(cls.size_weights(param, deviation) @ deviation)

    @classmethod
    def size_weights(cls, param: str, deviation: np.ndarray) -> np.ndarray:
        """The weights w whose w · deviation is its size near `deviation` (its gradient;
        a fit's standard error of its size is |w · standard errors|, componentwise): a
        displacement's length, else its largest |component| (an IMU's bias or scale per
        axis, as a datasheet gives it). An effect whose parameter is not a size in itself
        overrides it."""
        if param in cls.lengths:
            length = np.linalg.norm(deviation)
            return deviation / length if length > 0 else np.zeros_like(deviation)
        weights = np.zeros_like(deviation)
        largest = int(np.argmax(np.abs(deviation)))
        weights[largest] = np.sign(deviation[largest])
        return weights

    def params(self) -> dict:
        return {}

    def beyond_bound(self) -> list[str]:
        """Each parameter beyond its physical bound, as 'name value (bound B)'."""
        params = self.params()
        return [f"{name} {params[name]} (bound {bound:g})" for name, bound in self.bounds.items()
                if self.size(name, np.asarray(params[name], float) - self.neutral) > bound]

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


def staged(effects: list["Effect"]) -> list["Effect"]:
    """The effects in the order they act: by stage."""
    return sorted(effects, key=lambda e: e.stage)


def anchor_sign(id_a: np.ndarray, id_b: np.ndarray, anchor: int) -> np.ndarray:
    """+1 where `anchor` is B (its range adds to distance_diff), -1 where it is A, else 0."""
    return (id_b == anchor).astype(float) - (id_a == anchor).astype(float)


def _anchor_sign(tdoa: TdoaBatch, anchor: int) -> np.ndarray:
    return anchor_sign(tdoa.id_a, tdoa.id_b, anchor)


def _anchor_id(anchor) -> int:
    if isinstance(anchor, bool) or int(anchor) != anchor or anchor < 0:
        raise ValueError(f"anchor must be a non-negative integer id, got {anchor!r}")
    return int(anchor)
