"""Lock-step replay into real targets: the native program on a pty (under sanitizers)
and the STM32F405 firmware in QEMU, against the in-process library."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from rigtest import RIG

from rig.data.importer import load_any
from rig.estimator import native
from rig.estimator.evaluate import FULL_TRUST, build_events, load_model, make_estimator, start_time, truth_pose_at
from rig.hil import protocol, replay, targets
from rig.hil.job import score_run
from rig.hil.links import CrtpLink, LinkError, open_url

pytestmark = pytest.mark.slow        # left out of `make test-fast`


@pytest.fixture(scope="module")
def real_rec(data_dir: Path):
    return load_any(data_dir / "flights" / "0426-traj1")


def library_estimates(rec, params, model, duration: float) -> np.ndarray:
    """The in-process library fed exactly what a board decodes."""
    return _library_replay(rec, params, model, duration)[1]


def library_estimator(rec, params, model, duration: float) -> native.Estimator:
    """The in-process estimator after `library_estimates`' replay."""
    return _library_replay(rec, params, model, duration)[0]


def _library_replay(rec, params, model, duration: float) -> tuple[native.Estimator, np.ndarray]:
    t0 = start_time(rec)
    est = make_estimator(rec, params, model)
    pos, quat = truth_pose_at(rec, t0)
    est.reset(0, pos, protocol.quantize(quat, protocol.QUAT_LSB).astype(np.float32) * protocol.QUAT_LSB)
    return est, est.replay(replay.wire_events(replay.windows(build_events(rec, t0, t0 + duration))))


def run_target(link, rec, params, model, duration):
    try:
        return replay.run(link, rec, params, model, duration=duration)
    finally:
        link.close()


def positions(session) -> np.ndarray:
    return np.array([e[1] for e in session.estimates], np.float32)


def test_native_program_under_sanitizers_equals_the_library(default_rec) -> None:
    native.make("program-asan")
    params, model = native.params_with(), load_model()
    link = targets.open_native(native.ESTIMATOR_DIR / "build" / "estimator_native-asan")
    session = run_target(link, default_rec, params, model, duration=6.0)
    lib = library_estimates(default_rec, params, model, 6.0)
    assert len(session.estimates) == len(lib) >= 599
    np.testing.assert_array_equal(positions(session), lib["pos"])
    assert session.unit == "ns" and all(t.window > 0 for t in session.timing)


def test_the_board_applies_the_correction_trust_the_rig_sends_and_reports_it(default_rec) -> None:
    """trust_prior_n travels as PARAM 12 (since estimator API 2): a board told to apply the whole
    correction gives the library's estimates with the whole correction, not the default's;
    with the default, its COUNTERS carry the share the library applies (protocol 3)."""
    native.make("program")
    program, model = native.ESTIMATOR_DIR / "build" / "estimator_native", load_model()
    whole_params = native.params_with(trust_prior_n=FULL_TRUST)
    whole_board = run_target(targets.open_native(program), default_rec, whole_params, model, duration=6.0)
    whole = library_estimates(default_rec, whole_params, model, 6.0)
    trusted = library_estimates(default_rec, native.params_with(), model, 6.0)
    np.testing.assert_array_equal(positions(whole_board), whole["pos"])
    assert not np.array_equal(whole["pos"], trusted["pos"])
    assert whole_board.counters.trust == protocol.TRUST_FULL

    board = run_target(targets.open_native(program), default_rec, native.params_with(), model, duration=20.0)
    est = library_estimator(default_rec, native.params_with(), model, 20.0)    # long enough to move off 1
    assert board.counters.trust == round(est.correction_trust() * protocol.TRUST_FULL) < protocol.TRUST_FULL


