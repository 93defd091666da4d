"""Soak: four boards, ten replays each, through one router, with boards that lose power
mid-replay and line noise on the links. Every run either completes or ends with a
clear status, and every run record is finished and holds what metrics.json counts."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from rigtest import alive, finished_mcap

from rig.data import paths
from rig.data.importer import load_any
from rig.hil import targets
from rig.hil.job import EstimatorChoice, JobFailed, replay_job
from rig.hil.runrecord import TOPIC_ESTIMATE, read_run
from rig.hil.zenoh import Bridge, open_session

pytestmark = pytest.mark.slow        # left out of `make test-fast`

BOARDS, ROUNDS, START, SECONDS = 4, 10, 12.0, 2.0     # in flight: every run is scored
WINDOWS = int(SECONDS * 100)
PLANS = ("clean", "noise", "power_loss")


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def faulty_board(plan: str, rng: random.Random):
    """A native board whose link carries the plan's fault: line noise between windows
    (a garbage frame every few sends), or the board killed mid-replay (power lost)."""
    link = targets.open_native()
    send, sends, at = link.send, {"n": 0}, rng.randrange(60, WINDOWS - 20)

    def faulty_send(payloads, framed=None):
        sends["n"] += 1
        if plan == "noise" and sends["n"] % 7 == 0:
            link.port.write(bytes(rng.randrange(1, 256) for _ in range(rng.randrange(1, 60))) + b"\x00")
        send(payloads, framed)
        if plan == "power_loss" and sends["n"] == at:
            os.kill(link.process.pid, signal.SIGKILL)

    link.send = faulty_send
    return link


def replay(rec, board: str, router, out: Path) -> dict:
    try:
        return replay_job(paths.default_recording(), f"zenoh:{board}", out, EstimatorChoice(use_nn=False),
                          start=START, duration=SECONDS, report=False, session=router, board=f"rig-{board}", loaded=rec)
    except JobFailed as exc:
        return exc.result


def test_four_boards_ten_replays_with_power_losses_and_line_noise_lose_no_record(tmp_path: Path) -> None:
    rng, rec, boards = random.Random(2026), load_any(paths.default_recording()), set()
    endpoint = _free_endpoint()
    router = open_session("router", [endpoint], [])
    runs = []
    try:
        for round_ in range(ROUNDS):
            plans = [rng.choice(PLANS) for _ in range(BOARDS)]
            sessions = [open_session(None, [], [endpoint]) for _ in range(BOARDS)]
            links = [faulty_board(plan, rng) for plan in plans]
            boards |= {link.process.pid for link in links}
            bridges = [Bridge(s, f"b{k}", link).start() for k, (s, link) in enumerate(zip(sessions, links))]
            try:
                with ThreadPoolExecutor(BOARDS) as pool:
                    results = list(pool.map(lambda k: replay(rec, f"b{k}", router, tmp_path / f"r{round_}b{k}"),
                                            range(BOARDS)))
            finally:
                for bridge, session in zip(bridges, sessions):
                    bridge.stop()
                    session.close()
            runs += [(plan, tmp_path / f"r{round_}b{k}", r) for k, (plan, r) in enumerate(zip(plans, results))]
    finally:
        router.close()
    assert threading.active_count() < 20 and not alive(boards)      # nothing left running
    assert {plan for plan, _, _ in runs} == set(PLANS) and len(runs) == BOARDS * ROUNDS
    for plan, out, result in runs:
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics == json.loads(json.dumps(result))
        assert finished_mcap(out / "run.mcap"), out
        assert len(read_run(out / "run.mcap").get(TOPIC_ESTIMATE, [])) == metrics["n_estimates"]
        if plan == "power_loss":
            assert metrics["ended"] == "board_lost", (out, metrics["error"])
            assert "went away" in metrics["error"] or "stopped answering" in metrics["error"], metrics["error"]
            assert 0 < metrics["n_estimates"] < WINDOWS
        else:
            assert metrics["ended"] == "completed" and metrics["error"] is None, (out, metrics["error"])
            assert WINDOWS - 1 <= metrics["n_estimates"] <= WINDOWS
    completed = {(r["n_estimates"], r["rmse_3d"]) for plan, _, r in runs if plan != "power_loss"}
    assert len(completed) == 1                       # line noise costs frames, never a different answer
