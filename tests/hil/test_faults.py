"""A replay stopped or misused loses nothing: SIGTERM and SIGHUP stop the rig as Ctrl-C
does, with the run record finished, metrics.json saying how the run ended and no board
process left behind; option values a replay cannot use are refused before anything
starts; JSON is written whole or not at all."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rigtest import RIG, ROOT, alive, board_processes, exit_status, finished_mcap, run_rig, start

from rig.data.files import write_json
from rig.hil.runrecord import read_run


@pytest.mark.slow
@pytest.mark.parametrize("signum, status", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_signal_mid_replay_finishes_the_record_says_how_it_ended_and_leaves_no_board(
        tmp_path: Path, signum: int, status: int) -> None:
    out = tmp_path / "run"
    replay = start(*RIG, "replay", "recordings/default.mcap", "--target", "native", "--mode", "realtime",
                   "--out", str(out))
    record, deadline = out / "run.mcap", time.monotonic() + 120
    while time.monotonic() < deadline and (not record.exists() or record.stat().st_size < 30_000):
        time.sleep(0.2)                                    # anchors and ground truth are on disk
    time.sleep(3.0)                                        # windows are flowing
    boards = board_processes(parent=replay.pid)
    assert len(boards) == 1
    replay.send_signal(signum)
    assert exit_status(replay, 60) == status
    assert signal.Signals(signum).name in replay.stderr.read()
    assert finished_mcap(out / "run.mcap")                # the stock reader opens it
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ended"] == "interrupted" and signal.Signals(signum).name in metrics["error"]
    assert 0 < metrics["n_estimates"] == len(read_run(out / "run.mcap")["/run/estimate"])
    assert read_run(out / "run.mcap")["/run/status"][-1]["message"].startswith("interrupted")
    time.sleep(0.5)
    assert not alive(boards), "the native program outlived the rig"


@pytest.mark.slow
@pytest.mark.parametrize("option, rule", [
    (["--target", "nonsense"], "unknown target 'nonsense'"),
    (["--board", "*"], "board name '*'"),
    (["--target", "zenoh:a/b"], "board name 'a/b'"),
    (["--duration", "0"], "--duration must be a positive number"),
    (["--duration", "-3"], "--duration must be a positive number"),
    (["--lookahead", "-1"], "--lookahead must be 0"),
    (["--full-answer-every", "0"], "--full-answer-every must be 1"),
    (["--late-allowed", "1.5"], "--late-allowed must be a share"),
    (["--late-allowed", "nan"], "--late-allowed must be a share"),
    (["--start", "1e9"], "is past the end of"),
    (["--start-yaw", "90"], "--start-yaw needs --start-position"),
    (["--start-position", "1.5", "nan", "0"], "three finite coordinates"),
    (["--target", "zenoh:b0", "--zenoh-connect", "nope"], "zenoh endpoint 'nope' is not PROTOCOL/ADDRESS"),
])
def test_an_option_value_a_replay_cannot_use_is_refused_before_anything_starts(tmp_path: Path, option: list[str],
                                                                               rule: str) -> None:
    began = time.monotonic()
    proc = run_rig("replay", "recordings/default.mcap", "--out", str(tmp_path / "run"), *option, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert rule in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "run").exists()                # nothing written
    assert time.monotonic() - began < 30                  # and no board waited for


@pytest.mark.parametrize("command", [["replay", "--target", "native", "--start", "1", "--out"], ["evaluate", "--json"]])
def test_a_recording_without_ground_truth_is_refused_before_anything_starts(tmp_path: Path,
                                                                              command: list[str]) -> None:
    from dataclasses import replace

    from rig.data.recording import PoseSeries, read_recording, write_recording

    recording = tmp_path / "no-truth.mcap"
    write_recording(replace(read_recording(ROOT / "recordings" / "default.mcap"), truth=PoseSeries.empty()), recording)
    proc = run_rig(command[0], str(recording), *command[1:], str(tmp_path / "out"), timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "no ground truth on /truth/pose" in proc.stderr and "Traceback" not in proc.stderr
    assert "--start-position X Y Z" in proc.stderr           # and says how to replay it anyway
    assert not (tmp_path / "out").exists()


def test_a_recording_without_ground_truth_is_replayed_from_where_the_drone_stood_timed_not_scored(
        tmp_path: Path) -> None:
    from dataclasses import replace

    from rig.data.recording import PoseSeries, read_recording, write_recording
    from rig.estimator import metrics as scoring

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    write_recording(replace(rec, truth=PoseSeries.empty()), tmp_path / "no-truth.mcap")
    stood = rec.truth.position[0]                       # where the drone stood, as its pilot would say
    proc = run_rig("replay", str(tmp_path / "no-truth.mcap"), "--target", "native", "--out", str(tmp_path / "run"),
                   "--start-position", *map(str, stood), "--start-yaw", "0", check=True)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert "rmse_3d" not in metrics and "no ground truth" in metrics["score_error"]
    assert "not scored" in proc.stdout and metrics["timing"]["windows"] == metrics["n_estimates"]
    assert metrics["start_pose"] == {"position": stood.tolist(), "yaw_deg": 0.0}
    page = (tmp_path / "run" / "report.html").read_text()
    assert "<td>not scored</td><td>the recording has no ground truth" in page and "start pose given" in page
    # from its first IMU sample, not from a take-off only the ground truth could tell
    assert abs(metrics["n_estimates"] - (rec.time_span()[1] - max(rec.accel.t[0], rec.gyro.t[0])) / 0.01) <= 1
    estimates = read_run(tmp_path / "run" / "run.mcap")["/run/estimate"]
    t = [e["t"] for e in estimates]
    position = [[e["position"][axis] for axis in "xyz"] for e in estimates]
    assert scoring.score(t, position, rec.truth)["rmse_3d"] < 0.3      # it tracked the flight it was not told

    failed = run_rig("replay", str(tmp_path / "no-truth.mcap"), "--target", "native", "--out", str(tmp_path / "a"),
                     "--start-position", *map(str, stood), "--duration", "5", "--assert-rmse", "0.4")
    assert failed.returncode == 1 and "no rmse_3d to compare with 0.4 m" in failed.stderr


@pytest.mark.slow
def test_the_firmware_in_qemu_answers_a_given_start_as_the_native_program_does(tmp_path: Path) -> None:
    from dataclasses import replace

    import numpy as np

    from rig.data.recording import PoseSeries, read_recording, write_recording
    from rig.estimator.metrics import interpolate_positions

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    write_recording(replace(rec, truth=PoseSeries.empty()), tmp_path / "field.mcap")
    final = {}
    for target in ("native", "qemu"):
        run_rig("replay", str(tmp_path / "field.mcap"), "--target", target, "--out", str(tmp_path / target),
                "--duration", "15", "--start-position", "1.5", "0", "0.03", "--start-yaw", "30", check=True)
        estimates = read_run(tmp_path / target / "run.mcap")["/run/estimate"]
        assert len(estimates) == 1499                    # a STEP every 10 ms after the start, within 15 s
        final[target] = [estimates[-1]["position"][axis] for axis in "xyz"]
    assert max(abs(a - b) for a, b in zip(final["native"], final["qemu"])) < 0.002
    truth = interpolate_positions(rec.truth, np.array([estimates[-1]["t"]]))[0]
    assert np.linalg.norm(np.array(final["native"]) - truth) < 0.3     # in the air, 15 s in, where the flight is


def test_a_replay_reports_the_windows_the_board_had_no_imu_sample_for(tmp_path: Path) -> None:
    from dataclasses import replace

    from rig.data.recording import Vec3Series, read_recording, write_recording

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    gap = (rec.accel.t > 5.0) & (rec.accel.t < 7.0)               # two seconds without IMU, mid-replay
    accel, gyro = (Vec3Series(s.t[~gap], s.xyz[~gap]) for s in (rec.accel, rec.gyro))
    write_recording(replace(rec, accel=accel, gyro=gyro), tmp_path / "gap.mcap")
    proc = run_rig("replay", str(tmp_path / "gap.mcap"), "--target", "native", "--duration", "10",
                   "--out", str(tmp_path / "run"), check=True)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert 190 <= metrics["imu_gaps"] <= 201 and metrics["imu_lost"] == 0
    assert f"IMU: {metrics['imu_gaps']} windows of 10 ms without a sample" in proc.stderr


def test_json_is_written_whole_or_not_at_all(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "metrics.json"
    write_json(path, {"rmse_3d": 0.2})
    real_replace = os.replace

    def full_disk(source, destination):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OSError, match=f"cannot write {path}"):
        write_json(path, {"rmse_3d": 0.3})
    monkeypatch.setattr(os, "replace", real_replace)
    assert json.loads(path.read_text()) == {"rmse_3d": 0.2}    # what was there stays
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]   # no temporary left behind


def test_json_is_strict_a_figure_that_is_not_finite_is_null(tmp_path: Path) -> None:
    """A diverged run's RMSE is infinite and its mean error NaN: Python would write
    `Infinity` and `NaN`, which jq, JavaScript and most CI tools refuse."""
    import numpy as np

    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")

    write_json(tmp_path / "m.json", {"rmse_3d": float("inf"), "mean_xyz": [float("nan"), 0.1, np.float64("-inf")],
                                     "timing": {"window_max": 3.0, "per_call": {"predict": {"max": float("nan")}}}})
    data = json.loads((tmp_path / "m.json").read_text(), parse_constant=refuse)
    assert data == {"rmse_3d": None, "mean_xyz": [None, 0.1, None],
                    "timing": {"window_max": 3.0, "per_call": {"predict": {"max": None}}}}


def test_every_key_replay_and_evaluate_write_is_in_the_reference(tmp_path: Path) -> None:
    """docs/reference/metrics.md is what CI checks outside the project read: it names
    every top-level key a real-time replay's metrics.json and `rig evaluate --json` hold."""
    run_rig("replay", "recordings/default.mcap", "--target", "native", "--mode", "realtime", "--speed", "8",
            "--duration", "8", "--out", str(tmp_path / "run"), check=True)
    run_rig("evaluate", "recordings/default.mcap", "--json", str(tmp_path / "e.json"), check=True)
    reference = (ROOT / "docs" / "reference" / "metrics.md").read_text()
    keys = set(json.loads((tmp_path / "run" / "metrics.json").read_text())) | set(
        json.loads((tmp_path / "e.json").read_text()))
    assert sorted(k for k in keys if f"`{k}`" not in reference) == []


