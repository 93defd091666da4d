"""The rig as a service, with real components: zenoh sessions on loopback (a router
process, bridge processes, watcher processes), the QEMU firmware, real MCAP run records
read back, and failures (a bridge killed mid-run, a watcher that vanishes, a full disk,
Ctrl-C)."""

from __future__ import annotations

import json
import os
import resource
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
from rigtest import RIG, ROOT, exit_status, finished_mcap, run_rig, start

from rig.hil.runrecord import read_run

pytestmark = pytest.mark.slow        # left out of `make test-fast`


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _topics(path: Path) -> dict[str, int]:
    return {topic: len(rows) for topic, rows in read_run(path).items()}


ROUTER_START_S = 30.0          # bound on a router's start-up (a Python process importing zenoh: 1-2 s idle)


def _router(endpoint: str, duration_s: int) -> subprocess.Popen:
    """`rig router` listening on `endpoint`, once it accepts connections: a client (a
    bridge, a watcher) that connects before then finds no router and exits, which a
    fixed sleep of a second left to chance on a loaded machine."""
    router = start(*RIG, "router", "--listen", endpoint, "--duration", str(duration_s))
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    deadline = time.monotonic() + ROUTER_START_S
    while True:
        try:
            socket.create_connection((host, int(port)), timeout=1.0).close()
            return router
        except OSError:
            if router.poll() is not None or time.monotonic() > deadline:
                router.kill()
                raise AssertionError(f"rig router did not listen on {endpoint}: {router.stderr.read()}")
            time.sleep(0.1)


def test_held_out_flight_into_qemu_is_recorded_and_published_to_another_process(tmp_path: Path, data_dir) -> None:
    endpoint = _free_endpoint()
    router = _router(endpoint, 300)
    try:
        watcher = start(*RIG, "watch", "--connect", endpoint, "--board", "qemu0", "--count", "1000",
                         "--timeout", "240", "--json", str(tmp_path / "watch.json"))
        vanishing = start(*RIG, "watch", "--connect", endpoint, "--timeout", "240")
        time.sleep(2.0)
        vanishing.kill()                       # a subscriber that vanishes must not disturb the run
        out = tmp_path / "run"
        proc = run_rig("replay", str(data_dir / "flights" / "0426-traj2"), "--target", "qemu", "--board", "qemu0",
                       "--zenoh-connect", endpoint, "--start", "20", "--duration", "12", "--out", str(out))
        assert proc.returncode == 0, proc.stderr
        assert exit_status(watcher, 60) == 0, watcher.stderr.read()
    finally:
        router.terminate()
        router.wait(timeout=10)
    metrics = json.loads((out / "metrics.json").read_text())
    n = metrics["n_estimates"]
    assert 1199 <= n <= 1200 and metrics["timing"]["unit"] == "instructions"   # 12 s at 100 Hz
    assert finished_mcap(out / "run.mcap")
    counts = _topics(out / "run.mcap")
    assert counts["/run/estimate"] == counts["/run/timing"] == n
    assert counts["/run/input/imu"] >= 1000 and counts["/run/input/tdoa"] > 2000 and counts["/run/truth"] > 1000
    assert (out / "report.html").stat().st_size > 20_000
    assert json.loads((tmp_path / "watch.json").read_text())["counts"]["qemu0"] >= 1000


def test_four_boards_in_parallel_through_one_router(tmp_path: Path) -> None:
    out = tmp_path / "farm"
    proc = run_rig("farm", "recordings/default.mcap", *["--target", "native"] * 4, "--duration", "12",
                   "--listen", _free_endpoint(), "--out", str(out), "--junit-xml", str(out / "junit.xml"))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    suite = ElementTree.parse(out / "junit.xml").getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("failures")) == ("4", "0")
    assert sorted(c.get("classname") for c in suite.iter("testcase")) == [f"rig.farm.board{k}" for k in range(4)]
    jobs = json.loads((out / "farm.json").read_text())["jobs"]
    assert len(jobs) == 4 and all(j["error"] is None and 1199 <= j["n_estimates"] <= 1200 for j in jobs)
    for k in range(4):
        assert finished_mcap(out / f"board{k}" / "run.mcap")
        assert _topics(out / f"board{k}" / "run.mcap")["/run/estimate"] == jobs[k]["n_estimates"]
        assert (out / f"board{k}" / "report.html").exists()
    assert len({j["rmse_3d"] for j in jobs}) == 1            # the same answers on every board


