"""The uSD event-log decoder: format checks, truncation, corruption, salvage."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from rigtest import TYPES, crafted_log

from rig.data.usdlog import LogFormatError, decode


def test_crafted_log_round_trips() -> None:
    decoded = decode(crafted_log(50))
    assert decoded.crc_ok and decoded.version == 2
    assert decoded.counts() == {"estAcceleration": 50, "estGyroscope": 50, "estPose": 13, "estTDOA": 13}
    acc = decoded.series("estAcceleration")
    assert acc.type.variables == ("acc.x", "acc.y", "acc.z")
    np.testing.assert_allclose(acc.values[0], [0.0, 0.5, 1.0])
    assert decoded.series("estTDOA").values[:, :2].max() <= 7


def test_bad_magic_is_rejected() -> None:
    data = bytearray(crafted_log())
    data[0] = 0xAB
    body = bytes(data[:-4])
    with pytest.raises(LogFormatError, match="magic"):
        decode(body + struct.pack("<I", zlib.crc32(body)))


def test_unsupported_version_is_rejected() -> None:
    data = bytearray(crafted_log())
    data[1:3] = struct.pack("<H", 3)
    body = bytes(data[:-4])
    with pytest.raises(LogFormatError, match="version 3"):
        decode(body + struct.pack("<I", zlib.crc32(body)))


@pytest.mark.parametrize("cut", [1, 7, 100, 1000])
def test_truncated_log_fails_clearly(cut: int) -> None:
    """And says how to keep what is left: any command reading a log stops here, and
    only `rig import` salvages."""
    with pytest.raises(LogFormatError, match=r"CRC-32.*`rig import --salvage` imports its valid prefix"):
        decode(crafted_log()[:-cut])


def test_flipped_byte_fails_the_crc() -> None:
    data = bytearray(crafted_log())
    data[len(data) // 2] ^= 0x40
    with pytest.raises(LogFormatError, match="CRC-32 mismatch"):
        decode(bytes(data))


def test_salvage_keeps_the_valid_prefix_and_says_what_was_dropped() -> None:
    full = decode(crafted_log(50))
    cut = decode(crafted_log(50)[:-103], salvage=True)
    assert not cut.crc_ok
    assert any("CRC" in d for d in cut.dropped) and any("cut short" in d or "trailing" in d for d in cut.dropped)
    for name, n in cut.counts().items():
        assert 0 < full.counts()[name] - n <= 8 or n == full.counts()[name]
        np.testing.assert_array_equal(cut.series(name).values, full.series(name).values[:n])


def test_salvage_stops_at_an_unknown_event_id() -> None:
    data = bytearray(crafted_log(20))
    header_end = len(crafted_log(0)) - 4
    data[header_end] = 0xEE  # first event's id becomes unknown
    decoded = decode(bytes(data), salvage=True)
    assert sum(decoded.counts().values()) == 0
    assert any("unknown event id" in d for d in decoded.dropped)


def test_truncated_header_fails_even_with_salvage() -> None:
    with pytest.raises(LogFormatError, match="header truncated"):
        decode(crafted_log()[:20], salvage=True)


def test_types_declared_are_all_reported_even_when_empty() -> None:
    decoded = decode(crafted_log(0))
    assert set(decoded.counts()) == {t.name for t in TYPES}
    assert all(n == 0 for n in decoded.counts().values())