@pytest.mark.slow
def test_junit_xml_has_a_testcase_per_board_and_assertion_and_failures_carry_the_figure(tmp_path: Path) -> None:
    import xml.etree.ElementTree as ElementTree

    junit = tmp_path / "junit.xml"
    proc = run_rig("replay", "recordings/default.mcap", "--target", "native", "--duration", "12", "--out",
                   str(tmp_path / "run"), "--assert-rmse", "0.0001", "--assert-budget", "0.9", "--junit-xml", str(junit))
    assert proc.returncode == 1
    suite = ElementTree.parse(junit).getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("failures")) == ("3", "1")
    cases = {case.get("name"): case for case in suite.iter("testcase")}
    assert set(cases) == {"replay", "rmse_3d", "budget window_max"}
    failure = cases["rmse_3d"].find("failure")
    assert failure is not None and re.fullmatch(r"rmse_3d 0\.\d{3} m > 0\.0001 m", failure.get("message"))
    assert cases["replay"].find("failure") is None and cases["budget window_max"].find("failure") is None


@pytest.mark.slow
def test_exit_statuses_tell_a_board_that_failed_from_bad_input_and_from_a_bug(tmp_path: Path, monkeypatch,
                                                                              capfd) -> None:
    lost = run_rig("replay", "recordings/default.mcap", "--target", "serial:/dev/nonexistent-board", "--out",
                   str(tmp_path / "run"), "--duration", "2")
    assert lost.returncode == 3 and "cannot open /dev/nonexistent-board" in lost.stderr
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["ended"] == "board_lost"

    import rig.cli
    import rig.cli.estimator

    def bug(args):
        return 1 / 0
    monkeypatch.setattr(rig.cli.estimator, "cmd_size", bug)
    monkeypatch.chdir(tmp_path)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        assert rig.cli.main(["size"]) == 4
    finally:
        for s, handler in handlers.items():            # the rig's own handlers stay with the rig
            signal.signal(s, handler)
    said = capfd.readouterr().err
    assert "internal error: ZeroDivisionError" in said and "rig-error.log" in said and "Traceback" not in said
    assert "ZeroDivisionError" in (tmp_path / "rig-error.log").read_text()


