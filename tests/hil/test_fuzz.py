"""A short libFuzzer run on the board service in CI (the longer one: docs/reference/protocol.md).
It starts from valid sessions written by the rig's own encoders, so the fuzzer mutates
realistic traffic (IMU key and delta messages, packed TDOA, STEP) rather than only noise."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rig.data.recording import Recording
from rig.estimator import native
from rig.estimator.evaluate import build_events, start_time, truth_pose_at
from rig.hil import protocol, replay

pytestmark = pytest.mark.slow        # left out of `make test-fast`

FUZZ_SECONDS = 20


def seed_sessions(rec: Recording, n: int = 4) -> list[bytes]:
    t0 = start_time(rec)
    pos, quat = truth_pose_at(rec, t0)
    setup = [protocol.hello(), protocol.param(0, 0.1), protocol.reset(0, pos, quat)]
    setup += [protocol.anchors_clear()] + [protocol.anchor(a.id, a.position, a.quaternion) for a in rec.anchors[:8]]
    ws = replay.windows(build_events(rec, t0, t0 + 0.2))
    sessions = []
    for k in range(n):
        imu = protocol.ImuStream(key_every=3 + k)
        msgs = setup + [m for window in replay.encode_windows(ws[k:k + 5], imu) for m in window]
        if k % 2:           # brief STEPs (compact answers) too
            msgs = [protocol.brief(m) if m[0] == protocol.STEP else m for m in msgs]
        sessions.append(b"".join(protocol.frame(m) for m in msgs))
    return sessions


def test_fuzzing_the_board_service_finds_nothing(tmp_path: Path, default_rec) -> None:
    native.make("fuzz")
    seeds = tmp_path / "seeds"
    seeds.mkdir()
    for k, session in enumerate(seed_sessions(default_rec)):
        (seeds / f"session{k}").write_bytes(session)
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    proc = subprocess.run([str(native.BUILD_DIR / "fuzz_service"), f"-max_total_time={FUZZ_SECONDS}",
                           "-max_len=4096", "-print_final_stats=1", str(corpus), str(seeds)],
                          capture_output=True, text=True, timeout=FUZZ_SECONDS + 120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = int(re.search(r"stat::number_of_executed_units:\s+(\d+)", proc.stderr).group(1))
    assert runs > 10_000
    assert np.any([p.stat().st_size > 0 for p in corpus.iterdir()])   # it explored beyond the seeds
