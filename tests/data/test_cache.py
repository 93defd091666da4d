"""The recordings' binary cache: the same recording back, a changed or damaged file read
afresh, and never a reason for a job to fail."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from rigtest import simulate_exact

from rig.data import cache
from rig.data.cache import read_cached as read_recording
from rig.data.recording import write_recording


def assert_same(a, b) -> None:
    for name in ("accel", "gyro", "tdoa", "truth"):
        for column, value in vars(getattr(a, name)).items():
            np.testing.assert_array_equal(value, getattr(getattr(b, name), column))
            assert value.dtype == getattr(getattr(b, name), column).dtype
    assert a.anchors == b.anchors and a.metadata == b.metadata


@pytest.fixture
def private_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv("UWB_RIG_CACHE", str(root))
    return root


def test_a_recording_read_twice_comes_back_the_same_from_the_cache(
        survey_0425: Path, tmp_path: Path, private_cache: Path) -> None:
    path = tmp_path / "flight.mcap"
    write_recording(simulate_exact(survey_0425, duration=3.0), path)
    first = read_recording(path)
    assert len(list(private_cache.rglob("*.npz"))) == 1
    assert cache.load(path) is not None
    assert_same(first, read_recording(path))


def test_a_changed_file_is_read_afresh(survey_0425: Path, tmp_path: Path, private_cache: Path) -> None:
    path = tmp_path / "flight.mcap"
    write_recording(simulate_exact(survey_0425, duration=3.0), path)
    read_recording(path)
    other = simulate_exact(survey_0425, duration=4.0)
    write_recording(other, path)
    os.utime(path, ns=(1, 1))             # even with an old modification time: the size differs
    assert len(read_recording(path).tdoa.t) == len(other.tdoa.t)


def test_a_damaged_file_is_not_cached_and_warns_every_time(survey_0425: Path, tmp_path: Path,
                                                           private_cache: Path, caplog) -> None:
    path = tmp_path / "flight.mcap"
    write_recording(simulate_exact(survey_0425, duration=20.0), path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    for _ in range(2):
        caplog.clear()
        read_recording(path)
        assert "unfinished or damaged" in caplog.text
    assert not list(private_cache.rglob("*.npz"))


def test_a_cache_that_cannot_be_written_or_is_off_changes_nothing(
        survey_0425: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "flight.mcap"
    write_recording(simulate_exact(survey_0425, duration=3.0), path)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("UWB_RIG_CACHE", str(blocker / "cache"))
    assert_same(read_recording(path), read_recording(path))
    monkeypatch.setenv("UWB_RIG_CACHE", "off")
    assert cache.cache_dir() is None
    read_recording(path)


def test_a_damaged_cache_entry_falls_back_to_the_file(survey_0425: Path, tmp_path: Path,
                                                      private_cache: Path) -> None:
    path = tmp_path / "flight.mcap"
    write_recording(simulate_exact(survey_0425, duration=3.0), path)
    first = read_recording(path)
    for entry in private_cache.rglob("*.npz"):
        entry.write_bytes(b"garbage")
    assert_same(first, read_recording(path))


def test_a_flight_log_is_imported_once_and_again_when_its_survey_changes(
        data_dir: Path, tmp_path: Path, private_cache: Path) -> None:
    """A flight log and its survey are both the entry's key: the same import back from the
    cache, and a changed survey (another anchor layout) imported afresh."""
    from rig.data.importer import import_log, load_any

    log_path, survey = data_dir / "flights" / "0425-traj1", tmp_path / "anchors.txt"
    survey.write_text((data_dir / "surveys" / "anchor_0425.txt").read_text())
    first = load_any(log_path, survey)
    assert_same(first, import_log(log_path, survey))
    assert len(list(private_cache.rglob("*.npz"))) == 1
    assert_same(load_any(log_path, survey), first)
    lines = survey.read_text().splitlines()
    moved = [f"anchorAnt0,{float(line.split(',')[1]) + 0.5}," + ",".join(line.split(",")[2:])
             if line.startswith("anchorAnt0,") else line for line in lines]
    survey.write_text("\n".join(moved) + "\n")
    assert load_any(log_path, survey).anchors != first.anchors
    assert len(list(private_cache.rglob("*.npz"))) == 2