def test_the_board_weights_blocked_anchors_as_the_rig_sends_it(data_dir: Path) -> None:
    """anchor_bias_c travels as PARAM 13 (since estimator API 4). On a real TDOA3 flight with
    a shelf in the room, the board told to weight nothing gives the library's estimates
    without the weighting, and the firmware in QEMU weights as the library does."""
    rec = load_any(data_dir / "flights" / "0426-traj6")
    native.make("program")
    program, model = native.ESTIMATOR_DIR / "build" / "estimator_native", load_model()
    unweighted_params = native.params_with(anchor_bias_c=0.0)
    unweighted_board = run_target(targets.open_native(program), rec, unweighted_params, model, duration=12.0)
    unweighted = library_estimates(rec, unweighted_params, model, 12.0)
    weighted = library_estimates(rec, native.params_with(), model, 12.0)
    np.testing.assert_array_equal(positions(unweighted_board), unweighted["pos"])
    assert np.abs(weighted["pos"] - unweighted["pos"]).max() > 0.01
    qemu = run_target(targets.open_qemu(), rec, native.params_with(), model, duration=12.0)
    np.testing.assert_allclose(positions(qemu), weighted["pos"], atol=2e-3)
    # and counts what it weighted, as the library does (COUNTERS, protocol 5)
    assert qemu.counters.anchor_weighted == weighted["counters"][-1]["tdoa_anchor_weighted"] > 0
    assert unweighted_board.counters.anchor_weighted == 0


def test_a_second_flight_on_the_same_board_starts_from_its_own_evidence(default_rec) -> None:
    """A bench board replays flight after flight without a restart: the RESET of each
    flight's start clears the correction trust and the counters, so the second replay
    repeats the first."""
    native.make("program")
    link = targets.open_native(native.ESTIMATOR_DIR / "build" / "estimator_native")
    params, model = native.params_with(), load_model()
    try:
        first = replay.run(link, default_rec, params, model, duration=20.0)
        second = replay.run(link, default_rec, params, model, duration=20.0)
    finally:
        link.close()
    assert first.counters.trust < protocol.TRUST_FULL
    assert second.counters == first.counters                     # its own counts too, trust and all
    np.testing.assert_array_equal(positions(second), positions(first))


def test_a_board_forgets_the_anchors_of_an_earlier_flight(default_rec) -> None:
    """A bench board configured for a flight with eight anchors, then for one with four:
    ANCHORS_CLEAR before the second flight's ANCHORs, so the board refuses TDOA with the
    other four as a fresh board does, instead of using the first flight's positions."""
    four = dataclasses.replace(default_rec, anchors=default_rec.anchors[:4])
    params = native.params_with(use_bias_net=0)
    fresh = run_target(targets.open_native(), four, params, None, duration=3.0)
    link = targets.open_native()
    try:
        replay.run(link, default_rec, params, None, duration=3.0)
        after = replay.run(link, four, params, None, duration=3.0)
    finally:
        link.close()
    assert fresh.counters.rejected > 0 and after.counters == fresh.counters
    np.testing.assert_array_equal(positions(after), positions(fresh))


def test_a_board_reports_each_sessions_own_link_losses(default_rec) -> None:
    """A HELLO starts a session and the board's link counts with it: two replays on the
    same native program, each with one configuration frame arriving corrupt (the board
    drops it and says so, the rig sends it again), each report one bad frame, not the
    second one two."""
    link = targets.open_native()
    original, state = link.send, {"corrupt": True}

    def corrupt_the_first_anchor(payloads, framed=None):
        if state["corrupt"] and payloads[0][0] == protocol.ANCHOR:
            state["corrupt"] = False
            frame = bytearray(protocol.frame(payloads[0]))
            frame[3] ^= 0x5A
            framed = bytes(frame)
        original(payloads, framed)

    link.send = corrupt_the_first_anchor
    try:
        runs = []
        for _ in range(2):
            state["corrupt"] = True
            runs.append(replay.run(link, default_rec, native.params_with(use_bias_net=0), None, duration=1.0))
    finally:
        link.close()
    for run in runs:
        assert score_run(run, default_rec)["board_link"] == {"frames_bad": 1, "bytes_dropped": 0,
                                                             "reports": {"dropped a corrupt frame": 1}}
    np.testing.assert_array_equal(positions(runs[1]), positions(runs[0]))


def test_cflib_udp_link_to_the_native_program_equals_the_library(default_rec) -> None:
    """The Crazyflie path: cflib's real udp:// link driver, CRTP app-channel packets, the
    native program's UDP endpoint (under sanitizers); with compact answers the same
    estimates come in about half the packets down."""
    native.make("program-asan")
    params, model = native.params_with(), load_model()
    lib = library_estimates(default_rec, params, model, 4.0)
    received = {}
    for full_every in (1, 10):
        link = targets.open_native_udp(native.ESTIMATOR_DIR / "build" / "estimator_native-asan")
        assert isinstance(link, CrtpLink) and link.name.startswith("crazyflie udp://127.0.0.1:")
        try:
            session = replay.run(link, default_rec, params, model, duration=4.0, full_every=full_every)
        finally:
            link.close()
        assert len(session.estimates) == len(lib) >= 399
        np.testing.assert_array_equal(positions(session), lib["pos"])
        assert session.counters.imu_lost == 0 and session.counters.steps >= len(lib)
        received[full_every] = link.bytes_received
    assert received[10] < 0.65 * received[1]


