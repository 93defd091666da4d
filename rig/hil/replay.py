"""Replay of a recording into a board over the wire protocol, in lock-step or in real time.

The recording is cut into 10 ms windows exactly as `rig evaluate` does (same start,
same initial pose, same events). Each window goes out as delta-coded IMU messages
(accelerometer and gyroscope samples paired), packed TDOA items and a STEP; the host
then waits for the board's estimate, attitude, counters and timing before sending the
next window, so results do not depend on link speed. With compact answers
(`full_every` N > 1) only every N-th window and the last are answered in full; the
others (brief STEPs) get the estimate and attitude, and the next timing is that of the
most expensive window since the last one reported.

Real-time mode sends each window when the recording's clock (scaled by `speed`) says
it is due, whatever the board is doing, and matches answers to windows as they come:
it measures the input-to-estimate latency and finds late windows (the estimate came
after the next window was due), missed windows (no estimate at all) and overruns, the
timing problems lock-step hides. Its clock starts after a warm-up (the first windows
flown once, then the flight reset), so it times the board in its steady state.

`wire_events` rebuilds the event stream exactly as the board decodes it (quantised
IMU and TDOA, paired samples), so the in-process library can be compared with any
board to float32 precision.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from rig.data.recording import Recording
from rig.estimator import metrics, native
from rig.estimator.bias_net import BiasNet
from rig.estimator.evaluate import StartPose, build_events, initial_pose, start_time
from rig.hil import protocol
from rig.hil.links import BoardLink, LinkError

log = logging.getLogger(__name__)

BUDGET_SECONDS = 0.010        # one 10 ms window
CPU_HZ = 168_000_000          # STM32F405
REPLY_TIMEOUT_S = 5.0
CONFIG_ATTEMPTS = 3           # a configuration message the board lost bytes of is sent again
SETTLE_S = 0.1                # after a loss, the link is quiet this long before the message goes again
LOSS_STATUSES = (protocol.STATUS_BAD_FRAME, protocol.STATUS_RX_OVERFLOW)
LOOKAHEAD = 0                 # strict lock-step; more windows in flight need the board RX ring (1 kB)
FULL_EVERY = 1                # every window answered with its counters and timing
WARM_UP_WINDOWS = 10          # flown once before a real-time run is timed (_warm_up)


@dataclass
class Window:
    t_us: int                                  # the STEP time
    imu: list = field(default_factory=list)    # (dt_us, accel[3], gyro[3])
    tdoa: list = field(default_factory=list)   # (dt_us, id_a, id_b, value)


def windows(events: np.ndarray) -> list[Window]:
    """Group an EVENT_DTYPE stream (as from build_events) into STEP windows; times relative
    to the previous STEP (0 for the first window, the reset time). The columns are read
    out once: a field of a structured record costs a microsecond, and a flight has a
    hundred thousand events."""
    kinds, times = events["kind"].tolist(), events["t_us"].tolist()
    ids_a, ids_b = events["id_a"].tolist(), events["id_b"].tolist()
    values = np.array(events["v"])                      # the windows keep rows of this copy
    firsts = values[:, 0].tolist() if len(values) else []
    out, acc, gyro, current, prev = [], [], [], Window(0), 0
    for i, (kind, t) in enumerate(zip(kinds, times)):
        if kind == native.EV_ACCEL:
            acc.append((t - prev, values[i]))
        elif kind == native.EV_GYRO:
            gyro.append(values[i])
        elif kind == native.EV_TDOA:
            current.tdoa.append((t - prev, ids_a[i], ids_b[i], firsts[i]))
        elif kind == native.EV_STEP:
            # pair the k-th accelerometer with the k-th gyroscope sample of the window
            current.imu = [(dt, a, g) for (dt, a), g in zip(acc, gyro)]
            current.t_us = t
            out.append(current)
            acc, gyro, current, prev = [], [], Window(0), t
    return out


def imu_counts(ws: list[Window]) -> list[np.ndarray]:
    """Each window's IMU samples as the int16 counts on the wire (n x 6), quantised in
    one pass over the whole replay."""
    sizes = [len(w.imu) for w in ws]
    if not sum(sizes):
        return [np.zeros((0, protocol.IMU_AXES), np.int16) for _ in ws]
    counts = protocol.imu_counts([a for w in ws for _, a, _ in w.imu], [g for w in ws for _, _, g in w.imu])
    return np.split(counts, np.cumsum(sizes)[:-1])


def encode_windows(ws: list[Window], imu: protocol.ImuStream | None = None,
                   counts: list[np.ndarray] | None = None) -> list[list[bytes]]:
    """The windows on the wire, in order: each one's IMU samples (delta-coded on one
    stream), its TDOAs and the STEP. Encoded before the replay starts: the stream's
    state depends only on the windows before, so the bytes are those of encoding each
    window as it goes out."""
    imu = imu or protocol.ImuStream()
    counts = imu_counts(ws) if counts is None else counts
    values = [v for w in ws for _, _, _, v in w.tdoa]        # quantised in one pass too
    tdoa_counts = protocol.quantize(values, protocol.TDOA_LSB).tolist() if values else []
    out, first = [], 0
    for w, imu_messages in zip(ws, imu.encode_windows(counts)):
        out.append(imu_messages + protocol.tdoa_messages(w.tdoa, w.t_us, tdoa_counts[first:first + len(w.tdoa)]))
        first += len(w.tdoa)
    return out


_EVENT_KINDS = {"accel": native.EV_ACCEL, "gyro": native.EV_GYRO, "tdoa": native.EV_TDOA, "step": native.EV_STEP}


def wire_events(ws: list[Window]) -> np.ndarray:
    """The events a board makes of `ws` on the wire (quantised IMU stamped at the window
    start, packed TDOA), decoded by the Python twin of the board service, so the
    in-process library can be compared with any board to float32 precision."""
    board, rows = protocol.BoardView(), []
    for window in encode_windows(ws):
        for payload in window:
            rows += [(t, _EVENT_KINDS[kind], a, b, 0, np.asarray(v, np.float32))
                     for t, kind, a, b, v in board.events(payload)]
    return np.array(rows, dtype=native.EVENT_DTYPE)


@dataclass
class Session:
    """What a replay produced."""

    t0: float
    unit: str = "ns"
    timer_hz: int = 0
    estimates: list = field(default_factory=list)   # (t_us, pos, vel, quat, cov_diag)
    timing: list = field(default_factory=list)      # protocol.Timing
    counters: protocol.Counters | None = None
    statuses: list = field(default_factory=list)
    windows_sent: int = 0
    full_every: int = FULL_EVERY                    # counters and timing with every N-th window's answer
    loop_seconds: float | None = None               # the windows' exchange, from the first sent to the last answer
    recorder: object | None = None                  # a runrecord.RunRecorder, if recording
    realtime: RealTime | None = None                # real-time mode only


@dataclass
class RealTime:
    """Real-time mode bookkeeping: when each window went out, how long its answer took."""

    speed: float
    sent_at: dict = field(default_factory=dict)     # window t_us -> monotonic time its last byte was sent
    latency: dict = field(default_factory=dict)     # window t_us -> seconds to its estimate
    send_lag_max: float = 0.0                       # how far the host itself fell behind the schedule

    @property
    def period(self) -> float:
        return BUDGET_SECONDS / self.speed

    def summary(self) -> dict:
        t_us = np.array(list(self.latency.keys()), np.int64)
        lat = np.array(list(self.latency.values()), float) * 1e3
        missed = sorted(t for t in self.sent_at if t not in self.latency)
        late = np.sort(t_us[lat > self.period * 1e3])
        return {
            "speed": self.speed, "deadline_ms": self.period * 1e3, "windows_sent": len(self.sent_at),
            "latency_ms": ({"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                            "max": float(lat.max())} if len(lat) else None),
            # where the slowest and the late windows fall (µs from the replay's start): a
            # cold start (QEMU translating the code it runs first) or a stall mid-flight
            "slowest_t_us": int(t_us[np.argmax(lat)]) if len(lat) else None,
            "late_windows": len(late), "first_late_t_us": late[:10].tolist(),
            "missed_windows": len(missed), "first_missed_t_us": missed[:10],
            "host_send_lag_max_ms": self.send_lag_max * 1e3,
        }


def _expect(link: BoardLink, kind: type, what: str, timeout: float = REPLY_TIMEOUT_S, session: Session | None = None):
    """Wait for one message of `kind`; other messages are kept in the session (status) or logged."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = link.next_message(min(0.5, max(0.01, deadline - time.monotonic())))
        if isinstance(msg, kind):
            return msg
        if msg is not None:
            _note(link, msg, session)
    raise LinkError(f"{link.name}: no answer to {what} within {timeout:.0f} s (target stopped answering)")


