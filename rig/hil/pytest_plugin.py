"""The rig as a pytest plugin (registered through the `pytest11` entry point): hardware-in-
the-loop tests written as pytest-embedded users write theirs with `dut`.

    def test_default_recording_is_accurate(board):
        metrics = board.replay("recordings/default.mcap", duration=20)
        assert metrics["rmse_3d"] < 0.3

    pytest --rig-target native --rig-target qemu --rig-target serial:/dev/ttyACM0

`--rig-target` (repeatable; default `native`) takes what `rig replay --target` takes:
native, native-udp, qemu, qemu-usart, serial:URL, crazyflie:URI, zenoh:NAME. The `board` fixture
is parametrized over them; `board.replay(recording, **options)` replays as `rig
replay` does (options: `start`, `duration`, `mode` "lockstep" or "realtime", `speed`,
`lookahead`, `no_nn`, `no_robust`, `model`, `full_trust`, `no_anchor_weighting`, `survey`,
`report`, and for a recording without ground truth `start_position` (x, y, z) and `start_yaw` in degrees) into a directory of
the test's own and returns what metrics.json holds. A board or link that fails raises
`rig.hil.job.JobFailed` with what was kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

DEFAULT_TARGET = "native"
REPLAY_OPTIONS = {"start", "duration", "mode", "speed", "lookahead", "full_answer_every", "no_nn", "no_robust", "model",
                  "full_trust", "no_anchor_weighting", "survey", "report", "strict", "start_position", "start_yaw"}


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("rig", "uwb-rig hardware in the loop")
    group.addoption("--rig-target", action="append", default=[], metavar="TARGET",
                    help="a board for the `board` fixture, as `rig replay --target` takes it (repeatable; default "
                         "native): native, native-udp, qemu, qemu-usart, serial:URL, crazyflie:URI, zenoh:NAME")


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "board" in metafunc.fixturenames:
        targets = metafunc.config.getoption("rig_target") or [DEFAULT_TARGET]
        metafunc.parametrize("board", targets, indirect=True, ids=targets)


@dataclass
class Board:
    """One target the test replays into; its outputs go under `out` (the test's own)."""

    target: str
    out: Path
    replays: int = 0

    def replay(self, recording: str | Path | None = None, **options) -> dict:
        """Replay `recording` (default: the shipped default recording) as `rig replay`
        would; returns metrics.json's content (also written, with run.mcap, under `out`)."""
        from rig.data import paths
        from rig.estimator.evaluate import StartPose
        from rig.hil.job import EstimatorChoice, replay_job

        unknown = set(options) - REPLAY_OPTIONS
        if unknown:
            raise TypeError(f"board.replay() takes {sorted(REPLAY_OPTIONS)}, not {sorted(unknown)}")
        mode = options.pop("mode", "lockstep")
        if mode not in ("lockstep", "realtime"):
            raise ValueError(f"mode must be 'lockstep' or 'realtime', not {mode!r}")
        speed = float(options.pop("speed", 1.0))
        estimator = EstimatorChoice(use_nn=not options.pop("no_nn", False), robust=not options.pop("no_robust", False),
                                    model_path=options.pop("model", None), full_trust=options.pop("full_trust", False),
                                    anchor_weighting=not options.pop("no_anchor_weighting", False))
        position, yaw = options.pop("start_position", None), options.pop("start_yaw", 0.0)
        start_pose = None if position is None else StartPose(tuple(position), float(yaw))
        self.replays += 1
        out = self.out / f"replay{self.replays}"
        recording = Path(recording) if recording is not None else paths.default_recording()
        return replay_job(recording, self.target, out, estimator, speed=speed if mode == "realtime" else None,
                          report=options.pop("report", False), start_pose=start_pose, **options)


@pytest.fixture
def board(request: pytest.FixtureRequest, tmp_path: Path) -> Board:
    """A board to replay flights into: each `--rig-target` in turn."""
    return Board(request.param, tmp_path)
