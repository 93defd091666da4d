"""The `board` fixture as a user's hardware-in-the-loop test uses it (rig.hil.pytest_plugin,
registered through the pytest11 entry point): parametrized over --rig-target, replaying
as `rig replay` does and returning metrics.json's content."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from rigtest import ROOT

pytestmark = pytest.mark.slow        # left out of `make test-fast`

USER_TEST = '''
def test_default_recording_on_every_board(board):
    metrics = board.replay(duration=12.0)
    assert metrics["ended"] == "completed" and metrics["n_estimates"] >= 1199
    assert metrics["rmse_3d"] < 0.4 and metrics["target"] == board.target


def test_a_replay_in_real_time(board):
    metrics = board.replay(start=12.0, duration=2.0, mode="realtime", speed=4.0, no_nn=True)
    assert metrics["mode"] == "realtime" and metrics["realtime"]["speed"] == 4.0 and not metrics["bias_net"]


def test_compact_answers(board):
    metrics = board.replay(duration=3.0, full_answer_every=10)
    assert metrics["full_answer_every"] == 10 and metrics["timing"]["windows"] == 30


def test_a_flight_without_ground_truth_from_where_the_drone_stood(board, tmp_path):
    from dataclasses import replace

    from rig.data import paths
    from rig.data.recording import PoseSeries, read_recording, write_recording

    rec = read_recording(paths.default_recording())
    write_recording(replace(rec, truth=PoseSeries.empty()), tmp_path / "field.mcap")
    metrics = board.replay(tmp_path / "field.mcap", duration=3.0, start_position=(1.5, 0.0, 0.03), start_yaw=10.0)
    assert "rmse_3d" not in metrics and metrics["timing"]["windows"] >= 299
    assert metrics["start_pose"] == {"position": [1.5, 0.0, 0.03], "yaw_deg": 10.0}


def test_the_recording_still_bears_out_the_bias_correction(board):
    trusted, whole = board.replay(duration=20.0), board.replay(duration=20.0, full_trust=True)
    assert 0.8 < trusted["correction_trust"] < 1.0 and not trusted["full_trust"]
    assert whole["correction_trust"] == 1.0 and whole["full_trust"]


def test_the_blocked_anchor_weighting_is_the_users_choice(board):
    assert board.replay(duration=2.0)["anchor_weighting"]
    assert not board.replay(duration=2.0, no_anchor_weighting=True)["anchor_weighting"]
'''


def test_a_users_test_file_with_the_board_fixture_passes_on_the_native_target(tmp_path: Path) -> None:
    (tmp_path / "test_hil.py").write_text(USER_TEST)
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rig-target", "native",
                           "--junitxml", str(tmp_path / "junit.xml"), str(tmp_path / "test_hil.py")],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "6 passed" in proc.stdout
    assert 'test_default_recording_on_every_board[native]' in (tmp_path / "junit.xml").read_text()


def test_the_board_fixture_refuses_an_option_rig_replay_does_not_take(board) -> None:
    with pytest.raises(TypeError, match="not \\['speeed'\\]"):
        board.replay(speeed=2.0)
    metrics = board.replay(duration=3.0)
    assert json.loads((board.out / "replay1" / "metrics.json").read_text()) == json.loads(json.dumps(metrics))