def _keep_status(session: Session | None, msg: protocol.Status) -> None:
    if session is not None:
        session.statuses.append(msg)
        if session.recorder is not None:
            session.recorder.status(session.t0, "board", msg.code, f"frames ok {msg.frames_ok}, bad "
                                    f"{msg.frames_bad}, bytes dropped {msg.bytes_dropped}")


def _note(link: BoardLink, msg, session: Session | None) -> None:
    if isinstance(msg, protocol.Status):
        _keep_status(session, msg)
        if session is not None:
            if msg.code == protocol.STATUS_BOOT:
                raise LinkError(f"{link.name}: the board reset during the replay (window {session.windows_sent})")
            if msg.code == protocol.STATUS_RX_OVERFLOW and session.realtime is None:
                # lock-step: a lost window would only time out later, so say why now
                raise LinkError(f"{link.name}: the board {protocol.STATUS_MEANING[msg.code]} ({msg.bytes_dropped} "
                                f"bytes dropped by window {session.windows_sent}): the link brings bytes faster "
                                "than the board reads them (a smaller --lookahead sends less at once)")
        if msg.code != protocol.STATUS_BOOT:
            log.warning("%s: the board %s (frames ok %d, bad %d, bytes dropped %d)", link.name,
                        protocol.STATUS_MEANING.get(msg.code, f"sent status {msg.code}"), msg.frames_ok,
                        msg.frames_bad, msg.bytes_dropped)
    elif isinstance(msg, protocol.Ack) and msg.status != 0:
        raise LinkError(f"{link.name}: message 0x{msg.acked:02x} refused with status {msg.status}")


