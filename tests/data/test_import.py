"""`rig import`: unit conversions, time order, every real flight imported losslessly."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rigtest import TYPES, crafted_events, crafted_log, run_rig

from rig.data import paths
from rig.data.importer import GRAVITY, import_log, infer_uwb_mode, load_any
from rig.data.recording import read_recording, write_recording
from rig.data.survey import parse_survey
from rig.data.usdlog import encode, read_log


def test_unit_conversions_and_time_order(tmp_path: Path, survey_0425: Path) -> None:
    log = tmp_path / "log"
    log.write_bytes(crafted_log(40))
    rec = import_log(log, survey_0425)
    np.testing.assert_allclose(rec.accel.xyz[0], [0.0, 0.5 * 9.81, 9.81])  # g → m/s²
    np.testing.assert_allclose(rec.gyro.xyz[0], [np.pi / 2, -np.pi, 0.0])  # deg/s → rad/s
    assert rec.accel.t[0] == pytest.approx(1.0)  # µs → s (first event at 1 000 000 µs)
    assert rec.gyro.t[0] == pytest.approx(1.000017)
    for series in (rec.accel, rec.gyro, rec.tdoa, rec.truth):
        assert np.all(np.diff(series.t) >= 0), "streams must be sorted by time"
    assert GRAVITY == 9.81


def test_uwb_mode_inference() -> None:
    ring = np.arange(80) % 8
    assert infer_uwb_mode(ring, (ring + 1) % 8, 8) == "TDOA2"
    rng = np.random.default_rng(0)
    a = rng.integers(0, 8, 500)
    assert infer_uwb_mode(a, (a + rng.integers(1, 8, 500)) % 8, 8) == "TDOA3"


def _import_and_compare(flight: Path, tmp: Path) -> str | None:
    """Import one real flight, read it back, compare with the raw log. Returns a problem or None."""
    decoded = read_log(flight)
    if not decoded.crc_ok:
        return f"{flight.name}: CRC not verified"
    out = tmp / f"{flight.name}.mcap"
    write_recording(import_log(flight, paths.survey_for(flight)), out)
    back = read_recording(out)
    expected = {"estAcceleration": back.accel, "estGyroscope": back.gyro, "estTDOA": back.tdoa,
                "estPose": back.truth}
    for event, series in expected.items():
        if len(series) != decoded.counts()[event]:
            return f"{flight.name}: {event} {decoded.counts()[event]} in log, {len(series)} in MCAP"
    raw = decoded.series("estTDOA")
    order = np.argsort(raw.timestamps_us, kind="stable")
    if not np.array_equal(raw.values[order, 2], back.tdoa.distance_diff):
        return f"{flight.name}: TDOA values differ"
    if not np.allclose(decoded.series("estAcceleration").values[np.argsort(
            decoded.series("estAcceleration").timestamps_us, kind="stable")] * 9.81, back.accel.xyz, rtol=0, atol=0):
        return f"{flight.name}: accelerations differ"
    out.unlink()
    return None


@pytest.mark.slow
def test_every_shared_flight_imports_without_losing_an_event(tmp_path: Path, data_dir: Path) -> None:
    flights = paths.flights()
    assert len(flights) >= 35
    with ProcessPoolExecutor(max_workers=2) as pool:
        problems = [p for p in pool.map(_import_and_compare, flights, [tmp_path] * len(flights)) if p]
    assert problems == []


@pytest.mark.slow
def test_cli_import_writes_an_mcap_with_the_contract_topics(tmp_path: Path, data_dir: Path) -> None:
    flight = data_dir / "flights" / "0425-traj1"
    out = tmp_path / "x.mcap"
    run_rig("import", str(flight), "--survey", str(data_dir / "surveys" / "anchor_0425.txt"), "-o", str(out),
            check=True)
    counts: dict[str, int] = {}
    with open(out, "rb") as stream:
        for _, channel, _ in make_reader(stream).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    log_counts = read_log(flight).counts()
    assert counts[next(t for t in counts if "tdoa" in t)] == log_counts["estTDOA"]
    assert counts[next(t for t in counts if "truth" in t)] == log_counts["estPose"]
    imu_topics = [t for t in counts if "imu" in t]
    assert sorted(counts[t] for t in imu_topics) == sorted([log_counts["estAcceleration"],
                                                            log_counts["estGyroscope"]])


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncate", "corrupt"])
def test_cli_import_of_a_damaged_log_fails_cleanly(tmp_path: Path, data_dir: Path, damage: str) -> None:
    data = bytearray((data_dir / "flights" / "0425-traj2").read_bytes())
    if damage == "truncate":
        data = data[: len(data) * 2 // 3]
    else:
        data[len(data) // 3] ^= 0xFF
    log = tmp_path / "damaged"
    log.write_bytes(bytes(data))
    out = tmp_path / "out.mcap"
    proc = run_rig("import", str(log), "--survey", str(data_dir / "surveys" / "anchor_0425.txt"), "-o", str(out))
    assert proc.returncode != 0
    assert "CRC-32" in proc.stderr and "--salvage" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()


@pytest.mark.slow
def test_cli_salvage_imports_the_valid_prefix_with_a_warning(tmp_path: Path, data_dir: Path) -> None:
    source = data_dir / "flights" / "0425-traj2"
    data = source.read_bytes()
    log = tmp_path / "truncated"
    log.write_bytes(data[: len(data) // 2])
    out = tmp_path / "out.mcap"
    proc = run_rig("import", str(log), "--survey", str(data_dir / "surveys" / "anchor_0425.txt"), "-o", str(out),
                   "--salvage")
    assert proc.returncode == 0, proc.stderr
    assert "salvage" in proc.stderr.lower() and "not decoded" in proc.stderr
    rec = read_recording(out)
    full = read_log(source).counts()
    assert 0 < len(rec.accel) < full["estAcceleration"]
    assert rec.metadata["crc"].startswith("bad")


@pytest.mark.slow
def test_cli_import_finds_the_survey_of_the_logs_day_or_says_where_it_looked(tmp_path: Path, data_dir: Path) -> None:
    half = (data_dir / "flights" / "0425-traj2").read_bytes()
    half = half[: len(half) // 4]
    (tmp_path / "flights").mkdir()
    for name in ("0425-cut", "0999-cut"):
        (tmp_path / "flights" / name).write_bytes(half)
    out = tmp_path / "out.mcap"
    proc = run_rig("import", str(tmp_path / "flights" / "0425-cut"), "-o", str(out), "--salvage")
    assert proc.returncode == 0, proc.stderr
    surveyed = {a.id: a.position for a in parse_survey(data_dir / "surveys" / "anchor_0425.txt")}
    imported = {a.id: a.position for a in read_recording(out).anchors}
    assert imported.keys() == surveyed.keys()
    assert all(imported[k] == pytest.approx(surveyed[k], abs=1e-6) for k in surveyed)
    proc = run_rig("import", str(tmp_path / "flights" / "0999-cut"), "-o", str(tmp_path / "other.mcap"), "--salvage")
    assert proc.returncode == 2
    assert "anchor_0999.txt" in proc.stderr and "--survey" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "other.mcap").exists()


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncate", "corrupt"])
def test_a_cut_or_damaged_recording_is_read_up_to_the_damage_with_a_warning_or_refused_when_strict(tmp_path: Path, data_dir: Path,
                                                                           damage: str) -> None:
    whole = tmp_path / "whole.mcap"
    write_recording(load_any(data_dir / "flights" / "0425-traj2"), whole)
    data = bytearray(whole.read_bytes())
    if damage == "truncate":                                  # a writer killed, a copy cut short
        data = data[: len(data) * 3 // 4]
    else:
        data[len(data) // 2] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    proc = run_rig("evaluate", str(damaged))
    assert proc.returncode == 0, proc.stderr
    assert "unfinished or damaged" in proc.stderr and "Traceback" not in proc.stderr
    out = tmp_path / "out"
    for command in (["evaluate"], ["replay", "--target", "native", "--out", str(out)], ["diagnose", "--out", str(out)]):
        strict = run_rig(*command, str(damaged), "--strict")          # --strict: an error, nothing scored
        assert strict.returncode == 2, (command, strict.stderr)
        assert "damaged or unfinished (--strict" in strict.stderr and "Traceback" not in strict.stderr
    assert not out.exists()
    original, salvaged = read_recording(whole), read_recording(damaged)
    n = len(salvaged.accel)
    assert 0 < n < len(original.accel) and salvaged.anchors == original.anchors
    assert salvaged.metadata == original.metadata
    np.testing.assert_array_equal(salvaged.accel.xyz, original.accel.xyz[:n])   # nothing damaged decoded


def test_a_recording_cut_before_its_first_chunk_or_empty_is_a_clear_error(tmp_path: Path) -> None:
    data = paths.default_recording().read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    proc = run_rig("evaluate", str(cut))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "cannot read" in proc.stderr and "no message before the damage" in proc.stderr
    assert "it ends inside a record" in proc.stderr               # what is wrong, not the index's garbage
    empty = tmp_path / "empty.mcap"
    empty.touch()
    proc = run_rig("evaluate", str(empty))
    assert proc.returncode == 2 and f"recording {empty} is empty (0 bytes)" in proc.stderr


@pytest.mark.parametrize("content", [b"garbage", bytes(range(256)) * 12])
def test_a_file_that_is_not_mcap_is_named_so(tmp_path: Path, content: bytes) -> None:
    """Too short for MCAP's magic, or other bytes where it should be: said so, not a
    parser's message about unpacking."""
    other = tmp_path / "other.mcap"
    other.write_bytes(content)
    proc = run_rig("evaluate", str(other))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"{other} is not an MCAP file: it does not begin with MCAP's magic bytes ({len(content)} bytes)" \
        in proc.stderr


