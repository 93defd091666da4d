"""Replay a recording through the C estimator in-process and score it.

The replay starts `START_BEFORE_TAKEOFF` seconds before take-off (first ground
truth above the segment height), where the estimator is initialised with the
ground-truth pose, as a drone is told its start pose before it flies. From there
on it sees only IMU and TDOA, in time order, with a STEP every 10 ms.

A recording without ground truth (a flight without motion capture) can still be
replayed for timing when the drone's start position is given (`StartPose`, as the
Crazyflie's `kalman.initialX/Y/Z/Yaw`): it then starts at its first IMU sample,
level. The TDOA cannot place a drone on the floor, where their errors are metres
(multipath; benchmarks/start_pose.py), so a fix from them would not do.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.data.errors import InputError
from rig.data.recording import TOPIC_TRUTH, Recording
from rig.estimator import metrics, native
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet
from rig.estimator.trained_region import outside_share

log = logging.getLogger(__name__)

STEP_S = 0.01
START_BEFORE_TAKEOFF = 1.0
DIVERGED_RMSE_M = 1.0  # a flight scored worse than this has lost track
FULL_TRUST = -1.0      # trust_prior_n that applies the whole correction on every flight
DISCOUNTED_BELOW = 0.5     # an anchor weight under this is counted as tdoa_anchor_weighted is (EST_WEIGHT_ACCEPTED)
DISCOUNT_SAMPLE_STEPS = 10  # anchor_weight_series reads the anchors' weights every 100 ms


@dataclass
class Replay:
    """Estimator outputs of one replay, on the recording's clock."""

    t: np.ndarray
    outputs: np.ndarray  # native.OUTPUT_DTYPE
    estimator_seconds: float
    t_start: float
    correction_trust: float = 1.0    # the share of the bias correction applied at the end

    @property
    def position(self) -> np.ndarray:
        return self.outputs["pos"].astype(float)

    @property
    def counters(self) -> np.void:
        return self.outputs["counters"][-1]


@dataclass(frozen=True)
class StartPose:
    """Where the drone stood when its recording has no ground truth to say so: its
    position in the anchors' frame and its heading, level (as the Crazyflie's Kalman
    filter starts: the accelerometer's own bias at rest would read as a tilt)."""

    position: tuple[float, float, float]
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        if len(self.position) != 3 or not all(np.isfinite(self.position)) or not np.isfinite(self.yaw_deg):
            raise InputError(f"a start pose needs three finite coordinates and a finite yaw, not "
                             f"{list(self.position)} and {self.yaw_deg}")

    def as_dict(self) -> dict:
        """As metrics.json records it."""
        return {"position": [float(v) for v in self.position], "yaw_deg": float(self.yaw_deg)}


def require_truth(rec: Recording) -> None:
    """The ground truth a replay starts from and is scored against, or a clear error."""
    if len(rec.truth) == 0:
        raise InputError(f"the recording has no ground truth on {TOPIC_TRUTH} to start the estimator from and "
                         "score it against; `rig replay --start-position X Y Z [--start-yaw DEG]` replays it from "
                         "where the drone stood, timed and not scored")


def start_time(rec: Recording, rule: metrics.SegmentRule = metrics.SegmentRule(),
               given: StartPose | None = None) -> float:
    """`START_BEFORE_TAKEOFF` before take-off by the ground truth; with a `given` start
    pose and no ground truth, the first instant both IMU streams have a sample."""
    if given is not None and len(rec.truth) == 0:
        if not len(rec.accel) or not len(rec.gyro):
            raise InputError("the recording has no IMU samples to start a replay from")
        return float(max(rec.accel.t[0], rec.gyro.t[0]))
    require_truth(rec)
    return float(max(metrics.takeoff_time(rec.truth, rule) - START_BEFORE_TAKEOFF, rec.truth.t[0]))


