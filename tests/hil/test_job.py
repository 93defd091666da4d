"""A replay job from Python, as `rig replay` runs it: the native program on a pty, the
outputs in a directory (metrics.json, a run record the stock MCAP reader reads, the
report, built from memory as it would be from the record), and a board that does not exist reported with what was kept."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from rig.data import paths
from rig.hil.checks import assertions
from rig.hil.job import EstimatorChoice, JobFailed, replay_job
from rig.hil.report import write_report
from rig.hil.runrecord import (
    TOPIC_ESTIMATE,
    TOPIC_FOXGLOVE_ANCHORS,
    TOPIC_FOXGLOVE_ESTIMATE,
    TOPIC_FOXGLOVE_TRUTH,
    TOPIC_IMU,
    TOPIC_POSITION_ERROR,
    TOPIC_TRUTH,
    read_run,
)


def test_a_short_native_replay_writes_its_metrics_record_and_report(tmp_path: Path) -> None:
    result = replay_job(paths.default_recording(), "native", tmp_path, EstimatorChoice(), duration=8.0)
    assert json.loads((tmp_path / "metrics.json").read_text()) == json.loads(json.dumps(result))
    assert result["n_estimates"] >= 799 and result["error"] is None and result["bias_net"]
    assert result["ended"] == "completed"
    assert 0 < result["loop_seconds"] < result["wall_seconds"]            # the exchange, within the whole job
    assert result["speed"] == pytest.approx(result["n_estimates"] * 0.01 / result["loop_seconds"])
    assert assertions(result, 0.4, 0.2, "window_p99") == []
    with open(tmp_path / "run.mcap", "rb") as stream:       # finished: the stock reader's summary is there
        reader = make_reader(stream)
        counts = reader.get_summary().statistics.channel_message_counts
        topics = {c.id: c.topic for c in reader.get_summary().channels.values()}
    assert {topics[k]: n for k, n in counts.items()}[TOPIC_ESTIMATE] == result["n_estimates"]
    # the IMU as the board received it, one message a window, its samples 1 ms apart in order
    imu = read_run(tmp_path / "run.mcap")[TOPIC_IMU]
    assert result["n_estimates"] - 1 <= len(imu) <= result["n_estimates"] + 2
    times = np.array([s["t"] for m in imu for s in m["samples"]])
    assert [m["t"] for m in imu] == [m["samples"][0]["t"] for m in imu]
    assert np.all(np.diff(times) > 0) and np.median(np.diff(times)) == pytest.approx(0.001, abs=2e-4)
    report = tmp_path / "report.html"
    assert report.stat().st_size > 10_000
    assert f"outside where the model was trained (extrapolated)</td><td>{result['outside_trained_region']:.1%}" \
        in report.read_text()
    assert result["board_link"] == {"frames_bad": 0, "bytes_dropped": 0, "reports": {}}     # nothing lost on a pty
    assert "board link: bytes dropped</td><td>0" in report.read_text()
    built_in_memory = report.read_bytes()              # from what the replay held: the same as from its record
    assert write_report(tmp_path) == report and report.read_bytes() == built_in_memory


@pytest.mark.slow
def test_the_run_record_opens_in_foxglove_as_a_3d_scene(tmp_path: Path) -> None:
    """Beside the project's topics: the estimate and the ground truth as foxglove.PoseInFrame,
    the anchors as a foxglove.SceneUpdate, the notes as foxglove.Log, and the position
    error as a plottable topic that agrees with the scored RMSE."""
    result = replay_job(paths.default_recording(), "native", tmp_path, EstimatorChoice(), duration=8.0, report=False)
    with open(tmp_path / "run.mcap", "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        schema_of = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        messages = {}
        for _, channel, message in reader.iter_messages():
            messages.setdefault(channel.topic, []).append(json.loads(message.data))
    assert schema_of[TOPIC_FOXGLOVE_ESTIMATE] == schema_of[TOPIC_FOXGLOVE_TRUTH] == "foxglove.PoseInFrame"
    assert schema_of[TOPIC_FOXGLOVE_ANCHORS] == "foxglove.SceneUpdate"
    estimates = messages[TOPIC_FOXGLOVE_ESTIMATE]
    assert len(estimates) == result["n_estimates"] and {e["frame_id"] for e in estimates} == {"world"}
    first = messages[TOPIC_ESTIMATE][0]
    assert estimates[0]["pose"]["position"] == first["position"]
    assert estimates[0]["timestamp"]["sec"] + estimates[0]["timestamp"]["nsec"] * 1e-9 == pytest.approx(first["t"])
    [scene] = messages[TOPIC_FOXGLOVE_ANCHORS]
    assert sorted(e["id"] for e in scene["entities"]) == [f"anchor{k}" for k in range(8)]
    errors = [m["error_m"] for m in messages[TOPIC_POSITION_ERROR]]
    assert len(errors) >= result["n_estimates"] - 2 and max(errors) < 1.0
    truth = [m["t"] for m in messages[TOPIC_TRUTH]]
    assert len(truth) == len(messages[TOPIC_FOXGLOVE_TRUTH]) and min(np.diff(truth)) > 0.0095   # one a window


def test_a_board_that_diverged_leaves_a_record_of_strict_json(tmp_path: Path) -> None:
    """NaN and infinities from a board that diverged are written null: every message
    parses as strict JSON (Foxglove's parser refuses `NaN`) and reads back as missing."""
    from rig.data.survey import Anchor
    from rig.hil import protocol
    from rig.hil.runrecord import TOPIC_COUNTERS, RunRecorder

    nan, inf = float("nan"), float("inf")
    rec = type("Rec", (), {"anchors": [Anchor(0, (0.0, 0.0, 2.0), (0.0, 0.0, 0.0, 1.0))],
                           "truth": type("Truth", (), {"t": np.array([0.0, 1.0]), "position": np.zeros((2, 3)),
                                                       "quaternion": np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))})()})()
    recorder = RunRecorder(tmp_path / "run.mcap")
    t0 = np.float64(0.0)                # numpy's numbers are numbers too
    recorder.start(rec, t0, 1.0, {"target": "test"})
    recorder.inputs(t0, 0, [], np.zeros((0, 6), np.int16), [(100, np.int64(0), 1, np.float32(nan))])
    recorder.answer(t0, protocol.Estimate(500_000, (nan, np.float32(1.0), inf), (0.0, -inf, 0.0)),
                    protocol.Attitude((0.0, 0.0, 0.0, nan), (nan,) * 9), protocol.Counters(*range(8)),
                    protocol.Timing(500_000, 10, 4, 6, 6, 1), "ns", 1e7)
    recorder.close()

    def refuse(constant: str):
        raise ValueError(f"{constant} is not JSON")

    with open(tmp_path / "run.mcap", "rb") as stream:
        texts = {channel.topic: json.loads(message.data, parse_constant=refuse)
                 for _, channel, message in make_reader(stream).iter_messages()}
    assert texts[TOPIC_ESTIMATE]["position"] == {"x": None, "y": 1.0, "z": None}
    assert texts[TOPIC_FOXGLOVE_ESTIMATE]["pose"]["orientation"]["w"] is None
    assert texts[TOPIC_POSITION_ERROR]["error_m"] is None and texts["/run/input/tdoa"]["distance_diff"] is None
    assert texts[TOPIC_COUNTERS]["imu_lost"] == 7 and texts[TOPIC_ESTIMATE]["t"] == 0.5


