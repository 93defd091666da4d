"""Wire protocol: the Python twin round-trips and resynchronises (property tests); the C
parser, inside the native program under sanitizers, drops corrupt frames and keeps going."""

from __future__ import annotations

import subprocess

from hypothesis import given, settings
from hypothesis import strategies as st

from rig import native, protocol

payloads = st.binary(min_size=1, max_size=protocol.MAX_PAYLOAD)


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


def test_every_message_fits_one_crtp_packet() -> None:
    import numpy as np

    msgs = [protocol.anchor(1, [1, 2, 3], [0, 0, 0, 1]), protocol.reset(1, [0, 0, 0], [0, 0, 0, 1]),
            protocol.imu([(1, np.ones(3), np.ones(3))] * 2), protocol.tdoa(1, 2, 3, 0.5), protocol.step(7),
            *protocol.net_chunks(bytes(3296))]
    assert max(len(m) for m in msgs) <= protocol.MAX_PAYLOAD