def initial_pose(rec: Recording, t: float, given: StartPose | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pose the estimator starts from at `t`: the `given` one, else the ground
    truth's (else a clear error)."""
    if given is not None:
        return np.array(given.position, float), yaw_quaternion(given.yaw_deg)
    return truth_pose_at(rec, t)


def yaw_quaternion(yaw_deg: float) -> np.ndarray:
    """Body-to-world quaternion (x, y, z, w) of a level drone heading `yaw_deg`."""
    half = np.radians(yaw_deg) / 2.0
    return np.array([0.0, 0.0, np.sin(half), np.cos(half)])


def truth_pose_at(rec: Recording, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The ground truth's position and orientation (quaternion x, y, z, w) at `t`, the
    orientation interpolated on the great circle between the two poses around it."""
    require_truth(rec)
    pos = metrics.interpolate_positions(rec.truth, np.array([t]))[0]
    times, keep = np.unique(rec.truth.t, return_index=True)
    quats = rec.truth.quaternion[keep]
    t = float(np.clip(t, times[0], times[-1]))
    k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(len(times) - 2, 0)))
    if len(times) < 2:
        return pos, quats[0] / np.linalg.norm(quats[0])
    return pos, slerp(quats[k], quats[k + 1], (t - times[k]) / (times[k + 1] - times[k]))


def slerp(q0: np.ndarray, q1: np.ndarray, fraction: float) -> np.ndarray:
    """The unit quaternion `fraction` of the way from q0 to q1 along the shorter arc."""
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    cos = float(np.dot(q0, q1))
    if cos < 0.0:
        q1, cos = -q1, -cos
    if cos > 1.0 - 1e-12:
        q = q0 + fraction * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = np.arccos(min(cos, 1.0))
    return (np.sin((1.0 - fraction) * angle) * q0 + np.sin(fraction * angle) * q1) / np.sin(angle)


def build_events(rec: Recording, t0: float, t_end: float | None = None) -> np.ndarray:
    """All IMU and TDOA samples in [t0, t_end] plus a STEP every 10 ms, sorted;
    times are microseconds since t0. Samples at a STEP's instant belong to its window."""
    t_end = rec.time_span()[1] if t_end is None else t_end
    parts = []

    def add(kind: int, t: np.ndarray, v: np.ndarray, id_a=None, id_b=None) -> None:
        keep = (t >= t0) & (t <= t_end)
        ev = np.zeros(int(keep.sum()), native.EVENT_DTYPE)
        ev["t_us"] = np.round((t[keep] - t0) * 1e6).astype(np.uint32)
        ev["kind"] = kind
        ev["v"][:, : v.shape[1]] = v[keep]
        if id_a is not None:
            # ids outside 0..255 cannot be sent; map them to 255, which the estimator rejects as unknown
            ev["id_a"] = np.where((id_a[keep] >= 0) & (id_a[keep] < 255), id_a[keep], 255)
            ev["id_b"] = np.where((id_b[keep] >= 0) & (id_b[keep] < 255), id_b[keep], 255)
        parts.append(ev)

    add(native.EV_ACCEL, rec.accel.t, rec.accel.xyz)
    add(native.EV_GYRO, rec.gyro.t, rec.gyro.xyz)
    add(native.EV_TDOA, rec.tdoa.t, rec.tdoa.distance_diff[:, None], rec.tdoa.id_a, rec.tdoa.id_b)
    steps = np.arange(t0 + STEP_S, t_end, STEP_S)
    add(native.EV_STEP, steps, np.zeros((len(steps), 1)))
    events = np.concatenate(parts)
    return events[np.lexsort((events["kind"], events["t_us"]))]


def load_model(path: Path | None = None) -> BiasNet | None:
    path = DEFAULT_NETWORK if path is None else Path(path)
    if not path.exists():
        return None
    return BiasNet.load(path)


def make_estimator(rec: Recording, params: native.EstimatorParams, model: BiasNet | None) -> native.Estimator:
    est = native.Estimator(params)
    for anchor in rec.anchors:
        if 0 <= anchor.id < native.MAX_ANCHORS:
            est.set_anchor(anchor.id, anchor.position, anchor.quaternion)
        else:
            log.warning("anchor id %d is outside the estimator's range 0..%d; ignored", anchor.id,
                        native.MAX_ANCHORS - 1)
    if model is not None and params.use_bias_net:
        est.set_bias_net(model.pack())
    return est


def started(rec: Recording, params: native.EstimatorParams, model: BiasNet | None = None,
            start_pose: StartPose | None = None) -> tuple[native.Estimator, np.ndarray, float]:
    """An estimator at the recording's start (`start_time`, `initial_pose`), the events
    it is to replay and their time origin on the recording's clock."""
    t0 = start_time(rec, given=start_pose)
    est = make_estimator(rec, params, model)
    pos, quat = initial_pose(rec, t0, start_pose)
    est.reset(0, pos, quat)
    return est, build_events(rec, t0), t0


def replay(rec: Recording, params: native.EstimatorParams, model: BiasNet | None = None,
           start_pose: StartPose | None = None) -> Replay:
    """The whole recording from its start through the estimator, in-process."""
    est, events, t0 = started(rec, params, model, start_pose)
    tic = time.perf_counter()
    outputs = est.replay(events)
    elapsed = time.perf_counter() - tic
    return Replay(t0 + outputs["t_us"].astype(float) * 1e-6, outputs, elapsed, t0, est.correction_trust())


def anchor_weight_series(rec: Recording, params: native.EstimatorParams, model: BiasNet | None = None,
                         start_pose: StartPose | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each anchor's weight in the blocked-anchor weighting over the flight: a replay read
    every DISCOUNT_SAMPLE_STEPS STEPs, as (times on the recording's clock, weights with
    one column per anchor id up to MAX_ANCHORS). The board sends the count only."""
    est, events, t0 = started(rec, params, model, start_pose)
    ends = np.flatnonzero(events["kind"] == native.EV_STEP)[DISCOUNT_SAMPLE_STEPS - 1::DISCOUNT_SAMPLE_STEPS] + 1
    times, weights, begin = [], [], 0
    for end in ends:
        outputs = est.replay(events[begin:end])
        begin = end
        if len(outputs):
            times.append(t0 + float(outputs["t_us"][-1]) * 1e-6)
            weights.append(est.anchor_weights())
    return np.array(times), np.array(weights).reshape(len(weights), native.MAX_ANCHORS)


def anchor_discounts(rec: Recording, params: native.EstimatorParams, model: BiasNet | None = None,
                     start_pose: StartPose | None = None) -> dict[str, float]:
    """For each anchor of the recording, the share of the scored flight it spent
    discounted by the blocked-anchor weighting (its weight under DISCOUNTED_BELOW): which
    anchors the count `tdoa_anchor_weighted` is made of (anchor_weight_series)."""
    times, weights = anchor_weight_series(rec, params, model, start_pose)
    start, stop = metrics.flight_window(rec.truth, metrics.SegmentRule())
    scored = (times >= start) & (times <= stop)
    if not scored.any():
        return {}
    discounted = weights[scored] < DISCOUNTED_BELOW
    return {str(k): float(np.mean(discounted[:, k])) for k in sorted(rec.anchor_map()) if k < native.MAX_ANCHORS}


def counter_summary(counters: np.void) -> dict:
    return {
        "tdoa_accepted": int(counters["tdoa_accepted"]),
        "tdoa_downweighted": int(counters["tdoa_downweighted"]),
        "tdoa_rejected": int(counters["tdoa_rejected"]),
        "tdoa_anchor_weighted": int(counters["tdoa_anchor_weighted"]),
        "rejected_by_reason": {name: int(n) for name, n in zip(native.REJECT_REASONS, counters["rejected"])},
        "imu_samples": int(counters["imu_samples"]),
        "imu_gaps": int(counters["imu_gaps"]),
        "steps": int(counters["steps"]),
        "resets": int(counters["resets"]),
    }


def estimator_config(robust: bool = True, use_nn: bool = True, model_path: Path | None = None,
                     model: BiasNet | None = None, full_trust: bool = False,
                     **param_overrides) -> tuple[native.EstimatorParams, BiasNet | None]:
    """Parameters and bias network of a run (in-process or on a board): `model` when given,
    else the one at `model_path` or the shipped one. An explicit model path must exist;
    without the shipped one the run goes on without correction, with a warning.
    `full_trust` applies the whole correction, whatever share the flight supports."""
    if full_trust:
        param_overrides.setdefault("trust_prior_n", FULL_TRUST)
    if not use_nn:
        model = None
    elif model is None:
        model = load_model(model_path)
        if model is None:
            if model_path is not None:
                raise FileNotFoundError(f"no bias network at {model_path}")
            log.warning("no bias network shipped yet (%s): running without bias correction", DEFAULT_NETWORK)
    params = native.params_with(robust=int(robust), use_bias_net=int(model is not None), **param_overrides)
    return params, model


def evaluate(rec: Recording, *, robust: bool = True, use_nn: bool = True, model_path: Path | None = None,
             model: BiasNet | None = None, full_trust: bool = False, start_pose: StartPose | None = None,
             **param_overrides) -> dict:
    """Replay and score; the dict is what `rig evaluate --json` writes. `start_pose`:
    the pose it starts from instead of the ground truth's (at the same time)."""
    require_truth(rec)
    params, model = estimator_config(robust, use_nn, model_path, model, full_trust, **param_overrides)
    run = replay(rec, params, model, start_pose)
    position = run.position
    result = metrics.score(run.t, position, rec.truth)
    counters = counter_summary(run.counters)
    result.update(counters)
    result["diverged"] = bool(not np.isfinite(position).all() or counters["resets"] > 0 or result["rmse_3d"] > DIVERGED_RMSE_M)
    result["estimator_seconds"] = run.estimator_seconds
    result["flight_seconds"] = float(run.t[-1] - run.t[0]) if len(run.t) else 0.0
    result["config"] = {"robust": robust, "bias_net": model is not None, "params": params.as_dict(),
                        "start_s": run.t_start, "start_pose": None if start_pose is None else start_pose.as_dict()}
    if model is not None:
        result["correction_trust"], result["full_trust"] = run.correction_trust, bool(params.trust_prior_n < 0)
    if model is not None and model.region is not None:
        result["outside_trained_region"] = extrapolated_share(rec, run.t, position, model)
    return result


def extrapolated_share(rec: Recording, t: np.ndarray, position: np.ndarray, model: BiasNet) -> float:
    """The share of the scored segment's TDOA measurements that the model corrects
    with either link outside where it was trained (its `region`), at the tag position
    estimated at times `t` (the position the board's features use)."""
    start, end = metrics.flight_window(rec.truth, metrics.SegmentRule())
    anchors = rec.anchor_map()
    known = [k for k in anchors if model.anchors is None or k in model.anchors]
    tdoa = rec.tdoa
    rows = (tdoa.t >= start) & (tdoa.t <= end) & np.isin(tdoa.id_a, known) & np.isin(tdoa.id_b, known)
    tag = metrics.interpolate(tdoa.t[rows], t, position)
    where = lambda ids: np.array([anchors[int(k)].position for k in ids], float).reshape(-1, 3)  # noqa: E731
    return outside_share(model.region, where(tdoa.id_a[rows]) - tag, where(tdoa.id_b[rows]) - tag,
                         tdoa.id_a[rows], tdoa.id_b[rows])