def handshake(link: BoardLink, attempts: int = 10) -> protocol.HelloReply:
    """Say hello until the board answers (a board still booting drops what it receives)."""
    for attempt in range(attempts):
        link.send([protocol.hello()])
        try:
            reply = _expect(link, protocol.HelloReply, "hello", timeout=1.0)
            break
        except LinkError:
            if attempt == attempts - 1:
                raise LinkError(f"{link.name}: no answer to hello after {attempts} attempts") from None
    if reply.version != protocol.VERSION:
        raise LinkError(f"{link.name}: protocol version {reply.version}, the rig speaks {protocol.VERSION}")
    if reply.api_version != protocol.ESTIMATOR_API:
        raise LinkError(f"{link.name}: estimator API {reply.api_version}, the rig's estimator is "
                        f"{protocol.ESTIMATOR_API} (reflash the board with this checkout's firmware)")
    return reply


def _acked(link: BoardLink, payloads: list[bytes], what: str, session: Session | None = None) -> None:
    """Send configuration messages one at a time, each acknowledged before the next. One
    that the board reports losing bytes of is sent again (it sets a value, so twice is
    as once), after a lone delimiter that ends whatever the board's parser holds."""
    for payload in payloads:
        for attempt in range(CONFIG_ATTEMPTS):
            link.send([payload], b"\x00" + protocol.frame(payload) if attempt else None)
            ack = _ack_unless_lost(link, what, session)
            if ack is not None:
                break
        else:
            raise LinkError(f"{link.name}: {what}: the board lost bytes of the same message {CONFIG_ATTEMPTS} times")
        if ack.status != 0:
            raise LinkError(f"{link.name}: {what} refused (status {ack.status})")


