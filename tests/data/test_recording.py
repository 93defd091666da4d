"""MCAP writing: a file whose writing stopped is finished from its whole records."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from rig.data.recording import McapJsonWriter, seal_unfinished

ROOT = Path(__file__).resolve().parents[2]

MESSAGES = 3000


def _written(path: Path) -> Path:
    """A finished file of MESSAGES messages in small chunks, each numbered."""
    with McapJsonWriter(path, chunk_size=2048) as out:
        channel = out.channel("/n", "n", {"type": "object"})
        for k in range(MESSAGES):
            out.write(channel, k * 0.01, f'{{"n": {k}}}')
    return path


def _numbers(path: Path) -> list[int]:
    with open(path, "rb") as stream:
        return [int(message.data[6:-1]) for _, _, message in make_reader(stream).iter_messages()]


@pytest.mark.parametrize("share", [0.2, 0.5, 0.93])
def test_a_file_cut_anywhere_is_finished_with_every_whole_record_before_the_cut(tmp_path: Path, share: float) -> None:
    whole = _written(tmp_path / "whole.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: int(len(whole) * share)])
    with pytest.raises(Exception):
        _numbers(cut)                                     # the stock reader stops at the cut record
    assert seal_unfinished(cut)
    numbers = _numbers(cut)
    assert numbers == list(range(len(numbers)))           # a prefix, in order, nothing invented
    assert len(numbers) > share * MESSAGES * 0.8
    assert cut.stat().st_size <= len(whole) * share + 50


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.0, 1.0))
def test_any_cut_of_a_file_is_finished_to_a_prefix_the_stock_reader_reads(tmp_path: Path, cut: float) -> None:
    """Wherever the writing stopped, sealing leaves a file the stock reader reads, a
    prefix of the messages in order; or, when not even the header is whole, the file
    as it was."""
    source = tmp_path / "whole.mcap"                     # one per test: hypothesis reuses tmp_path
    whole = source.read_bytes() if source.exists() else _written(source).read_bytes()
    data = whole[: int(len(whole) * cut)]
    path = tmp_path / "cut.mcap"
    path.write_bytes(data)
    kept = seal_unfinished(path)
    if kept is None:                                      # the cut is inside the magic or the header record
        header_end = 8 + 9 + int.from_bytes(whole[9:17], "little")
        assert path.read_bytes() == data and len(data) < header_end
        return
    numbers = _numbers(path)
    assert numbers == list(range(len(numbers)))
    assert kept <= len(data)


def test_what_is_not_a_file_with_a_whole_header_is_left_as_it_is(tmp_path: Path) -> None:
    header_only = tmp_path / "short.mcap"
    header_only.write_bytes(_written(tmp_path / "whole.mcap").read_bytes()[:12])
    assert not seal_unfinished(header_only)
    assert header_only.stat().st_size == 12
    assert not seal_unfinished(Path("/dev/full"))
    assert not seal_unfinished(tmp_path / "absent.mcap")


@pytest.fixture(scope="module")
def default_recording():
    from rig.data.recording import read_recording

    return read_recording(ROOT / "recordings" / "default.mcap")


@pytest.mark.parametrize("fault", ["duplicated", "non-finite"])
def test_an_anchor_set_with_a_duplicated_or_non_finite_anchor_is_refused_from_file_and_cache(
        tmp_path: Path, default_recording, fault: str) -> None:
    from dataclasses import replace

    from rig.data import cache
    from rig.data.errors import RecordingError
    from rig.data.recording import read_recording, write_recording
    from rig.data.survey import Anchor

    anchors = list(default_recording.anchors)
    a = anchors[2]
    if fault == "duplicated":
        anchors.append(Anchor(a.id, (a.position[0] + 1.0, a.position[1], a.position[2]), a.quaternion))
    else:
        anchors[2] = Anchor(a.id, (float("nan"), a.position[1], a.position[2]), a.quaternion)
    bad = replace(default_recording, anchors=anchors)
    path = tmp_path / "bad.mcap"
    write_recording(bad, path)
    expected = f"anchor id\\(s\\) \\[{a.id}\\] appear more than once" if fault == "duplicated" else \
        f"anchor\\(s\\) \\[{a.id}\\] .* non-finite"
    with pytest.raises(RecordingError, match=expected):
        read_recording(path)
    cache.store(path, rec=bad)                       # as an entry cached before the check existed
    with pytest.raises(RecordingError, match=expected):
        cache.read_cached(path)


def test_a_writer_interrupted_while_finishing_still_closes_its_file(tmp_path: Path, monkeypatch) -> None:
    writer = McapJsonWriter(tmp_path / "x.mcap")

    def interrupted() -> None:
        raise KeyboardInterrupt("SIGTERM")
    monkeypatch.setattr(writer._writer, "finish", interrupted)
    with pytest.raises(KeyboardInterrupt):
        writer.close()
    assert writer._stream.closed
    writer.close()                                        # once closed, closing again does nothing