def test_a_board_that_cannot_be_reached_fails_the_job_and_keeps_its_outputs(tmp_path: Path) -> None:
    with pytest.raises(JobFailed, match="cannot open") as failure:
        replay_job(paths.default_recording(), "serial:/dev/nonexistent-board", tmp_path, EstimatorChoice(),
                   duration=1.0)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["n_estimates"] == 0 and "cannot open" in metrics["error"] == failure.value.result["error"]
    assert metrics["ended"] == "board_lost"
    assert (tmp_path / "run.mcap").is_file()


def test_the_score_is_known_before_any_file_is_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A disk that fills up as metrics.json is written: the score was handed out first
    (`rig replay` prints it), and the failure names the file."""
    import rig.hil.job

    def full_disk(path: Path, data: dict) -> None:
        raise OSError(28, f"cannot write {path}: No space left on device")

    scored = []
    monkeypatch.setattr(rig.hil.job, "write_json", full_disk)
    with pytest.raises(OSError, match="metrics.json: No space left"):
        replay_job(paths.default_recording(), "native", tmp_path, EstimatorChoice(), start=12.0, duration=2.0,
                   report=False, on_scored=scored.append)
    assert len(scored) == 1 and scored[0]["n_estimates"] >= 199 and scored[0]["rmse_3d"] > 0