def _ack_unless_lost(link: BoardLink, what: str, session: Session | None) -> protocol.Ack | None:
    """The board's ACK; None when it reported losing bytes (a corrupt frame, a full
    receive buffer) before any ACK came and none came while the link settled."""
    deadline = time.monotonic() + REPLY_TIMEOUT_S
    while time.monotonic() < deadline:
        msg = link.next_message(min(0.5, max(0.01, deadline - time.monotonic())))
        if isinstance(msg, protocol.Ack):
            return msg
        if isinstance(msg, protocol.Status) and msg.code in LOSS_STATUSES:
            _keep_status(session, msg)
            log.warning("%s: the board %s during %s: sending it again", link.name,
                        protocol.STATUS_MEANING[msg.code], what)
            while (msg := link.next_message(SETTLE_S)) is not None:     # its other reports of the same loss
                if isinstance(msg, protocol.Ack):
                    return msg
                if isinstance(msg, protocol.Status):
                    _keep_status(session, msg)
            return None
        if msg is not None:
            _note(link, msg, None)          # not a window's: a boot here is the board still starting
    raise LinkError(f"{link.name}: no answer to {what} within {REPLY_TIMEOUT_S:.0f} s (target stopped answering)")


def configure(link: BoardLink, rec: Recording, params: native.EstimatorParams, model: BiasNet | None,
              hello: protocol.HelloReply, session: Session | None = None) -> None:
    """Parameters, anchors and the bias network, each message acknowledged; the board's
    reports of lost bytes meanwhile are kept in `session`."""
    _acked(link, [protocol.param(k, float(getattr(params, name)))
                  for k, (name, _) in enumerate(native.EstimatorParams._fields_)], "parameters", session)
    anchors = [a for a in rec.anchors if 0 <= a.id < hello.max_anchors]
    for a in rec.anchors:
        if a not in anchors:        # as the in-process estimator says (evaluate.make_estimator)
            log.warning("anchor id %d is outside the board's range 0..%d; ignored", a.id, hello.max_anchors - 1)
    _acked(link, [protocol.anchors_clear()] + [protocol.anchor(a.id, a.position, a.quaternion) for a in anchors],
           "anchors", session)
    if model is not None and params.use_bias_net:
        image = model.pack().tobytes()
        if len(image) != hello.net_size:
            raise LinkError(f"{link.name}: the board's network is {hello.net_size} bytes, the model {len(image)}")
        _acked(link, protocol.net_chunks(image) + [protocol.net_commit(len(image))], "bias network", session)


def run(link: BoardLink, rec: Recording, params: native.EstimatorParams, model: BiasNet | None = None,
        start: float | None = None, duration: float | None = None, progress=None,
        lookahead: int = LOOKAHEAD, recorder=None, speed: float | None = None,
        full_every: int = FULL_EVERY, start_pose: StartPose | None = None) -> Session:
    """Handshake, configure, reset at the start pose (the ground truth's, or `start_pose`
    given), then lock-step every window (with
    `lookahead` further windows already on the wire; 0 is strict send-and-wait), or, with
    a `speed`, send them in real time at that multiple of the recording's clock; every
    `full_every`-th window (and the last) is answered in full, the others briefly. With a
    `recorder` (runrecord.RunRecorder) every input and answer is recorded as it happens.
    A LinkError, or an interruption (KeyboardInterrupt: SIGINT, SIGTERM, SIGHUP), carries
    the partial session as `.session`."""
    t0 = start_time(rec, given=start_pose) if start is None else start
    pos, quat = initial_pose(rec, t0, start_pose)
    t_end = None if duration is None else t0 + duration
    session = Session(t0, recorder=recorder, full_every=full_every)
    try:
        hello = handshake(link)
        session.unit, session.timer_hz = hello.unit, hello.timer_hz
        if full_every > 1 and not hello.capabilities & protocol.CAP_BRIEF_STEP:
            raise LinkError(f"{link.name}: the board does not answer brief STEPs (compact answers); "
                            "replay it with every answer full")
        configure(link, rec, params, model, hello, session)
        wire = Wire(windows(build_events(rec, t0, t_end)), full_every)
        if speed is not None:
            _warm_up(link, wire, pos, quat, session)
        _acked(link, [protocol.reset(0, pos, quat)], "reset", session)
        if recorder is not None:            # the record starts when the first window is ready to go
            recorder.start(rec, t0, t_end if t_end is not None else t0 + len(wire) * BUDGET_SECONDS,
                           {"target": link.name, "start": t0, "windows": len(wire), "unit": hello.unit})
        began = time.perf_counter()
        try:
            with collector_paused():
                if speed is None:
                    _lock_step(link, wire, session, lookahead, progress)
                else:
                    session.realtime = RealTime(speed)
                    _real_time(link, wire, session, progress)
        finally:
            session.loop_seconds = time.perf_counter() - began
    except (LinkError, KeyboardInterrupt) as exc:
        exc.session = session
        raise
    return session