def test_a_signal_inside_a_critical_section_waits_for_its_end() -> None:
    from rig.hil.interrupt import Interrupted, critical, stop_on_signals

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    stop_on_signals()
    done = []
    try:
        with pytest.raises(Interrupted) as stopped:
            with critical():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)                           # the handler has run: the section goes on
                done.append("the whole write")
        assert done == ["the whole write"] and stopped.value.signum == signal.SIGTERM
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)


def test_a_signal_while_the_record_is_closed_leaves_it_whole(tmp_path: Path) -> None:
    """A Ctrl-C that lands between writing the held messages and finishing the file (a
    replay through QEMU's bulk link is often there when the user gives up waiting)
    takes effect once the file is finished."""
    from rigtest import finished_mcap

    from rig.hil.interrupt import Interrupted, stop_on_signals
    from rig.hil.runrecord import RunRecorder, read_run

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    stop_on_signals()
    try:
        recorder = RunRecorder(tmp_path / "run.mcap")
        recorder.status(1.0, "rig", 0, "a note")
        flush = recorder.flush

        def flush_then_ctrl_c() -> None:
            flush()
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)                               # the handler has run
        recorder.flush = flush_then_ctrl_c
        with pytest.raises(Interrupted):
            recorder.close()
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)
    assert finished_mcap(tmp_path / "run.mcap")
    assert [m["message"] for m in read_run(tmp_path / "run.mcap")["/run/status"]] == ["a note"]