def test_a_farm_says_which_boards_it_could_not_score_and_why(tmp_path: Path) -> None:
    """One recording cut short before its scored segment, one without ground truth
    replayed from a given start: both timed, neither scored, each saying why."""
    from dataclasses import replace

    from rig.data.recording import PoseSeries, read_recording, write_recording

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    write_recording(replace(rec, truth=PoseSeries.empty()), tmp_path / "field.mcap")
    out = tmp_path / "farm"
    proc = run_rig("farm", "recordings/default.mcap", str(tmp_path / "field.mcap"), "--target", "native",
                   "--duration", "2", "--start-position", "1.5", "0", "0.03", "--listen", _free_endpoint(),
                   "--out", str(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "board0 (native, recordings/default.mcap): not scored (no estimate inside the scored segment" in proc.stdout
    assert "board1 (native, " + str(tmp_path / "field.mcap") + "): not scored (the recording has no ground truth" \
        in proc.stdout
    jobs = json.loads((out / "farm.json").read_text())["jobs"]
    assert all(199 <= j["n_estimates"] <= 200 for j in jobs)
    assert all(j["start_pose"] == {"position": [1.5, 0.0, 0.03], "yaw_deg": 0.0} for j in jobs)


def test_a_board_lost_mid_run_keeps_the_record_and_says_so(tmp_path: Path) -> None:
    endpoint = _free_endpoint()
    router = _router(endpoint, 120)
    bridge = start(sys.executable, "-m", "bridge", "--target", "native", "--name", "b0", "--connect", endpoint)
    try:
        out = tmp_path / "run"
        # in real time (30 s of flight) the bridge surely goes while windows are flowing
        replay = start(*RIG, "replay", "recordings/default.mcap", "--target", "zenoh:b0", "--zenoh-connect",
                        endpoint, "--out", str(out), "--mode", "realtime")
        time.sleep(14.0)                                      # well into the scored segment
        bridge.kill()                                         # the board and its bridge vanish
        assert exit_status(replay, 60) == 3                   # a board that failed: a clear error, not a crash
        stderr = replay.stderr.read()
        assert "went away" in stderr or "stopped answering" in stderr
    finally:
        router.terminate()
        router.wait(timeout=10)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["error"] and metrics["n_estimates"] > 0
    assert finished_mcap(out / "run.mcap")
    rows = read_run(out / "run.mcap")
    assert len(rows["/run/estimate"]) == metrics["n_estimates"]
    assert rows["/run/status"][-1]["source"] == "rig"


def test_ctrl_c_finishes_the_run_record(tmp_path: Path) -> None:
    out = tmp_path / "run"
    # through the emulated USART (about 1x real time), so that windows are still flowing
    replay = start(*RIG, "replay", "recordings/default.mcap", "--target", "qemu-usart", "--out", str(out))
    deadline = time.monotonic() + 120
    record = out / "run.mcap"
    while time.monotonic() < deadline and (not record.exists() or record.stat().st_size < 30_000):
        time.sleep(0.2)                                       # anchors and ground truth are on disk
    time.sleep(3.0)                                           # windows are flowing
    replay.send_signal(signal.SIGINT)
    assert exit_status(replay, 60) == 130
    assert finished_mcap(out / "run.mcap")
    assert len(read_run(out / "run.mcap").get("/run/estimate", [])) > 0


def test_a_record_left_unfinished_by_sigkill_is_finished_by_rig_report(tmp_path: Path) -> None:
    """SIGKILL leaves the record without its end; `rig report DIR --finish` closes it at
    its last whole record, and the stock reader then reads it."""
    from mcap.reader import make_reader

    from rig.data.recording import is_finished

    out = tmp_path / "run"
    replay = start(*RIG, "replay", "recordings/default.mcap", "--target", "native", "--mode", "realtime",
                   "--out", str(out))
    record = out / "run.mcap"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not record.exists() or record.stat().st_size < 30_000):
        time.sleep(0.2)                                       # anchors and ground truth are on disk
    time.sleep(1.0)
    replay.kill()
    assert exit_status(replay, 30) == -signal.SIGKILL
    assert not is_finished(record)
    proc = run_rig("report", str(out))
    assert proc.returncode == 0 and "--finish" in proc.stderr              # read as it is, with the hint
    proc = run_rig("report", str(out), "--finish", check=True)
    assert "finished at its last whole record" in proc.stdout
    with open(record, "rb") as stream:
        topics = [channel.topic for _, channel, _ in make_reader(stream).iter_messages()]
    assert topics.count("/uwb/anchors") == 1 and topics.count("/run/truth") > 100
    assert (out / "report.html").stat().st_size > 0
    assert "already finished" in run_rig("report", str(out), "--finish", check=True).stdout


def test_a_full_disk_is_reported_and_the_replay_still_scores(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.mcap").symlink_to("/dev/full")               # every write: ENOSPC
    proc = run_rig("replay", "recordings/default.mcap", "--target", "native", "--duration", "12", "--out", str(out))
    assert proc.returncode == 2
    assert "No space left on device" in proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_estimates"] >= 1199 and "No space left" in metrics["run_record_error"]
    assert metrics["ended"] == "completed"


def test_a_record_cut_short_by_a_full_disk_is_finished_and_the_stock_reader_reads_it(tmp_path: Path) -> None:
    """A file-size limit fails the run record's writes mid-replay as a full disk does,
    after part of it is written; the record is still finished (cut at its last whole
    record, closed without a summary) and holds the estimates written before."""
    from mcap.reader import make_reader

    out = tmp_path / "run"
    limit = 120_000

    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)           # a write past it fails (EFBIG) instead

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([*RIG, "replay", "recordings/default.mcap", "--target", "native", "--duration", "20",
                           "--out", str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
                          preexec_fn=limit_file_size)
    assert "File too large" in proc.stderr and "Traceback" not in proc.stderr
    assert limit - 20_000 < (out / "run.mcap").stat().st_size <= limit
    with open(out / "run.mcap", "rb") as stream:
        topics = [channel.topic for _, channel, _ in make_reader(stream).iter_messages()]
    assert topics.count("/run/estimate") > 0 and topics.count("/uwb/anchors") == 1
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ended"] == "completed" and "File too large" in metrics["run_record_error"]


def test_board_samples_are_stamped_declare_their_encoding_and_a_late_joiner_gets_the_latest(tmp_path: Path) -> None:
    """A native replay published on zenoh (the in-process bridge): every estimate sample
    carries a timestamp and application/json; a session that joins mid-run and asks
    for every board's estimate gets this board's latest one at once."""
    import threading

    from rig.data import paths
    from rig.hil.job import EstimatorChoice, replay_job
    from rig.hil.zenoh import key, open_session

    endpoint = _free_endpoint()
    rig_session, watcher = open_session("peer", [endpoint], []), open_session(None, [], [endpoint])
    seen = []
    subscriber = watcher.declare_subscriber(key("b0", "estimate"), seen.append)
    job = threading.Thread(target=replay_job, args=(paths.default_recording(), "native", tmp_path / "run",
                                                    EstimatorChoice()),
                           kwargs={"duration": 20.0, "session": rig_session, "board": "b0", "report": False})
    try:
        job.start()
        deadline = time.monotonic() + 60
        while len(seen) < 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        late = open_session(None, [], [endpoint])
        try:
            replies = [r.ok for r in late.get("rig/board/*/estimate", timeout=5.0) if r.ok is not None]
        finally:
            late.close()
        job.join(timeout=120)
    finally:
        subscriber.undeclare()
        watcher.close()
        rig_session.close()
    assert len(seen) >= 200 and all(s.timestamp is not None for s in seen)
    assert {str(s.encoding) for s in seen} == {"application/json"}
    assert [str(r.key_expr) for r in replies] == ["rig/board/b0/estimate"]
    latest = json.loads(replies[0].payload.to_bytes())
    assert latest["t_us"] >= json.loads(seen[199].payload.to_bytes())["t_us"]     # the state when it asked, or later