@contextlib.contextmanager
def collector_paused():
    """Python's cycle collector off while windows are exchanged: a full collection over
    the replay's data stopped the rig for 50 ms, long enough to make a real-time window
    late. The loop makes no reference cycles; what it allocates goes by reference count."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


class Wire:
    """The windows of a replay, encoded (and framed, for byte-stream links) once before it
    starts, and what sending window k means: its payloads on the link and its inputs in
    the run record. `full[k]`: window k is answered in full (every `full_every`-th
    window and the last), else its STEP is brief."""

    def __init__(self, ws: list[Window], full_every: int = FULL_EVERY) -> None:
        self.windows, self.counts = ws, imu_counts(ws)
        self.payloads = encode_windows(ws, counts=self.counts)
        self.full = [(k + 1) % full_every == 0 or k == len(ws) - 1 for k in range(len(ws))]
        for payloads, full in zip(self.payloads, self.full):
            if not full:
                payloads[-1] = protocol.brief(payloads[-1])
        self.framed = [protocol.frames(p) for p in self.payloads]

    def __len__(self) -> int:
        return len(self.windows)

    def send(self, link: BoardLink, k: int, session: Session) -> None:
        link.send(self.payloads[k], self.framed[k])
        if session.recorder is not None:
            w = self.windows[k]
            session.recorder.inputs(session.t0, self.windows[k - 1].t_us if k else 0, w.imu, self.counts[k], w.tdoa)


def _lock_step(link: BoardLink, wire: Wire, session: Session, lookahead: int, progress) -> None:
    sent, limit, ws = 0, budget(session.unit, session.timer_hz), wire.windows
    for k in progress(range(len(ws))) if progress else range(len(ws)):
        # Keep `lookahead` windows in flight: the board still answers them strictly in
        # order (results are those of strict lock-step), but its slow receive overlaps
        # with the previous answer.
        while sent < len(ws) and sent <= k + lookahead:
            wire.send(link, sent, session)
            sent += 1
        session.windows_sent = sent
        est = _expect(link, protocol.Estimate, f"window at {ws[k].t_us} us", session=session)
        att = _expect(link, protocol.Attitude, "attitude", session=session)
        counters = timing = None
        if wire.full[k]:
            counters = session.counters = _expect(link, protocol.Counters, "counters", session=session)
            timing = _expect(link, protocol.Timing, "timing", session=session)
            session.timing.append(timing)
        session.estimates.append((est.t_us, est.pos, est.vel, att.quat, att.cov_diag))
        if session.recorder is not None:
            session.recorder.answer(session.t0, est, att, counters, timing, session.unit, limit)


def _warm_up(link: BoardLink, wire: Wire, pos: np.ndarray, quat: np.ndarray, session: Session) -> None:
    """Before a real-time run is timed, the board flies its first WARM_UP_WINDOWS once,
    in lock-step, unrecorded; the flight then starts again from its RESET, which clears
    the state, the trust and the counters. So the run times the board in its steady
    state, not an emulator translating the code it meets first (QEMU's first window
    took 3.7-7.3 ms, against a p99 of 0.6 ms)."""
    _acked(link, [protocol.reset(0, pos, quat)], "reset", session)
    for k in range(min(WARM_UP_WINDOWS, len(wire))):
        link.send(wire.payloads[k], wire.framed[k])
        answer = [protocol.Estimate, protocol.Attitude] + ([protocol.Counters, protocol.Timing] if wire.full[k] else [])
        for kind in answer:
            _expect(link, kind, f"warm-up window {k}", session=session)


def _real_time(link: BoardLink, wire: Wire, session: Session, progress) -> None:
    """Send window k at start + k * period whatever the board does; take answers as
    they come; after the last window wait for the stragglers."""
    rt, ws = session.realtime, wire.windows
    collector = _AnswerCollector(link, session, {w.t_us for w, full in zip(ws, wire.full) if not full})
    begin = time.monotonic()
    for k in progress(range(len(ws))) if progress else range(len(ws)):
        due = begin + k * rt.period
        while (now := time.monotonic()) < due:
            collector.take(link.next_message(due - now))
        rt.send_lag_max = max(rt.send_lag_max, now - due)
        link.send(wire.payloads[k], wire.framed[k])
        rt.sent_at[ws[k].t_us] = time.monotonic()
        session.windows_sent = k + 1
        if session.recorder is not None:
            w = ws[k]
            session.recorder.inputs(session.t0, ws[k - 1].t_us if k else 0, w.imu, wire.counts[k], w.tdoa)
    last = time.monotonic()
    while len(rt.latency) < len(rt.sent_at) and time.monotonic() - last < REPLY_TIMEOUT_S:
        msg = link.next_message(0.1)
        if msg is not None:
            collector.take(msg)
            last = time.monotonic()


class _AnswerCollector:
    """Assembles a window's answer (estimate, attitude, counters, timing, in that order;
    estimate and attitude for a window in `brief`) from messages taken one at a time,
    and stamps its latency."""

    def __init__(self, link: BoardLink, session: Session, brief: set[int] = frozenset()) -> None:
        self.link, self.session, self.estimate, self.arrived, self.parts = link, session, None, 0.0, {}
        self.brief = brief

    def take(self, msg) -> None:
        if msg is None:
            return
        if isinstance(msg, protocol.Estimate):
            self.estimate, self.arrived, self.parts = msg, time.monotonic(), {}
        elif isinstance(msg, protocol.Attitude) and self.estimate is not None and self.estimate.t_us in self.brief:
            self.parts[type(msg)] = msg
            self._complete(None)
        elif isinstance(msg, (protocol.Attitude, protocol.Counters)) and self.estimate is not None:
            self.parts[type(msg)] = msg
        elif isinstance(msg, protocol.Timing) and self.estimate is not None:
            self._complete(msg)
        else:
            _note(self.link, msg, self.session)

    def _complete(self, timing: protocol.Timing | None) -> None:
        """The answer is whole: a brief one at its attitude (`timing` None), a full one
        at its timing."""
        s, est, rt = self.session, self.estimate, self.session.realtime
        att, counters = self.parts.get(protocol.Attitude), self.parts.get(protocol.Counters)
        self.estimate = None
        if att is None or (timing is not None and counters is None) or est.t_us not in rt.sent_at:
            log.warning("incomplete or unknown answer for window %d us dropped", est.t_us)
            return
        latency = self.arrived - rt.sent_at[est.t_us]
        rt.latency[est.t_us] = latency
        if timing is not None:
            s.counters = counters
            s.timing.append(timing)
        s.estimates.append((est.t_us, est.pos, est.vel, att.quat, att.cov_diag))
        if s.recorder is not None:
            s.recorder.answer(s.t0, est, att, counters, timing, s.unit, budget(s.unit, s.timer_hz), latency)


def budget(unit: str, timer_hz: int) -> float:
    """One 10 ms window in the target's unit (instructions are counted as cycles at 168 MHz)."""
    if unit == "ns":
        return BUDGET_SECONDS * 1e9
    if unit in ("cycles", "instructions"):
        return BUDGET_SECONDS * CPU_HZ
    return BUDGET_SECONDS * timer_hz


