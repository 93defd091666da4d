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

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

# Stages, in order of application.
WORLD = 0       # changes what is physically true (anchor positions, lever arm)
SIGNAL = 1      # deterministic sensor errors (biases, scale factors, delays)
NOISE = 2       # random errors (white noise)
CORRUPTION = 3  # rare gross errors (outliers)
TIMING = 4      # timestamps (offsets, drift)


@dataclass
class World:
    """What is physically true in a simulation, as effects of stage WORLD leave it."""

    anchor_positions: dict[int, np.ndarray]
    anchor_rotations: dict[int, Rotation]
    lever_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class ImuBatch:
    """IMU samples being simulated: true values in, measured values out."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray


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
        anchors = np.array([world.anchor_positions[int(k)] for k in ids]).reshape(-1, 3)
        return np.linalg.norm(self.tag_position - anchors, axis=1)


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

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator) -> None:
        """Change TDOA values (or timestamps) in place."""


def _vec3(value, name: str) -> np.ndarray:
    v = np.asarray(value, float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be three finite numbers, got {value!r}")
    return v


class _ImuConstantBias(Effect):
    """measured = true + bias on one IMU stream (body frame)."""

    stage = SIGNAL
    stream: ClassVar[str] = ""   # "accel" or "gyro"
    param: ClassVar[str] = ""    # the catalog's parameter name

    def __init__(self, **params):
        unknown = set(params) - {self.param}
        if unknown:
            raise TypeError(f"unexpected parameter(s) {sorted(unknown)}")
        self.bias = _vec3(params.get(self.param, (0.0, 0.0, 0.0)), self.param)

    def params(self) -> dict:
        return {self.param: self.bias.tolist()}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator) -> None:
        getattr(imu, self.stream)[:] += self.bias


class ImuAccelBias(_ImuConstantBias):
    """Accelerometer bias (m/s²)."""

    name, stream, param = "imu_accel_bias", "accel", "bias_mps2"


class ImuGyroBias(_ImuConstantBias):
    """Gyroscope bias (rad/s)."""

    name, stream, param = "imu_gyro_bias", "gyro", "bias_rps"


class ImuNoise(Effect):
    """White noise on every IMU axis (standard deviations in m/s² and rad/s)."""

    name, stage = "imu_noise", NOISE

    def __init__(self, accel_std: float = 0.05, gyro_std: float = 0.005):
        self.accel_std, self.gyro_std = float(accel_std), float(gyro_std)

    def params(self) -> dict:
        return {"accel_std": self.accel_std, "gyro_std": self.gyro_std}

    def apply_imu(self, imu: ImuBatch, rng: np.random.Generator) -> None:
        imu.accel += rng.normal(0.0, self.accel_std, imu.accel.shape)
        imu.gyro += rng.normal(0.0, self.gyro_std, imu.gyro.shape)


class TdoaNoise(Effect):
    """Zero-mean Gaussian noise on every TDOA measurement (m)."""

    name, stage = "tdoa_noise", NOISE

    def __init__(self, std_m: float = 0.1):
        self.std = float(std_m)

    def params(self) -> dict:
        return {"std_m": self.std}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator) -> None:
        tdoa.value += rng.normal(0.0, self.std, tdoa.value.shape)


class Outliers(Effect):
    """A `fraction` of TDOA samples gets an excess path delay on one of its two
    anchors (exponential, mean `mean_excess_m`): multipath makes a path longer,
    so the error's sign says which anchor was hit."""

    name, stage = "outliers", CORRUPTION

    def __init__(self, fraction: float = 0.05, mean_excess_m: float = 2.0):
        if not 0.0 <= fraction <= 1.0:
            raise ValueError("fraction must be within [0, 1]")
        self.fraction, self.mean_excess = float(fraction), float(mean_excess_m)

    def params(self) -> dict:
        return {"fraction": self.fraction, "mean_excess_m": self.mean_excess}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator) -> None:
        hit = rng.random(len(tdoa.value)) < self.fraction
        excess = 1.0 + rng.exponential(self.mean_excess, len(tdoa.value))
        # A longer path to B raises distance_diff, a longer path to A lowers it.
        sign = np.where(rng.random(len(tdoa.value)) < 0.5, 1.0, -1.0)
        tdoa.value += np.where(hit, sign * excess, 0.0)


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (ImuAccelBias, ImuGyroBias, ImuNoise, TdoaNoise, Outliers)
}


def register(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the catalog (used as a decorator by effect modules)."""
    EFFECTS[cls.name] = cls
    return cls


def make_effect(name: str, params: dict | None = None) -> Effect:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    try:
        return EFFECTS[name](**(params or {}))
    except TypeError as exc:
        raise ValueError(f"bad parameters for effect {name!r}: {exc}") from exc


def effects_from_json(items: list[dict]) -> list[Effect]:
    return [make_effect(item["effect"], item.get("params", {})) for item in items]
