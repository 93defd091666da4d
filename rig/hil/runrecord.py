"""Run records: everything a replay sent and received, as `DIR/run.mcap`.

Topics (JSON, with JSON schemas, readable in Foxglove; documented in recordings/README.md):

    /run/input/imu      each window's IMU samples as the board received them (quantised), one
                        message a window at its first sample's time (records written before
                        2026-11-27 hold one message a sample, uwb_rig.RunImu)
    /run/input/tdoa     TDOA measurements as sent
    /run/truth          ground truth over the replayed span, at most one pose every 10 ms
    /run/estimate       the board's estimates (position, velocity, attitude, covariance diagonal)
    /run/timing         cost of each window and call, in the target's unit, with the budget
                        (with compact answers, of the worst window since the last, every N windows)
    /run/counters       the estimator's cumulative counters after each window (with compact
                        answers, every N windows)
    /run/status         status messages and the rig's own notes (board reset, link errors)
    /uwb/anchors        the anchor set

The file is written as the replay goes (small chunks) and finished on every exit path:
normal end, Ctrl-C, a board failure. A write error (a full disk) stops the recording
with a clear message, and the file is still finished from its whole records
(`recording.seal_unfinished`), so any MCAP reader reads what was written before.
"""

from __future__ import annotations

import bisect
import functools
import json
import math
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import orjson
from mcap.writer import CompressionType

from rig.data.recording import (
    SCHEMAS,
    TOPIC_ANCHORS,
    McapJsonWriter,
    Recording,
    RecordingError,
    anchors_message,
    is_finished,
    number_schema,
    object_schema,
    read_topics,
    seal_unfinished,
    vector_schema,
)
from rig.hil import foxglove, protocol
from rig.hil.interrupt import critical

log = logging.getLogger(__name__)

RUN_FILE = "run.mcap"
METADATA_RUN = "run"
TOPIC_IMU = "/run/input/imu"
TOPIC_TDOA = "/run/input/tdoa"
TOPIC_TRUTH = "/run/truth"
TOPIC_ESTIMATE = "/run/estimate"
TOPIC_TIMING = "/run/timing"
TOPIC_COUNTERS = "/run/counters"
TOPIC_STATUS = "/run/status"
# Foxglove's well-known schemas beside the project's own: the flight in 3D, the notes as
# log lines, the position error as a plot
TOPIC_FOXGLOVE_ESTIMATE = "/foxglove/estimate"
TOPIC_FOXGLOVE_TRUTH = "/foxglove/truth"
TOPIC_FOXGLOVE_ANCHORS = "/foxglove/anchors"
TOPIC_FOXGLOVE_LOG = "/foxglove/log"
TOPIC_POSITION_ERROR = "/run/position_error"
CHUNK_BYTES = 256 * 1024      # what an unfinished file can lose at most

_T = number_schema("time on the recording's clock", "s")
_IMU_SAMPLE = object_schema("uwb_rig.RunImu", {
    "t": _T, "accel": vector_schema("specific force as received (quantised)", "m/s^2"),
    "gyro": vector_schema("angular rate as received (quantised)", "rad/s")})
RUN_SCHEMAS = {
    "uwb_rig.RunImuWindow": object_schema("uwb_rig.RunImuWindow", {
        "t": _T, "samples": {"type": "array", "items": _IMU_SAMPLE,
                             "description": "the window's samples in time order"}}),
    "uwb_rig.Estimate": object_schema("uwb_rig.Estimate", {
        "t": _T, "position": vector_schema("estimated position", "m"), "velocity": vector_schema("estimated velocity", "m/s"),
        "orientation": {**SCHEMAS["uwb_rig.Pose"]["properties"]["orientation"],
                        "description": "estimated attitude, unit quaternion body->world"},
        "cov_diag": {"type": "array", "items": {"type": "number"},
                     "description": "error-state covariance diagonal (position, velocity, attitude)"}}),
    "uwb_rig.Timing": object_schema("uwb_rig.Timing", {
        "t": _T, "unit": {"type": "string", "description": "ns, cycles or instructions"},
        "budget": number_schema("one 10 ms window in the unit"), "window": number_schema("cost of the whole window"),
        "predict": number_schema("prediction"), "tdoa_total": number_schema("all TDOA updates"),
        "tdoa_max": number_schema("most expensive TDOA update"), "n_tdoa": {"type": "integer"},
        "latency_ms": number_schema("real-time mode only: wall time from the window's last byte sent to its "
                              "estimate received", "ms")}),
    "uwb_rig.Counters": object_schema("uwb_rig.Counters", {
        "t": _T, **{name: {"type": "integer"} for name in protocol.Counters.__dataclass_fields__}}),
    "uwb_rig.Status": object_schema("uwb_rig.Status", {
        "t": _T, "source": {"type": "string", "description": "board or rig"},
        "code": {"type": "integer"}, "message": {"type": "string"}}),
}

