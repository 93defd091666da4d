"""Helpers the tests share: running `rig` as a user does, crafted logs, exact simulations."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rig.data.usdlog import EventType, encode

ROOT = Path(__file__).resolve().parent.parent


RIG = [sys.executable, "-m", "rig"]


# The event types of a real Crazyflie log, as far as the rig uses them.
ACC = EventType(1, "estAcceleration", ("acc.x", "acc.y", "acc.z"), "fff")


GYRO = EventType(5, "estGyroscope", ("gyro.x", "gyro.y", "gyro.z"), "fff")


POSE = EventType(6, "estPose", ("locSrv.x", "locSrv.y", "locSrv.z", "locSrv.qx", "locSrv.qy", "locSrv.qz",
                                "locSrv.qw"), "fffffff")


TDOA = EventType(9, "estTDOA", ("idA", "idB", "distanceDiff"), "BBf")


TYPES = [ACC, GYRO, POSE, TDOA]


# Simulator output resolution off: values exactly as computed (no sensor LSB rounding).
FULL_PRECISION = {k: 0.0 for k in ("time", "accel", "gyro", "tdoa", "position", "quaternion")}


def simulate_exact(survey: Path, trajectory: str = "circle-sine", effects: list[dict] | None = None, **kw):
    """A simulated flight at full precision (no effects unless given)."""
    from rig.sim.simulate import SimConfig, simulate

    return simulate(SimConfig(trajectory=trajectory, survey=str(survey), effects=effects or [],
                              resolution=dict(FULL_PRECISION), **kw))


def tdoa_poses(rec):
    """The TDOA rows inside the ground truth's span (a mask), their times, and the true
    body attitude and position there."""
    from scipy.spatial.transform import Rotation, Slerp

    tdoa, truth = rec.tdoa, rec.truth
    inside = (tdoa.t > truth.t[0]) & (tdoa.t < truth.t[-1])
    t = tdoa.t[inside]
    body = Slerp(truth.t, Rotation.from_quat(truth.quaternion))(t)
    position = np.stack([np.interp(t, truth.t, truth.position[:, i]) for i in range(3)], axis=1)
    return inside, t, body, position


def crafted_log(n: int = 50) -> bytes:
    """A small valid log: n samples of each stream, one event out of time order."""
    return encode(TYPES, crafted_events(n))


def crafted_events(n: int = 50) -> list[tuple[str, int, tuple]]:
    """The events of `crafted_log`, in recording order."""
    events = []
    for k in range(n):
        t = 1_000_000 + 1000 * k
        events.append(("estAcceleration", t, (0.0, 0.5, 1.0)))
        events.append(("estGyroscope", t + 17, (90.0, -180.0, 0.0)))
        if k % 4 == 0:
            events.append(("estPose", t + 5, (1.0, 2.0, 0.5 + k * 0.01, 0.0, 0.0, 0.0, 1.0)))
            events.append(("estTDOA", t + 9, (k % 8, (k + 1) % 8, 0.25)))
    if len(events) > 11:  # recording order is not time order
        events[10], events[11] = events[11], events[10]
    return events


def fail_with_stacks(proc: subprocess.Popen, timeout: float) -> None:
    """Fail the test on a `rig` process still running after `timeout`, with every thread's
    stack (the rig prints them on SIGUSR1), so that a hang says where it is."""
    proc.send_signal(signal.SIGUSR1)
    time.sleep(2.0)
    proc.kill()
    _, stderr = proc.communicate()
    pytest.fail(f"{' '.join(map(str, proc.args))} still running after {timeout:g} s; its threads:\n{stderr[-8000:]}")


def exit_status(proc: subprocess.Popen, timeout: float) -> int:
    """proc's exit status, waiting at most `timeout` (fail_with_stacks after that)."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        fail_with_stacks(proc, timeout)


def run_rig(*args: str, cwd: Path = ROOT, check: bool = False, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with subprocess.Popen([*RIG, *args], cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            fail_with_stacks(proc, timeout)
    result = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def start(*args: str) -> subprocess.Popen:
    """A child as from a terminal: SIGINT at its default disposition (a runner that started
    the tests in the background may have left it ignored, and a program started with
    SIGINT ignored rightly keeps ignoring it)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(list(args), cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def finished_mcap(path: Path) -> bool:
    """Whether the stock MCAP reader finds the file finished (its summary written)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return make_reader(f).get_summary() is not None


def board_processes(parent: int | None = None) -> set[int]:
    """The native estimator programs running on this machine (started by `parent`, if
    given: other tests may run boards at the same time)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if b"estimator_native" not in (entry / "cmdline").read_bytes():
                    continue
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue                          # it ended while we looked
            if parent is None or ppid == parent:
                found.add(int(entry.name))
    return found


def alive(pids: set[int]) -> set[int]:
    """Those of `pids` still running (not zombies)."""
    out = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if state != "Z":
            out.add(pid)
    return out