def timing_summary(session: Session) -> dict:
    window = np.array([t.window for t in session.timing], float)
    predict = np.array([t.predict for t in session.timing], float)
    n_tdoa = np.array([t.n_tdoa for t in session.timing], float)
    total = np.array([t.tdoa_total for t in session.timing], float)
    tdoa_max = np.array([t.tdoa_max for t in session.timing], float)
    limit = budget(session.unit, session.timer_hz)
    if not len(window):
        return {"unit": session.unit, "budget": limit, "windows": 0, "full_answer_every": session.full_every}
    per_tdoa = total[n_tdoa > 0] / n_tdoa[n_tdoa > 0]
    # With compact answers each timing is the worst of up to N windows: the maximum and
    # the overruns' presence are exact, the percentiles are of those maxima.
    return {
        "unit": session.unit, "budget": limit, "windows": int(len(window)), "full_answer_every": session.full_every,
        "window_p50": float(np.percentile(window, 50)), "window_p99": float(np.percentile(window, 99)),
        "window_max": float(window.max()), "window_max_fraction_of_budget": float(window.max() / limit),
        "overruns": int((window > limit).sum()),
        "per_call": {
            "predict": {"p50": float(np.median(predict)), "max": float(predict.max())},
            "tdoa_update": {"mean": float(per_tdoa.mean()) if len(per_tdoa) else 0.0,
                            "max": float(tdoa_max.max()), "calls": int(n_tdoa.sum())},
        },
    }