RUN_SCHEMAS["uwb_rig.Timing"]["required"].remove("latency_ms")    # present in real-time mode only
RUN_SCHEMAS["uwb_rig.PositionError"] = object_schema("uwb_rig.PositionError", {
    "t": _T, "error_m": number_schema("distance from the estimate to the ground truth at its time", "m"),
    "x": number_schema("estimate − truth, x", "m"), "y": number_schema("estimate − truth, y", "m"),
    "z": number_schema("estimate − truth, z", "m")})
RUN_SCHEMAS.update(foxglove.SCHEMAS)


def _xyz(v) -> dict:
    return {"x": v[0], "y": v[1], "z": v[2]}


def _quat(q) -> dict:
    return {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}


# Messages are encoded with orjson: a tenth of the json module's time on a run record's
# 60 000 messages, and strict JSON (NaN and infinities, from a board that diverged, are
# written null, which any reader and Foxglove parse; `NaN` is not JSON). numpy's
# scalars and arrays are numbers and lists, as the json module's callers made them.
_dumps = functools.partial(orjson.dumps, option=orjson.OPT_SERIALIZE_NUMPY)


TRUTH_STEP_S = 0.010          # the ground truth in the record: at most one pose a window


MAX_PENDING = 20_000           # windows held at most (200 s of flight), then written as they come


def _one_section(method):
    """The messages a method writes, in one section a signal does not interrupt: half a
    message would corrupt the chunk (one section per window, not per message)."""
    @functools.wraps(method)
    def in_section(self, *args, **kwargs):
        with critical():
            return method(self, *args, **kwargs)
    return in_section