def test_cli_reports_a_missing_file_without_traceback(tmp_path: Path) -> None:
    proc = run_rig("import", str(tmp_path / "nope"), "--survey", str(tmp_path / "nope.txt"), "-o",
                   str(tmp_path / "o.mcap"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "cannot read" in proc.stderr


def _shifted_survey(source: Path, target: Path, dx: float) -> None:
    """The survey with every point moved by dx along x (so every anchor is)."""
    lines = []
    for line in source.read_text().splitlines():
        fields = line.split(",")
        if len(fields) == 4 and not line.startswith("#"):
            fields[1] = f"{float(fields[1]) + dx:.6f}"
        lines.append(",".join(fields))
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("\n".join(lines) + "\n")


@pytest.mark.slow
def test_a_flight_log_finds_its_survey_beside_it_or_by_option(tmp_path: Path, data_dir: Path) -> None:
    """A copy of the data tree (flights/ and surveys/) with altered files uses its own
    survey; a log renamed away from its day needs --survey, and says so."""
    shared = data_dir / "surveys" / "anchor_0425.txt"
    flight = tmp_path / "tree" / "flights" / "0425-traj2"
    flight.parent.mkdir(parents=True)
    flight.write_bytes((data_dir / "flights" / "0425-traj2").read_bytes())
    _shifted_survey(shared, tmp_path / "tree" / "surveys" / "anchor_0425.txt", 1.0)
    own = {a.id: a.position for a in load_any(flight).anchors}
    for anchor in load_any(data_dir / "flights" / "0425-traj2").anchors:
        assert np.allclose(np.subtract(own[anchor.id], anchor.position), [1.0, 0.0, 0.0])

    renamed = tmp_path / "altered-flight"
    renamed.write_bytes(flight.read_bytes())
    out = tmp_path / "same.mcap"
    proc = run_rig("inject", str(renamed), "--effects", "[]", "-o", str(out))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "no survey of its day: anchor_altered.txt is not in" in proc.stderr and "--survey FILE" in proc.stderr
    proc = run_rig("inject", str(renamed), "--survey", str(shared), "--effects", "[]", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert [a.id for a in read_recording(out).anchors] == [a.id for a in load_any(flight).anchors]
    proc = run_rig("inject", str(out), "--survey", str(shared), "--effects", "[]", "-o", str(tmp_path / "x.mcap"))
    assert proc.returncode == 2 and "carries its own anchors" in proc.stderr


@pytest.mark.parametrize("content", [b"", bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8)) + b"x"],
                         ids=["empty", "random bytes"])
def test_a_file_that_is_no_log_at_all_says_so(tmp_path: Path, survey_0425: Path, content: bytes) -> None:
    log = tmp_path / "log"
    log.write_bytes(content if content[:1] != b"\xbc" else b"\x00" + content)
    for salvage in ([], ["--salvage"]):
        proc = run_rig("import", str(log), "--survey", str(survey_0425), "-o", str(tmp_path / "out.mcap"), *salvage)
        assert proc.returncode == 2
        assert "not a uSD event log" in proc.stderr and "CRC" not in proc.stderr
        assert not (tmp_path / "out.mcap").exists() and not list(tmp_path.glob("*.partial"))


def test_a_log_without_motion_capture_imports_without_ground_truth(tmp_path: Path, survey_0425: Path) -> None:
    log = tmp_path / "field"
    log.write_bytes(encode([t for t in TYPES if t.name != "estPose"],
                           [e for e in crafted_events(40) if e[0] != "estPose"]))
    rec = import_log(log, survey_0425)
    assert len(rec.truth) == 0 and len(rec.accel) == len(rec.gyro) == 40 and len(rec.tdoa) == 10
    write_recording(rec, tmp_path / "field.mcap")
    assert len(read_recording(tmp_path / "field.mcap").truth) == 0
    proc = run_rig("evaluate", str(log), "--survey", str(survey_0425))
    assert proc.returncode == 2 and "--start-position X Y Z" in proc.stderr


def test_a_survey_that_is_not_the_logs_is_refused(tmp_path: Path, survey_0425: Path) -> None:
    """A survey listing an anchor twice (which position is right?) or lacking one the log
    uses (another day's survey) is refused with the line or the anchor, not imported."""
    log = tmp_path / "log"
    log.write_bytes(crafted_log(40))
    lines = survey_0425.read_text().splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("anchorAnt3,"))
    twice = tmp_path / "twice.txt"
    twice.write_text("\n".join(lines + [lines[first].replace(",", ",1", 1)]) + "\n")
    proc = run_rig("import", str(log), "--survey", str(twice), "-o", str(tmp_path / "out.mcap"))
    assert proc.returncode == 2
    assert f"twice.txt:{len(lines) + 1}: anchorAnt3 is defined again (first on line {first + 1})" in proc.stderr
    lacking = tmp_path / "lacking.txt"
    lacking.write_text("\n".join(line for line in lines if not line.startswith(("anchorAnt5", "anchor5_"))) + "\n")
    proc = run_rig("import", str(log), "--survey", str(lacking), "-o", str(tmp_path / "out.mcap"))
    assert proc.returncode == 2
    assert "use anchor(s) 5" in proc.stderr and "which this survey lacks" in proc.stderr
    assert not (tmp_path / "out.mcap").exists()