def board_link_summary(statuses: list) -> dict:
    """What the board said of its side of the link: how often it reported each problem
    and its totals at the last report (a board that never reported lost nothing)."""
    last = statuses[-1] if statuses else protocol.Status(0, 0, 0, 0)
    reports = Counter(protocol.STATUS_MEANING.get(s.code, f"status {s.code}")
                      for s in statuses if s.code != protocol.STATUS_BOOT)
    return {"frames_bad": last.frames_bad, "bytes_dropped": last.bytes_dropped, "reports": dict(sorted(reports.items()))}


def score(session: Session, rec: Recording, model: BiasNet | None = None) -> dict:
    """Accuracy of the board's answers against the ground truth; with the `model` it
    ran, the share of its corrections made outside where the model was trained
    (metrics.MetricsError when no estimate falls in the scored segment)."""
    from rig.estimator.evaluate import extrapolated_share

    t = session.t0 + np.array([e[0] for e in session.estimates], float) * 1e-6
    pos = np.array([e[1] for e in session.estimates], float).reshape(-1, 3)
    result = metrics.score(t, pos, rec.truth)
    if model is not None and model.region is not None:
        result["outside_trained_region"] = extrapolated_share(rec, t, pos, model)
    return result


def answers_summary(session: Session, model: BiasNet | None = None) -> dict:
    """What the board answered, scored or not: how many estimates, their timing, the
    real-time bookkeeping, its last counters and (with a `model`) the share of the
    correction it applied."""
    result = {"n_estimates": len(session.estimates), "timing": timing_summary(session)}
    if session.realtime is not None:
        result["realtime"] = session.realtime.summary()
    if session.counters is not None:
        c = session.counters
        result.update({"tdoa_accepted": c.accepted, "tdoa_downweighted": c.downweighted,
                       "tdoa_rejected": c.rejected, "tdoa_anchor_weighted": c.anchor_weighted,
                       "resets": c.resets, "imu_gaps": c.imu_gaps, "imu_lost": c.imu_lost})
        if model is not None:
            result["correction_trust"] = c.correction_trust
    return result