def test_an_output_directory_that_cannot_be_written_is_refused_before_a_board_starts(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rig.data import paths
    from rig.data.errors import InputError
    from rig.hil import job

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    started = []
    monkeypatch.setattr(job, "board_link", lambda *args: started.append(args))
    with pytest.raises(InputError, match=f"cannot write to the output directory {blocker / 'run'}"):
        job.replay_job(paths.default_recording(), "native", blocker / "run", job.EstimatorChoice())

    def read_only(*args, **kwargs):
        raise OSError(30, "Read-only file system")
    monkeypatch.setattr(job.tempfile, "mkstemp", read_only)
    with pytest.raises(InputError, match="Read-only file system"):
        job.replay_job(paths.default_recording(), "native", tmp_path / "run", job.EstimatorChoice())
    assert not started


@pytest.mark.parametrize("command, rule", [
    (["-m", "rig", "watch", "--connect", "nope"], "zenoh endpoint 'nope' is not PROTOCOL/ADDRESS"),
    (["-m", "rig", "watch", "--connect", "tcp/127.0.0.1:7447", "--timeout", "-1"], "--timeout: must be above zero"),
    (["-m", "rig", "watch", "--connect", "tcp/127.0.0.1:7447", "--count", "0"], "--count: must be above zero"),
    (["-m", "rig", "router", "--listen", "tcp/127.0.0.1:0", "--duration", "0"], "--duration: must be above zero"),
    (["-m", "bridge", "--target", "native", "--name", "b0", "--connect", "127.0.0.1:7447"],
     "zenoh endpoint '127.0.0.1:7447' is not PROTOCOL/ADDRESS"),
    (["-m", "rig", "bench", "--targets", "native,nonsense"], "rig bench measures native and qemu, not 'nonsense'"),
    (["-m", "rig", "bench", "--threshold", "-1"], "--threshold: must be above zero"),
])
def test_a_service_command_refuses_a_malformed_endpoint_target_or_bound_in_one_line(command: list[str],
                                                                                    rule: str) -> None:
    proc = subprocess.run([sys.executable, *command], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and rule in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