def test_compact_answers_report_the_worst_window_of_each_group(real_rec) -> None:
    """Brief STEPs into the firmware in QEMU (deterministic instruction counts): the same
    estimates; every 7th window and the last answered in full, each timing that of the
    most expensive window since the one before, so a budget check misses nothing."""
    params, model = native.params_with(), load_model()
    full = run_target(targets.open_qemu(), real_rec, params, model, duration=3.0)
    compact_link = targets.open_qemu()
    try:
        compact = replay.run(compact_link, real_rec, params, model, duration=3.0, full_every=7)
    finally:
        compact_link.close()
    np.testing.assert_array_equal(positions(compact), positions(full))
    n = len(full.timing)
    groups = [full.timing[k:k + 7] for k in range(0, n, 7)]
    assert len(compact.timing) == len(groups) == -(-n // 7)
    for got, group in zip(compact.timing, groups):
        worst = max(group, key=lambda t: t.window)
        assert (got.t_us, got.window, got.predict, got.tdoa_total) == (worst.t_us, worst.window, worst.predict,
                                                                       worst.tdoa_total)
    assert compact.counters == full.counters
    summary = replay.timing_summary(compact)
    assert summary["full_answer_every"] == 7 and summary["window_max"] == replay.timing_summary(full)["window_max"]


def test_a_board_without_brief_steps_is_refused_compact_answers(default_rec) -> None:
    """A board built before brief STEPs says so in its hello reply (the capability bit
    cleared here, as such a board would send it): the rig refuses instead of waiting for
    answers that never come."""
    link = targets.open_native()
    original = link.receive_payloads

    def older_board(timeout):
        return [bytes([*p[:11], p[11] & ~protocol.CAP_BRIEF_STEP]) if p[0] == protocol.HELLO_REPLY else p
                for p in original(timeout)]

    link.receive_payloads = older_board
    try:
        with pytest.raises(LinkError, match="does not answer brief STEPs"):
            replay.run(link, default_rec, native.params_with(use_bias_net=0), None, duration=1.0, full_every=2)
        session = replay.run(link, default_rec, native.params_with(use_bias_net=0), None, duration=1.0)
    finally:
        link.close()
    assert len(session.estimates) == len(session.timing) >= 99        # full answers it gives


@pytest.mark.parametrize("channel", targets.QEMU_CHANNELS)
def test_qemu_firmware_matches_native_on_a_real_flight_and_counts_are_deterministic(real_rec, channel: str) -> None:
    """The same firmware image through either link: the bulk link (semihosting, which the
    firmware takes only when QEMU writes its selector) and the emulated USART, the path
    a real board's bytes take."""
    params, model = native.params_with(), load_model()
    duration = 12.0 if channel == "bulk" else 6.0
    lib = library_estimates(real_rec, params, model, duration)
    first = run_target(targets.open_qemu(channel=channel), real_rec, params, model, duration)
    second = run_target(targets.open_qemu(channel=channel), real_rec, params, model, duration=2.0)
    assert first.unit == "instructions"
    np.testing.assert_allclose(positions(first), lib["pos"], atol=2e-3)
    # identical instruction counts run to run (QEMU -icount): the calls inside a STEP exactly
    calls = lambda s: [(t.predict, t.tdoa_total, t.tdoa_max) for t in s.timing]  # noqa: E731
    assert calls(first)[:len(second.timing)] == calls(second)
    a = np.array([t.window for t in first.timing[:len(second.timing)]], float)
    b = np.array([t.window for t in second.timing], float)
    if channel == "bulk":       # no byte interrupts: whole windows are identical too
        np.testing.assert_array_equal(a, b)
    else:
        # the window also holds the receive interrupts' entry and exit, a few instructions
        # per byte, and how many bytes land inside it depends on the host's timing (1.07 %
        # apart once, on a loaded 2-core machine with 200 k-instruction windows)
        assert np.abs(a - b).max() <= 0.02 * a.max()
    summary = replay.timing_summary(first)
    assert summary["window_max"] <= 0.2 * summary["budget"]
    assert summary["per_call"]["tdoa_update"]["calls"] > 100


def test_cli_replay_writes_metrics_and_asserts(tmp_path: Path, data_dir: Path) -> None:
    flight = data_dir / "flights" / "0426-traj1"
    ok = subprocess.run([*RIG, "replay", str(flight), "--target", "native", "--out", str(tmp_path / "a"),
                         "--duration", "15", "--assert-rmse", "1.0", "--assert-budget", "1.0"],
                        capture_output=True, text=True, timeout=300)
    # the native program's windows are host wall-clock time (a sanitizer build sharing the
    # machine): the whole 10 ms budget here; the tight limits are the QEMU target's, in
    # deterministic instruction counts
    assert ok.returncode == 0, ok.stderr
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    for key in ("rmse_3d", "rmse_xyz", "n_estimates"):
        assert key in metrics
    # a shipped-model training flight: every correction inside where the model was trained
    assert metrics["outside_trained_region"] == 0.0 and "outside where the model was trained" in ok.stdout
    timing = metrics["timing"]
    for key in ("unit", "budget", "window_p50", "window_p99", "window_max", "overruns", "per_call"):
        assert key in timing
    assert timing["unit"] == "ns" and timing["budget"] == 1e7
    bad = subprocess.run([*RIG, "replay", str(flight), "--target", "native", "--out", str(tmp_path / "b"),
                          "--duration", "15", "--assert-rmse", "0.001"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and "assertion failed: rmse_3d" in bad.stderr
    over = subprocess.run([*RIG, "replay", str(flight), "--target", "native", "--out", str(tmp_path / "c"),
                           "--duration", "3", "--assert-budget", "1e-6"], capture_output=True, text=True, timeout=300)
    assert over.returncode == 1 and "of the budget" in over.stderr


def test_corrupt_bytes_mid_stream_are_dropped_and_counted(default_rec) -> None:
    params = native.params_with(use_bias_net=0)
    link = targets.open_native()
    original = link.send
    sent = {"n": 0}

    def noisy_send(payloads, framed=None):
        sent["n"] += 1
        if sent["n"] % 50 == 0:  # a burst of line noise between windows
            link.port.write(bytes(range(1, 40)) + b"\x00")
        original(payloads, framed)

    link.send = noisy_send
    session = run_target(link, default_rec, params, None, duration=5.0)
    clean = library_estimates(default_rec, params, None, 5.0)
    np.testing.assert_array_equal(positions(session), clean["pos"])
    bad = [s for s in session.statuses if s.code == protocol.STATUS_BAD_FRAME]
    assert bad and bad[-1].frames_bad >= 5


def test_a_target_that_stops_answering_fails_clearly_within_seconds(default_rec) -> None:
    link = targets.open_native()
    original = link.send
    state = {"n": 0, "stopped_at": None}

    def send_then_freeze(payloads, framed=None):
        state["n"] += 1
        original(payloads, framed)
        if state["n"] == 100:  # mid-replay the board hangs
            os.kill(link.process.pid, signal.SIGSTOP)
            state["stopped_at"] = time.monotonic()

    link.send = send_then_freeze
    try:
        with pytest.raises(LinkError, match="stopped answering"):
            replay.run(link, default_rec, native.params_with(use_bias_net=0), None, duration=5.0)
        assert time.monotonic() - state["stopped_at"] < 10
    finally:
        os.kill(link.process.pid, signal.SIGCONT)
        link.close()


def test_a_board_that_stops_reading_fails_the_write_instead_of_blocking_for_ever() -> None:
    """A real pty whose other end nobody reads (a board stuck with its receive
    interrupt off): once its buffer is full the write gives up with a clear error."""
    board_side, rig_side = os.openpty()
    link = open_url(os.ttyname(rig_side), write_timeout=0.5)
    try:
        began = time.monotonic()
        with pytest.raises(LinkError, match="the board stopped reading"):
            for _ in range(10_000):                  # 1 MB of hellos: far beyond a pty's buffer
                link.send([protocol.hello()] * 20)
        assert time.monotonic() - began < 5.0 and link.bytes_sent > 0
    finally:
        link.close()
        os.close(board_side)
        os.close(rig_side)


@pytest.mark.parametrize("speed", [None, 1.0], ids=["lockstep", "realtime"])
def test_a_board_that_resets_mid_replay_fails_clearly_and_keeps_the_record(default_rec, tmp_path: Path,
                                                                           speed: float | None) -> None:
    """A real reset: QEMU's system_reset reboots the firmware mid-replay; the board
    announces its boot, the replay stops with a clear error and the run record keeps
    every estimate received before, and the board's boot status (in lock-step, and in
    real time, where answers are taken as they come)."""
    from rig.hil.runrecord import TOPIC_ESTIMATE, TOPIC_STATUS, RunRecorder, read_run

    link = targets.open_qemu()
    original, count = link.send, {"n": 0}

    def send_then_reset(payloads, framed=None):
        count["n"] += 1
        original(payloads, framed)
        if count["n"] == 300:
            link.reset_board()

    link.send = send_then_reset
    recorder = RunRecorder(tmp_path / "run.mcap")
    try:
        with pytest.raises(LinkError, match="reset during the replay") as failure:
            replay.run(link, default_rec, native.params_with(use_bias_net=0), None, duration=8.0, recorder=recorder,
                       speed=speed)
    finally:
        link.close()
        recorder.close()
    record = read_run(tmp_path / "run.mcap")
    received = failure.value.session.estimates
    assert 200 < len(received) < 300 and len(record[TOPIC_ESTIMATE]) == len(received)
    assert any(r["code"] == protocol.STATUS_BOOT for r in record[TOPIC_STATUS])


def test_an_anchor_id_beyond_the_estimators_range_is_ignored_with_a_warning(default_rec, caplog) -> None:
    """In process and on a board alike: the anchor is not set, the rig says so, the
    replay goes on with the others."""
    rec = dataclasses.replace(default_rec, anchors=[*default_rec.anchors,
                                                    dataclasses.replace(default_rec.anchors[0], id=20)])
    params = native.params_with(use_bias_net=0)
    with caplog.at_level(logging.WARNING):
        make_estimator(rec, params, None)
        session = run_target(targets.open_native(), rec, params, None, duration=1.0)
    assert "anchor id 20 is outside the estimator's range 0..15; ignored" in caplog.text
    assert "anchor id 20 is outside the board's range 0..15; ignored" in caplog.text
    assert len(session.estimates) == 100


def test_a_configuration_message_the_board_lost_bytes_of_is_sent_again(default_rec) -> None:
    """Line noise on the native program's pty: the first copy of each anchor message
    arrives with a byte flipped; the board drops the frame and says so, the rig sends it
    again, and the replay gives the estimates of a clean link. A board that loses every
    copy fails the replay, naming the message."""
    params = native.params_with(use_bias_net=0)
    clean = run_target(targets.open_native(), default_rec, params, None, duration=2.0)

    def noisy(link, copies_lost: int):
        original, seen = link.send, {}

        def send(payloads, framed=None):
            data = framed or protocol.frames(payloads)
            if payloads[0][0] == protocol.ANCHOR and seen.setdefault(payloads[0], 0) < copies_lost:
                seen[payloads[0]] += 1
                data = data[:3] + bytes([data[3] ^ 0x5A]) + data[4:]
            original(payloads, data)
        link.send = send
        return link

    session = run_target(noisy(targets.open_native(), 1), default_rec, params, None, duration=2.0)
    np.testing.assert_array_equal(positions(session), positions(clean))
    assert sum(r.code == protocol.STATUS_BAD_FRAME for r in session.statuses) >= len(default_rec.anchors)
    with pytest.raises(LinkError, match="anchors: the board lost bytes of the same message 3 times"):
        run_target(noisy(targets.open_native(), 3), default_rec, params, None, duration=2.0)


def _small_ring_firmware() -> Path:
    """The firmware with a 16-byte receive ring: a window's bytes overflow it while the
    board works on the window's first messages."""
    native.make("firmware", "BUILD=build/small-ring", "FW_DEFS=-DBOARD_RX_RING=16u")
    return native.ESTIMATOR_DIR / "build" / "small-ring" / "stm32f405" / "firmware.elf"


def test_a_board_whose_receive_ring_overflows_says_so(default_rec) -> None:
    """The real firmware in QEMU, its receive ring made small: with 8 windows in flight
    bytes are lost in the USART interrupt and the board reports it (STATUS RX_OVERFLOW
    with its bytes dropped); lock-step stops on the report with that reason instead of
    timing out on a lost window. (On a loaded host the emulated USART can outrun the
    16-byte ring during configuration already: the rig then sends each message three
    times and fails naming it.)"""
    link = targets.open_qemu(_small_ring_firmware(), channel="usart")
    try:
        with pytest.raises(LinkError, match="lost bytes") as failure:
            replay.run(link, default_rec, native.params_with(), load_model(), duration=3.0, lookahead=8)
    finally:
        link.close()
    reports = failure.value.session.statuses
    assert any(r.code == protocol.STATUS_RX_OVERFLOW and r.bytes_dropped > 0 for r in reports)
    assert score_run(failure.value.session, default_rec)["board_link"]["bytes_dropped"] == reports[-1].bytes_dropped


@pytest.mark.serial
def test_real_time_mode_gives_the_lock_step_estimates_and_counts_a_lost_window(default_rec) -> None:
    """Real time at 2x on the native program: every window answered in order with the
    same estimates as lock-step, latencies measured; a window lost on the link (the
    radio dropped it) and one whose STEP arrived corrupt (the board drops the frame and
    says so) are counted as missed, the board's report kept, and the replay carries on."""
    params = native.params_with(use_bias_net=0)
    lock = run_target(targets.open_native(), default_rec, params, None, duration=6.0)
    link, original, calls = targets.open_native(), None, {"n": 0}
    original = link.send

    def lose_two_windows(payloads, framed=None):
        calls["n"] += 1             # the 300th and 400th sends are windows (handshake and set-up come first)
        if calls["n"] == 400:       # a byte of the STEP's frame (the last) flipped
            framed = framed[:-3] + bytes([framed[-3] ^ 0x5A]) + framed[-2:]
        if calls["n"] != 300:
            original(payloads, framed)

    link.send = lose_two_windows
    try:
        rt = replay.run(link, default_rec, params, None, duration=6.0, speed=2.0)
    finally:
        link.close()
    summary = rt.realtime.summary()
    assert summary["windows_sent"] == len(lock.estimates)
    assert summary["missed_windows"] == 2 and len(rt.estimates) == len(lock.estimates) - 2
    assert score_run(rt, default_rec)["board_link"] == {"frames_bad": 1, "bytes_dropped": 0,
                                                         "reports": {"dropped a corrupt frame": 1}}
    assert 0 < summary["latency_ms"]["p50"] < summary["deadline_ms"]
    lost = summary["first_missed_t_us"][0]
    same = [e for e in lock.estimates if e[0] < lost]
    np.testing.assert_array_equal(positions(rt)[:len(same)], np.array([e[1] for e in same], np.float32))


@pytest.mark.serial
def test_real_time_mode_with_compact_answers_times_every_window(default_rec) -> None:
    """Real time at 2x with compact answers: a brief window's answer ends at its
    attitude, so every window still has its latency and its estimate."""
    params = native.params_with(use_bias_net=0)
    lock = run_target(targets.open_native(), default_rec, params, None, duration=3.0)
    link = targets.open_native()
    try:
        rt = replay.run(link, default_rec, params, None, duration=3.0, speed=2.0, full_every=5)
    finally:
        link.close()
    summary = rt.realtime.summary()
    assert summary["windows_sent"] == len(rt.estimates) == len(lock.estimates) == len(rt.realtime.latency)
    assert summary["missed_windows"] == 0 and len(rt.timing) == -(-len(lock.estimates) // 5)
    np.testing.assert_array_equal(positions(rt), positions(lock))
    assert rt.counters == lock.counters


@pytest.mark.serial
def test_real_time_mode_exposes_the_slow_qemu_usart_that_lock_step_hides(tmp_path: Path) -> None:
    """QEMU's emulated UART takes one byte per turn of its main loop: lock-step hides it
    (every window still meets the board's budget), real time at 10x the recording's clock
    shows the estimates falling ever further behind; --assert-deadlines fails the run, the
    run record carries each window's latency, and a byte the board had no room for is reported. The UART's pace depends on the host (2.7 to
    5 ms a window measured, faster with other work beside it; at 3x a loaded CI run kept
    up with 60 % of the windows), so the run is 10x, a 1 ms deadline."""
    out = tmp_path / "rt"
    proc = subprocess.run([*RIG, "replay", "recordings/default.mcap", "--target", "qemu-usart", "--duration", "8",
                           "--mode", "realtime", "--speed", "10", "--assert-deadlines", "--assert-budget", "0.2",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "late windows" in proc.stderr and "budget" not in proc.stderr
    result = json.loads((out / "metrics.json").read_text())
    rt = result["realtime"]
    assert result["mode"] == "realtime" and result["timing"]["overruns"] == 0
    # behind on most windows: answered late, or not at all before the run ended (how the two
    # split depends on the host: 557 and 242 of 799 here, 280 and 519 on a loaded CI run)
    assert rt["late_windows"] > 0 and rt["late_windows"] + rt["missed_windows"] > rt["windows_sent"] // 2, rt
    assert result["n_estimates"] + rt["missed_windows"] == rt["windows_sent"]
    # the backlog waits in the link, or (when the emulator brings bytes faster than the firmware
    # drains them: 0 to 13 000 bytes on this host) overruns the board's receive buffer: never silently
    board = result["board_link"]
    assert board["bytes_dropped"] == 0 or board["reports"].get("lost bytes to a full receive buffer", 0) > 0, board
    assert rt["latency_ms"]["max"] > 10 * rt["deadline_ms"]       # a backlog that grows, not jitter
    from rig.hil.runrecord import TOPIC_TIMING, read_run
    latency = [r["latency_ms"] for r in read_run(out / "run.mcap")[TOPIC_TIMING]]
    assert len(latency) == result["n_estimates"] and max(latency) == pytest.approx(rt["latency_ms"]["max"])


@pytest.mark.serial
def test_real_time_into_qemu_through_the_bulk_link_meets_its_deadlines(tmp_path: Path) -> None:
    """Real time at 1x into the firmware in QEMU, through the bulk link: no window missed
    and no backlog, so what a real-time run measures is the board, not the emulated link.
    A shared CI host once answered one window of 2000 after 11.6 ms (p99 0.5 ms; it
    may have been the first, then slow while QEMU translated the code, which the warm-up
    now does before the clock starts), so 1 % may be late; the USART's backlog makes half
    of them late."""
    out = tmp_path / "rt"
    proc = subprocess.run([*RIG, "replay", "recordings/default.mcap", "--target", "qemu", "--mode", "realtime",
                           "--duration", "20", "--assert-deadlines", "--late-allowed", "0.01", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rt = json.loads((out / "metrics.json").read_text())["realtime"]
    assert rt["windows_sent"] == 2000 and rt["missed_windows"] == 0 and rt["late_windows"] <= 20
    assert rt["latency_ms"]["p99"] < rt["deadline_ms"]


@pytest.mark.parametrize("mode", [[], ["--mode", "realtime", "--speed", "2"]], ids=["lockstep", "realtime"])
def test_a_run_too_short_to_score_still_reports_and_fails_its_accuracy_assertion(tmp_path: Path, mode: list[str]) -> None:
    """All but the accuracy: the timing, the board's counters and, in real time, the
    latencies (once lost with the accuracy)."""
    proc = subprocess.run([*RIG, "replay", "recordings/default.mcap", "--target", "native", "--duration", "3", *mode,
                           "--assert-rmse", "0.3", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "no rmse_3d to compare" in proc.stderr, proc.stderr
    result = json.loads((tmp_path / "metrics.json").read_text())
    assert result["n_estimates"] == 299 and "scored segment" in result["score_error"]   # windows in 3 s
    assert result["timing"]["windows"] == 299 and (tmp_path / "report.html").exists()
    assert result["tdoa_accepted"] > 0 and 0.0 <= result["correction_trust"] <= 1.0
    if mode:
        assert result["realtime"]["windows_sent"] == 299 and result["realtime"]["missed_windows"] == 0
        assert "real time x2: latency" in proc.stdout


def test_the_cycle_collector_is_paused_only_while_windows_are_exchanged() -> None:
    import gc

    assert gc.isenabled()
    with pytest.raises(LinkError):
        with replay.collector_paused():
            assert not gc.isenabled()
            raise LinkError("board gone")
    assert gc.isenabled()
    gc.disable()                   # a caller that keeps it off keeps it off
    try:
        with replay.collector_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()