def test_salvage_drops_events_whose_timestamps_were_damaged_and_leaves_no_partial_file(tmp_path: Path,
                                                                                    survey_0425: Path) -> None:
    """One flipped byte in an event's timestamp (the CRC then fails): --salvage imports
    every other event, drops and counts the damaged one instead of importing a stamp
    hours away, and leaves nothing half-written behind."""
    events = crafted_events(200)
    damaged = len(events) // 2
    offset = len(encode(TYPES, events[:damaged])) - 4 + 2 + 5      # past the CRC's place, the event id; a high byte
    data = bytearray(encode(TYPES, events))
    data[offset] ^= 0x40
    log = tmp_path / "log"
    log.write_bytes(bytes(data))
    out = tmp_path / "out.mcap"
    proc = run_rig("import", str(log), "--survey", str(survey_0425), "-o", str(out), "--salvage")
    assert proc.returncode == 0, proc.stderr
    assert "1 events whose timestamps leave the log's time range or run backwards" in proc.stderr
    rec = read_recording(out)
    assert len(rec.accel) + len(rec.gyro) + len(rec.truth) + len(rec.tdoa) == len(events) - 1
    assert rec.time_span()[1] - rec.time_span()[0] < 1.0
    assert not list(tmp_path.glob("*.partial"))
