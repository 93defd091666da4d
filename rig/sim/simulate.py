"""The IMU + UWB TDOA simulator.

A simulation is described by a JSON-able `SimConfig`: a trajectory (parametric, or
a recording's own ground truth), an anchor set (a survey file or the recording's),
sensor rates, the UWB mode, a seed and a list of effects (see `rig.sim.effects`).
The same config and seed give the same recording, byte for byte.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from rig.data import paths
from rig.data.errors import read_json
from rig.data.importer import load_any
from rig.data.recording import PoseSeries, Recording, TdoaSeries, Vec3Series
from rig.data.survey import Anchor, parse_survey
from rig.sim import effects as fx
from rig.sim.trajectory import RecordedTrajectory, Trajectory, parametric

log = logging.getLogger(__name__)

# Output resolution (like a sensor's LSB); 0 keeps full float64 precision.
DEFAULT_RESOLUTION = {"time": 1e-6, "accel": 1e-3, "gyro": 1e-4, "tdoa": 1e-4, "position": 1e-4, "quaternion": 1e-7}
UWB_MODES = ("TDOA2", "TDOA3")


@dataclass
class SimConfig:
    """Everything that determines a simulated recording."""

    trajectory: str = "circle"              # circle | circle-sine | smooth-random | recording
    duration: float = 30.0                  # seconds of pattern flight (parametric only)
    trajectory_params: dict = field(default_factory=dict)
    recording: str | None = None            # recording whose ground truth (and anchors) to fly
    survey: str | None = None               # anchor survey; default: the recording's anchors
    imu_hz: float = 1000.0
    tdoa_hz: float = 200.0
    truth_hz: float = 100.0
    uwb_mode: str = "TDOA2"
    seed: int = 0
    effects: list[dict] = field(default_factory=lambda: [
        {"effect": "imu_noise", "params": {"accel_std": 0.05, "gyro_std": 0.005}},
        {"effect": "imu_accel_bias", "params": {"bias_mps2": [0.05, -0.03, 0.08]}},
        {"effect": "imu_gyro_bias", "params": {"bias_rps": [0.002, -0.003, 0.001]}},
        {"effect": "tdoa_noise", "params": {"std_m": 0.1}},
        {"effect": "outliers", "params": {"fraction": 0.05, "mean_excess_m": 2.0}},
    ])
    resolution: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_RESOLUTION))

    def __post_init__(self) -> None:
        for name in ("duration", "imu_hz", "tdoa_hz", "truth_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
                raise ValueError(f"simulation setting {name} must be a finite number above zero, not {value!r}")

    @classmethod
    def load(cls, path: Path) -> "SimConfig":
        data = read_json(path)
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"{path}: unknown simulation setting(s) {sorted(unknown)}")
        return cls(**data)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)


def tdoa_schedule(t0: float, t1: float, rate: float, mode: str, anchor_ids: list[int],
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample times and anchor pairs: TDOA2 cycles the ring (k, k+1); TDOA3 draws
    random ordered pairs of distinct anchors."""
    if mode not in UWB_MODES:
        raise ValueError(f"unknown UWB mode {mode!r}; choose one of {UWB_MODES}")
    t = np.arange(t0, t1, 1.0 / rate)
    ids = np.asarray(sorted(anchor_ids))
    n = len(ids)
    if mode == "TDOA2":
        k = np.arange(len(t)) % n
        return t, ids[k], ids[(k + 1) % n]
    a = rng.integers(0, n, len(t))
    b = (a + rng.integers(1, n, len(t))) % n  # any anchor but a
    return t, ids[a], ids[b]


def _quantize(values: np.ndarray, step: float) -> np.ndarray:
    """Round to a power-of-ten step, as decimals, so the numbers print short."""
    if step <= 0:
        return values
    decimals = int(round(-np.log10(step)))
    if not np.isclose(10.0 ** -decimals, step):
        raise ValueError(f"resolution {step} is not a power of ten")
    return np.round(values, decimals)


def _trajectory_and_anchors(cfg: SimConfig) -> tuple[Trajectory, list[Anchor], dict[str, str]]:
    meta: dict[str, str] = {}
    anchors: list[Anchor] | None = None
    if cfg.trajectory == "recording":
        if not cfg.recording:
            raise ValueError("trajectory 'recording' needs a recording path")
        source = load_any(Path(cfg.recording))        # an MCAP recording or a flight log
        trajectory: Trajectory = RecordedTrajectory(source.truth)
        anchors = source.anchors
        meta["trajectory_source"] = str(cfg.recording)
    else:
        trajectory = parametric(cfg.trajectory, duration=cfg.duration, seed=cfg.seed, **cfg.trajectory_params)
    if cfg.survey:
        anchors = parse_survey(paths.config_survey(cfg.survey))
        meta["survey"] = str(cfg.survey)
    if not anchors:
        raise ValueError("no anchors: give a survey or a recording")
    return trajectory, anchors, meta


