"""Wire protocol: the Python twin round-trips and resynchronises (property tests), its
C-backed CRC, COBS and stream parser agree with byte-by-byte references; the C
parser, inside the native program under sanitizers, drops corrupt frames and keeps going."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.estimator import native
from rig.hil import protocol

payloads = st.binary(min_size=1, max_size=protocol.MAX_PAYLOAD)


def reference_crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit, as the board's C computes it."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def reference_cobs(data: bytes) -> bytes:
    out, code_at, code = bytearray([0]), 0, 1
    for byte in data:
        if byte == 0:
            out[code_at], code_at, code = code, len(out), 1
            out.append(0)
        else:
            out.append(byte)
            code += 1
    out[code_at] = code
    return bytes(out)


class ReferenceParser(protocol.Parser):
    """The stream walked byte by byte, the plainest statement of the counting rules."""

    def feed(self, data: bytes) -> list[bytes]:
        payloads, buf = [], bytearray(self._buf)
        for byte in data:
            if byte == 0:
                if self._overflow:
                    self._overflow = False
                    self.frames_bad += 1
                elif buf:
                    payload = self._finish(bytes(buf))
                    if payload is not None:
                        payloads.append(payload)
                buf.clear()
            elif self._overflow:
                self.bytes_dropped += 1
            elif len(buf) >= self.max_frame:
                self._overflow = True
                self.bytes_dropped += len(buf) + 1
                buf.clear()
            else:
                buf.append(byte)
        self._buf = bytes(buf)
        return payloads


@given(st.binary(max_size=40))
def test_crc_and_cobs_are_the_boards(data: bytes) -> None:
    assert protocol.crc16(data) == reference_crc16(data)
    assert protocol.cobs_encode(data) == reference_cobs(data)


@settings(max_examples=300)
@given(st.lists(st.one_of(payloads.map(protocol.frame), st.binary(max_size=80),
                          st.just(b"\x00")), max_size=12),
       st.lists(st.integers(1, 50), min_size=1, max_size=6))
def test_the_parser_counts_as_the_byte_by_byte_reference_in_any_cut_of_the_stream(
        pieces: list[bytes], cuts: list[int]) -> None:
    """Frames, garbage and overlong runs, fed in arbitrary chunks: the same payloads and
    the same counters as walking the stream byte by byte."""
    stream, fast, reference = b"".join(pieces), protocol.Parser(), ReferenceParser()
    out_fast, out_reference, i, k = [], [], 0, 0
    while i < len(stream):
        chunk = stream[i:i + cuts[k % len(cuts)]]
        out_fast += fast.feed(chunk)
        out_reference += reference.feed(chunk)
        i, k = i + len(chunk), k + 1
    assert out_fast == out_reference
    counters = ("frames_ok", "frames_bad", "bytes_dropped", "_overflow", "_buf")
    assert [getattr(fast, c) for c in counters] == [getattr(reference, c) for c in counters]


def reference_cobs_decode(data: bytes) -> bytes | None:
    """COBS decoded block by block, the plain way (None: not COBS)."""
    out, i = bytearray(), 0
    while i < len(data):
        code = data[i]
        block = data[i + 1:i + code]
        if code == 0 or len(block) != code - 1 or 0 in block:
            return None
        out += block
        i += code
        if code < 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


@settings(max_examples=500)
@given(st.one_of(st.binary(max_size=300).map(protocol.cobs_encode), st.binary(max_size=300)))
def test_cobs_decoding_is_the_plain_block_walk(data: bytes) -> None:
    """Encoded data of any length (0xFF blocks included) and garbage alike: the same bytes,
    or the same refusal, as the block-by-block reference."""
    expected = reference_cobs_decode(data)
    if expected is None:
        with pytest.raises(protocol.ProtocolError):
            protocol.cobs_decode(data)
    else:
        assert protocol.cobs_decode(data) == expected


@given(payloads)
def test_cobs_frame_round_trips(payload: bytes) -> None:
    frame = protocol.frame(payload)
    assert frame.count(0) == 1 and frame.endswith(b"\x00")
    assert protocol.Parser().feed(frame) == [payload]


@settings(max_examples=200)
@given(st.lists(payloads, min_size=1, max_size=8), st.lists(st.binary(max_size=60), min_size=1, max_size=8))
def test_garbage_between_frames_loses_only_itself(good: list[bytes], garbage: list[bytes]) -> None:
    parser = protocol.Parser()
    stream = b""
    for k, payload in enumerate(good):
        stream += garbage[k % len(garbage)] + b"\x00" + protocol.frame(payload)
    assert parser.feed(stream) == good


@given(st.binary(min_size=1, max_size=protocol.MAX_PAYLOAD), st.integers(0, 1000), st.integers(1, 255))
def test_a_flipped_byte_is_never_accepted_as_the_original(payload: bytes, where: int, flip: int) -> None:
    frame = bytearray(protocol.frame(payload))
    k = where % (len(frame) - 1)
    frame[k] ^= flip
    out = protocol.Parser().feed(bytes(frame) + protocol.frame(b"\x01"))
    assert out[-1] == b"\x01"          # the next frame always survives
    assert payload not in out[:-1] or len(out) == 1


def test_c_parser_survives_random_bytes_and_counts_bad_frames() -> None:
    native.make("program-asan")
    program = native.ESTIMATOR_DIR / "build" / "estimator_native-asan"
    import random

    rng = random.Random(7)
    noise = bytes(rng.randrange(256) for _ in range(20000))
    stream = noise + b"\x00" + protocol.frame(protocol.hello())
    out = subprocess.run([str(program)], input=stream, capture_output=True, timeout=60, check=True).stdout
    messages = [protocol.decode(p) for p in protocol.Parser().feed(out)]
    assert isinstance(messages[-1], protocol.HelloReply)       # resynchronised after the noise
    statuses = [m for m in messages if isinstance(m, protocol.Status)]
    assert statuses[0].code == protocol.STATUS_BOOT
    assert max(s.frames_bad for s in statuses) > 10


imu_counts = st.lists(st.lists(st.integers(-32767, 32767), min_size=6, max_size=6), min_size=1, max_size=40)
small_steps = st.lists(st.lists(st.integers(-127, 127), min_size=6, max_size=6), min_size=1, max_size=40)


def _board_imu(board: protocol.BoardView, msgs: list[bytes]) -> np.ndarray:
    rows = [r for m in msgs for r in board.events(m)]
    acc = np.array([r[4] for r in rows if r[1] == "accel"]).reshape(-1, 3)
    gyro = np.array([r[4] for r in rows if r[1] == "gyro"]).reshape(-1, 3)
    return np.hstack([np.rint(acc / protocol.ACCEL_LSB), np.rint(gyro / protocol.GYRO_LSB)])


@settings(max_examples=200)
@given(imu_counts, small_steps)
def test_imu_stream_round_trips_any_samples(jumps: list, steps: list) -> None:
    """Arbitrary jumps (keys) mixed with small steps (deltas) come out exactly as sent."""
    counts = np.clip(np.cumsum(np.array(jumps + steps), axis=0), -32767, 32767)
    stream, board = protocol.ImuStream(key_every=7), protocol.BoardView()
    msgs = stream.encode(counts[: len(counts) // 2]) + stream.encode(counts[len(counts) // 2:])
    assert all(len(m) <= protocol.MAX_PAYLOAD for m in msgs)
    np.testing.assert_array_equal(_board_imu(board, msgs), counts)
    assert board.lost == 0


@given(st.lists(st.tuples(*[st.integers(-128, 127)] * 6), min_size=1, max_size=protocol.IMU_DELTA_MAX))
def test_a_packed_delta_message_holds_the_longest_prefix_that_fits(deltas: list) -> None:
    """As many samples as fit one message: each column as wide as its widest value in it."""
    def size(n: int) -> int:
        widths = [max(v if v >= 0 else -v - 1 for v in column).bit_length() + 1 for column in zip(*deltas[:n])]
        return protocol.IMU_DELTA_HEADER + (n * sum(widths) + 7) // 8

    n, payload = protocol._packed_deltas(deltas)
    assert n == max(k for k in range(1, len(deltas) + 1) if k == 1 or size(k) <= protocol.MAX_PAYLOAD)
    assert 2 + len(payload) == size(n)


def test_a_lost_imu_frame_costs_only_until_the_next_key() -> None:
    counts = np.cumsum(np.ones((200, 6), int), axis=0)
    msgs = protocol.ImuStream(key_every=10).encode(counts)
    board = protocol.BoardView()
    received = _board_imu(board, msgs[:3] + msgs[4:])
    # key, 10 deltas, key, ...: losing delta 3 loses deltas 4..10, and the key after them resyncs
    assert board.lost == 7
    assert len(received) < len(counts)
    np.testing.assert_array_equal(received[-20:], counts[-20:])   # back in step after the key


@settings(max_examples=200)
@given(st.lists(st.tuples(st.integers(0, 65535), st.integers(0, 20), st.integers(0, 20),
                          st.floats(allow_nan=True, allow_infinity=True, width=32)), max_size=14))
def test_tdoa_messages_deliver_every_measurement(tdoas: list) -> None:
    msgs = protocol.tdoa_messages(tdoas, 123456)
    assert all(len(m) <= protocol.MAX_PAYLOAD for m in msgs)
    board = protocol.BoardView(t_step=1000)
    rows = [r for m in msgs for r in board.events(m)]
    assert rows[-1][:2] == (123456, "step")
    got = sorted((t - 1000, a, b) for t, kind, a, b, _ in rows if kind == "tdoa")
    assert got == sorted((dt, a, b) for dt, a, b, _ in tdoas)
    for t, kind, a, b, v in rows:
        if kind == "tdoa":
            sent = [x[3] for x in tdoas if (x[0], x[1], x[2]) == (t - 1000, a, b)]
            assert any(v[0] == x or abs(v[0] - x) <= 0.0005 + 1e-6 * abs(x) or (np.isnan(x) and np.isnan(v[0])) for x in sent)


def test_every_message_fits_one_crtp_packet() -> None:
    msgs = [protocol.anchor(1, [1, 2, 3], [0, 0, 0, 1]), protocol.reset(1, [0, 0, 0], [0, 0, 0, 1]),
            *protocol.ImuStream().encode(np.arange(60).reshape(10, 6)), protocol.tdoa(1, 2, 3, 0.5),
            *protocol.tdoa_messages([(1, 2, 3, 0.5)] * 12, 7), *protocol.net_chunks(bytes(3296))]
    assert max(len(m) for m in msgs) <= protocol.MAX_PAYLOAD


def test_windows_encoded_before_the_replay_are_the_bytes_of_encoding_each_as_it_goes(default_rec) -> None:
    from rig.estimator.evaluate import build_events, start_time
    from rig.hil import replay

    t0 = start_time(default_rec)
    ws = replay.windows(build_events(default_rec, t0, t0 + 3.0))
    stream, one_by_one = protocol.ImuStream(), []
    for w in ws:
        counts = protocol.imu_counts([a for _, a, _ in w.imu], [g for _, _, g in w.imu]) if w.imu else []
        one_by_one.append((stream.encode(counts) if len(counts) else []) + protocol.tdoa_messages(w.tdoa, w.t_us))
    assert replay.encode_windows(ws) == one_by_one
    assert sum(len(w.imu) for w in ws) > 2000 and sum(map(len, one_by_one)) > 3 * len(ws)


def test_an_attitude_is_scaled_as_the_board_scales_it_in_float32() -> None:
    """Every int16 quaternion count, decoded without numpy, is numpy's float32 product."""
    counts = np.arange(-32768, 32768).reshape(-1, 4)
    decoded = [q for row in counts.tolist() for q in protocol._quaternion(row)]
    assert decoded == (counts.astype(np.float32) * protocol.QUAT_LSB).ravel().tolist()


def test_an_estimate_on_zenoh_is_strict_json_a_diverged_boards_nan_is_null() -> None:
    import json

    from rig.hil.zenoh import message_json

    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")

    nan, inf = float("nan"), float("inf")
    text = message_json(protocol.Estimate(1_000_000, (nan, 1.5, inf), (0.0, -inf, 0.25)))
    assert json.loads(text, parse_constant=refuse) == {"t_us": 1_000_000, "pos": [None, 1.5, None],
                                                       "vel": [0.0, None, 0.25]}