@dataclass
class RunRecorder:
    """Writes one replay's run record as it happens."""

    path: Path
    failed: str | None = None
    messages: int = 0
    kept: dict = field(default_factory=dict)   # topic -> messages, of the topics the report reads (REPORTED)
    deferred: bool = True                      # windows' inputs and answers held until flush()
    _pending: list = field(default_factory=list)
    _out: McapJsonWriter | None = None
    _channels: dict = field(default_factory=dict)
    _truth: tuple | None = None          # times and positions of the ground truth, for the position error

    def __post_init__(self) -> None:
        try:
            self._out = McapJsonWriter(self.path, compression=CompressionType.ZSTD, chunk_size=CHUNK_BYTES)
        except OSError as exc:
            self._fail(exc)

    @_one_section
    def start(self, rec: Recording, t0: float, t_end: float | None, info: dict) -> None:
        """Metadata, anchors and the ground truth of the replayed span."""
        if not self._ready():
            return
        self._guard(lambda: self._out.metadata(METADATA_RUN, {k: str(v) for k, v in info.items()}))
        self._write(TOPIC_ANCHORS, "uwb_rig.AnchorSet", t0, anchors_message(rec.anchors), raw=True)
        self._write(TOPIC_FOXGLOVE_ANCHORS, "foxglove.SceneUpdate", t0, foxglove.anchors_scene(t0, rec.anchors))
        truth = rec.truth
        end = np.inf if t_end is None else t_end
        span = np.flatnonzero((truth.t >= t0 - 0.5) & (truth.t <= end + 0.5))
        self._truth = (truth.t[span].tolist(), truth.position[span].tolist())   # whole, for the position error
        slots = np.floor((truth.t[span] - t0) / TRUTH_STEP_S)
        for k in span[np.concatenate([[True], np.diff(slots) > 0])] if len(span) else span:
            q, p, t = truth.quaternion[k].tolist(), truth.position[k].tolist(), float(truth.t[k])
            self._write(TOPIC_TRUTH, "uwb_rig.Pose", t, {"t": t, "position": _xyz(p), "orientation": _quat(q)})
            self._write(TOPIC_FOXGLOVE_TRUTH, "foxglove.PoseInFrame", t, foxglove.pose_in_frame(t, p, q))

    def inputs(self, t0: float, t_prev_us: int, imu: list, counts: np.ndarray, tdoa: list) -> None:
        """One window's inputs (the Window fields: dt since the previous STEP), the IMU as
        the board reads its `counts`."""
        self._hold(self._write_inputs, (t0, t_prev_us, imu, counts, tdoa))

    def answer(self, t0: float, est: protocol.Estimate, att: protocol.Attitude, counters: protocol.Counters | None,
               timing: protocol.Timing | None, unit: str, budget: float, latency_s: float | None = None) -> None:
        """One window's answer (a brief one has no counters and no timing)."""
        self._hold(self._write_answer, (t0, est, att, counters, timing, unit, budget, latency_s))

    def _hold(self, write, args: tuple) -> None:
        """While `deferred`, a window's messages wait for flush(): the replay loop then
        costs a list append, and the record is written in bulk once the loop is done
        (or when a status note, or the end, comes first)."""
        if self.deferred and len(self._pending) < MAX_PENDING:
            self._pending.append((write, args))
        else:
            self.flush()
            with critical():
                write(*args)

    @_one_section
    def flush(self) -> None:
        """Write every held message, in the order they came."""
        pending, self._pending = self._pending, []
        for write, args in pending:
            write(*args)

    def _write_inputs(self, t0: float, t_prev_us: int, imu: list, counts: np.ndarray, tdoa: list) -> None:
        if imu:
            # one message a window: a tenth of the messages of one a sample, which made up
            # half of the record's writing time
            acc, gyro = protocol.imu_values(counts)
            times = [t0 + (t_prev_us + dt) * 1e-6 for dt, _, _ in imu]
            samples = [{"t": t, "accel": _xyz(a), "gyro": _xyz(g)} for t, a, g in zip(times, acc.tolist(), gyro.tolist())]
            self._write(TOPIC_IMU, "uwb_rig.RunImuWindow", times[0], {"t": times[0], "samples": samples})
        for dt, a, b, v in tdoa:
            t = t0 + (t_prev_us + dt) * 1e-6
            self._write(TOPIC_TDOA, "uwb_rig.Tdoa", t,
                        {"t": t, "id_a": a, "id_b": b, "distance_diff": float(v) if math.isfinite(v) else None})

    def _write_answer(self, t0: float, est: protocol.Estimate, att: protocol.Attitude,
                      counters: protocol.Counters | None, timing: protocol.Timing | None, unit: str, budget: float,
                      latency_s: float | None = None) -> None:
        t = t0 + est.t_us * 1e-6
        q = att.quat
        cov = [float(c) if math.isfinite(c) else None for c in att.cov_diag]
        estimate = {"t": t, "position": _xyz(est.pos), "velocity": _xyz(est.vel), "orientation": _quat(q), "cov_diag": cov}
        self._write(TOPIC_ESTIMATE, "uwb_rig.Estimate", t, estimate)
        self._write(TOPIC_FOXGLOVE_ESTIMATE, "foxglove.PoseInFrame", t, foxglove.pose_in_frame(t, est.pos, q))
        self._position_error(t, est.pos)
        if timing is None:
            return
        figures = {"t": t, "unit": unit, "budget": budget, "window": timing.window, "predict": timing.predict,
                   "tdoa_total": timing.tdoa_total, "tdoa_max": timing.tdoa_max, "n_tdoa": timing.n_tdoa,
                   **({} if latency_s is None else {"latency_ms": latency_s * 1e3})}
        self._write(TOPIC_TIMING, "uwb_rig.Timing", t, figures)
        self._write(TOPIC_COUNTERS, "uwb_rig.Counters", t, {"t": t, **counters.__dict__})

    @_one_section
    def status(self, t: float, source: str, code: int, message: str) -> None:
        self.flush()                  # what came before it goes before it
        self._write(TOPIC_STATUS, "uwb_rig.Status", t, {"t": t, "source": source, "code": code, "message": message})
        self._write(TOPIC_FOXGLOVE_LOG, "foxglove.Log", t,
                    foxglove.log(t, "error" if code < 0 else "warning", source, f"{message} (code {code})"))

    def _position_error(self, t: float, position) -> None:
        """Estimate − truth at the estimate's time, while the ground truth covers it."""
        if self._truth is None or len(self._truth[0]) < 2 or not self._truth[0][0] <= t <= self._truth[0][-1]:
            return
        times, positions = self._truth
        k = min(bisect.bisect_right(times, t), len(times) - 1)      # np.interp, for one instant
        t_a, t_b = times[k - 1], times[k]
        f = (t - t_a) / (t_b - t_a) if t_b > t_a else 0.0
        truth = [a + f * (b - a) for a, b in zip(positions[k - 1], positions[k])]
        error = [float(p) - float(q) for p, q in zip(position, truth)]
        self._write(TOPIC_POSITION_ERROR, "uwb_rig.PositionError", t, {
            "t": t, "error_m": math.sqrt(sum(e * e for e in error)), "x": error[0], "y": error[1], "z": error[2]})

    def close(self) -> None:
        """Write what is held and finish the file, as one section: a signal that lands
        meanwhile takes effect once the file is whole (taken between the two, it left
        the held messages written and the summary never)."""
        with critical():
            self.flush()
            if self._out is not None:
                self._guard(self._out.close)
                self._out = None

    # -------------------------------------------------------------------- internals
    def _ready(self) -> bool:
        return self._out is not None and self.failed is None

    def _write(self, topic: str, schema: str, t: float, obj, raw: bool = False) -> None:
        """One message (inside a caller's `_one_section`): `obj` as JSON (`raw`: `obj` is
        its JSON text already)."""
        if topic in REPORTED:
            self.kept.setdefault(topic, []).append(json.loads(obj) if raw else obj)
        if not self._ready():
            return
        try:
            if topic not in self._channels:
                self._channels[topic] = self._out.channel(topic, schema, RUN_SCHEMAS.get(schema))
            self._out.write(self._channels[topic], t, obj.encode() if raw else _dumps(obj))
            self.messages += 1
        except OSError as exc:
            self._fail(exc)

    def _guard(self, action) -> bool:
        try:
            with critical():            # a signal waits: half a message would corrupt the chunk
                action()
            return True
        except OSError as exc:
            self._fail(exc)
            return False

    def _fail(self, exc: OSError) -> None:
        if self.failed is None:
            self.failed = f"run record {self.path}: {exc.strerror or exc} after {self.messages} messages"
            log.error("%s; the replay goes on, the record keeps what was written", self.failed)


# What the run report reads: kept in memory as written, so the report of a replay does
# not read its record back.
REPORTED = (TOPIC_ESTIMATE, TOPIC_TRUTH, TOPIC_TIMING, TOPIC_TDOA, TOPIC_ANCHORS)


def read_run(path: Path) -> dict[str, list[dict]]:
    """Every message of a run record by topic; an unfinished file yields its complete
    chunks (`rig report DIR --finish` finishes it for other readers)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no run record at {path}")
    if not is_finished(path):
        log.warning("%s is unfinished (its writer was killed?): `rig report %s --finish` closes it at its last "
                    "whole record, so that any MCAP reader opens it", path, path.parent)
    return read_topics(path)[0]


def finish_run_record(path: Path) -> str:
    """Finish a run record left unfinished (`recording.seal_unfinished`); what was done."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no run record at {path}")
    if is_finished(path):
        return "already finished"
    before = path.stat().st_size
    kept = seal_unfinished(path)
    if kept is None:
        raise RecordingError(f"{path}: cannot finish it: its header is cut or it is not an MCAP file")
    return f"finished at its last whole record ({kept} bytes kept, {before - kept} of a cut record dropped)"