def simulate(cfg: SimConfig) -> Recording:
    """Fly `cfg.trajectory` past `cfg`'s anchors and return the simulated recording."""
    rng = np.random.default_rng(cfg.seed)
    trajectory, anchors, meta = _trajectory_and_anchors(cfg)
    effects = fx.staged(fx.effects_from_json(cfg.effects, [a.id for a in anchors]))
    res = {**{k: 0.0 for k in DEFAULT_RESOLUTION}, **cfg.resolution}
    t0, t1 = trajectory.t_start, trajectory.t_end

    world = fx.World.surveyed(anchors)
    for effect in effects:
        effect.apply_world(world)

    t_imu = _quantize(np.arange(t0, t1, 1.0 / cfg.imu_hz), res["time"])
    force = trajectory.specific_force(t_imu)
    imu = fx.ImuBatch(t_imu, force, trajectory.angular_rate(t_imu), rotor=trajectory.rotor_speed(t_imu, force),
                      velocity=trajectory.body_velocity(t_imu), velocity_rate=trajectory.body_velocity_rate(t_imu))
    fx.apply_imu(effects, rng, imu)

    t_uwb, id_a, id_b = tdoa_schedule(t0, t1, cfg.tdoa_hz, cfg.uwb_mode, [a.id for a in anchors], rng)
    t_uwb = _quantize(t_uwb, res["time"])
    rotation = trajectory.rotation(t_uwb)
    tag = trajectory.position(t_uwb) + rotation.apply(world.lever_arm)
    batch = fx.TdoaBatch(t_uwb, id_a, id_b, tag, rotation, np.zeros(len(t_uwb)))
    batch.value = batch.range_to(world, id_b) - batch.range_to(world, id_a)
    for effect in effects:
        effect.apply_tdoa(batch, world, rng)
    order = np.argsort(batch.t, kind="stable")  # timing effects may reorder samples

    t_truth = _quantize(np.arange(t0, t1, 1.0 / cfg.truth_hz), res["time"])
    quat = trajectory.rotation(t_truth).as_quat()
    quat *= np.where(quat[:, 3:] < 0, -1.0, 1.0)  # one hemisphere: w ≥ 0
    return Recording(
        accel=Vec3Series(imu.t, _quantize(imu.accel, res["accel"])),
        gyro=Vec3Series(imu.t.copy(), _quantize(imu.gyro, res["gyro"])),
        tdoa=TdoaSeries(_quantize(batch.t[order], res["time"]), batch.id_a[order].astype(int),
                        batch.id_b[order].astype(int), _quantize(batch.value[order], res["tdoa"])),
        truth=PoseSeries(t_truth, _quantize(trajectory.position(t_truth), res["position"]),
                         _quantize(quat, res["quaternion"])),
        anchors=anchors,
        metadata={
            "source": "rig simulate",
            "uwb_mode": cfg.uwb_mode,
            "simulation": json.dumps(asdict(cfg), sort_keys=True),
            **meta,
        },
    )



class Predictor:
    """The simulator's physics evaluated on a recording's own schedule: what each
    recorded IMU sample and TDOA measurement would read if the world were the
    recording's ground truth and surveyed anchors plus `effects` (noise-free; random
    effects add their expected value). The diagnosis compares this with the recording.

    The ground truth is smoothed once (RecordedTrajectory); kinematics at the UWB
    sample times are cached per timing model."""

    def __init__(self, rec: Recording):
        self.rec = rec
        self.trajectory = RecordedTrajectory(rec.truth)
        self.accel_true = self.trajectory.specific_force(rec.accel.t)
        self.accel_vibration = fx.vibration_level(rec.accel.t, rec.accel.xyz)   # the recording's own
        self.accel_rotor = self.trajectory.rotor_speed(rec.accel.t, self.accel_true)
        self.gyro_true = self.trajectory.angular_rate(rec.gyro.t)
        self.gyro_rotor = _resampled(rec.gyro.t, rec.accel.t, self.accel_rotor)     # the gyroscope's own clock
        self._kinematics: dict[bytes, tuple[np.ndarray, object]] = {}

    @cached_property
    def motion(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each IMU stream's body velocity and its rate, at its samples (what a lean
        needs; computed once, when first asked for)."""
        return {stream: (self.trajectory.body_velocity(t), self.trajectory.body_velocity_rate(t))
                for stream, t in (("accel", self.rec.accel.t), ("gyro", self.rec.gyro.t))}

    def world(self, effects: list[fx.Effect]) -> fx.World:
        world = fx.World.surveyed(self.rec.anchors)
        for effect in fx.staged(effects):
            effect.apply_world(world)
        return world

    def true_uwb_times(self, effects: list[fx.Effect]) -> np.ndarray:
        """When the recorded UWB stamps were really measured, by the timing effects."""
        stamps = self.rec.tdoa.t
        timing = [e for e in fx.staged(effects) if e.stage == fx.TIMING]
        t = stamps.copy()
        for _ in range(3 if timing else 0):   # fixed point of stamp(t) = stamps; stamp is nearly t
            forward = t
            for effect in timing:
                forward = effect.stamp(forward)
            t = t - (forward - stamps)
        return t

    def tdoa(self, effects: list[fx.Effect], rng: np.random.Generator | None = None) -> fx.TdoaBatch:
        t_true = self.true_uwb_times(effects)
        position, rotation = self._uwb_kinematics(t_true)
        world = self.world(effects)
        d = self.rec.tdoa
        batch = fx.TdoaBatch(t_true, d.id_a, d.id_b, position + rotation.apply(world.lever_arm), rotation,
                             np.zeros(len(d.t)))
        known = world.known_pairs(d.id_a, d.id_b)
        batch.value = np.full(len(d.t), np.nan)
        batch.value[known] = (fx.ranges(batch.tag_position[known], world, d.id_b[known])
                              - fx.ranges(batch.tag_position[known], world, d.id_a[known]))
        for effect in fx.staged(effects):
            if effect.stage != fx.TIMING:
                effect.apply_tdoa(batch, world, rng)
        return batch

    def imu(self, effects: list[fx.Effect], accel=None, gyro=None,
            rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """IMU readings under `effects`, from the true ones (or from the given readings)."""
        a = fx.ImuBatch(self.rec.accel.t, (self.accel_true if accel is None else accel).copy(),
                        np.zeros_like(self.accel_true), vibration=self.accel_vibration, rotor=self.accel_rotor,
                        velocity=self.motion["accel"][0], velocity_rate=self.motion["accel"][1])
        # each batch is one stream's samples (the streams may have their own clocks); the
        # gyroscope's carries no accelerometer readings, so no vibration to measure on them
        nothing = np.zeros_like(self.gyro_true)
        g = fx.ImuBatch(self.rec.gyro.t, nothing.copy(), (self.gyro_true if gyro is None else gyro).copy(),
                        vibration=nothing, rotor=self.gyro_rotor,
                        velocity=self.motion["gyro"][0], velocity_rate=self.motion["gyro"][1])
        fx.apply_imu(effects, rng, a, g)
        return a.accel, g.gyro

    def _uwb_kinematics(self, t: np.ndarray):
        key = t.tobytes()
        if key not in self._kinematics:
            if len(self._kinematics) > 8:
                self._kinematics.clear()
            self._kinematics[key] = (self.trajectory.position(t), self.trajectory.rotation(t))
        return self._kinematics[key]


def _resampled(t: np.ndarray, t_from: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.interp(t, t_from, values) if len(t_from) else np.ones(len(t))


def inject(rec: Recording, effects: list[dict], seed: int = 0, predictor: Predictor | None = None) -> Recording:
    """The recording as if `effects` had been present when it was made: TDOA values
    change by what the effects change in the simulator's prediction along the ground
    truth (random ones drawn with `seed`), UWB stamps move by the timing effects, and
    IMU effects act on the recorded readings (measured' = scale × measured + bias).
    Used to prove the diagnosis on concealed effects; the result keeps the recording's
    real noise and real effects."""
    rng = np.random.default_rng(seed)
    chosen = fx.effects_from_json(effects, [a.id for a in rec.anchors])
    predictor = predictor or Predictor(rec)
    base = predictor.tdoa([])
    changed = predictor.tdoa([e for e in chosen if e.stage != fx.TIMING], rng)
    value = rec.tdoa.distance_diff + np.nan_to_num(changed.value - base.value)
    stamps = rec.tdoa.t
    for effect in fx.staged(chosen):
        stamps = effect.stamp(stamps)
    accel, gyro = predictor.imu(chosen, rec.accel.xyz, rec.gyro.xyz, rng)
    order = np.argsort(stamps, kind="stable")
    return Recording(
        accel=Vec3Series(rec.accel.t.copy(), accel), gyro=Vec3Series(rec.gyro.t.copy(), gyro),
        tdoa=TdoaSeries(stamps[order], rec.tdoa.id_a[order], rec.tdoa.id_b[order], value[order]),
        truth=rec.truth, anchors=rec.anchors,
        metadata={**rec.metadata, "injected_effects": json.dumps(effects, sort_keys=True), "injection_seed": str(seed)})
