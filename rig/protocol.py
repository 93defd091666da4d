"""Python twin of the wire protocol (estimator_c/include/protocol.h, docs/protocol.md).

Frames are COBS(payload || CRC-16/CCITT-FALSE little-endian) + 0x00; a payload is a
type byte and little-endian fields, at most 30 bytes (one CRTP app-channel packet).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

VERSION = 1
MAX_PAYLOAD = 30
ACCEL_LSB = np.float32(0.005)
GYRO_LSB = np.float32(0.001)
QUAT_LSB = np.float32(1.0 / 32767.0)

HELLO, PARAM, ANCHOR, NET_CHUNK, NET_COMMIT, RESET, IMU, TDOA, STEP = range(0x01, 0x0A)
HELLO_REPLY, ACK, ESTIMATE, ATTITUDE, COUNTERS, TIMING, STATUS = range(0x81, 0x88)
NET_CHUNK_BYTES = MAX_PAYLOAD - 3
UNITS = {0: "ns", 1: "cycles", 2: "instructions"}
STATUS_BOOT, STATUS_BAD_FRAME, STATUS_BAD_MESSAGE = 1, 2, 3


class ProtocolError(Exception):
    """A message that cannot be encoded or a reply that makes no sense."""


def crc16(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    out = bytearray([0])
    code_at, code = 0, 1
    for byte in data:
        if byte == 0:
            out[code_at] = code
            code_at, code = len(out), 1
            out.append(0)
        else:
            out.append(byte)
            code += 1
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        i += 1
        if code == 0 or i + code - 1 > len(data) or 0 in data[i:i + code - 1]:
            raise ProtocolError("bad COBS block")
        out += data[i:i + code - 1]
        i += code - 1
        if code < 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


def frame(payload: bytes) -> bytes:
    if not 0 < len(payload) <= MAX_PAYLOAD:
        raise ProtocolError(f"payload of {len(payload)} bytes (1..{MAX_PAYLOAD})")
    return cobs_encode(payload + struct.pack("<H", crc16(payload))) + b"\x00"


@dataclass
class Parser:
    """Byte stream to verified payloads; corrupt frames are counted and skipped."""

    max_frame: int = MAX_PAYLOAD + 4
    frames_ok: int = 0
    frames_bad: int = 0
    bytes_dropped: int = 0
    _buf: bytearray = field(default_factory=bytearray)
    _overflow: bool = False

    def feed(self, data: bytes) -> list[bytes]:
        payloads = []
        for byte in data:
            if byte == 0:
                if self._overflow:
                    self._overflow = False
                    self.frames_bad += 1
                elif self._buf:
                    payload = self._finish()
                    if payload is not None:
                        payloads.append(payload)
                self._buf.clear()
            elif self._overflow:
                self.bytes_dropped += 1
            elif len(self._buf) >= self.max_frame:
                self._overflow = True
                self.bytes_dropped += len(self._buf) + 1
                self._buf.clear()
            else:
                self._buf.append(byte)
        return payloads

    def _finish(self) -> bytes | None:
        try:
            raw = cobs_decode(bytes(self._buf))
        except ProtocolError:
            self.frames_bad += 1
            return None
        if len(raw) < 3 or len(raw) > MAX_PAYLOAD + 2 or crc16(raw[:-2]) != struct.unpack("<H", raw[-2:])[0]:
            self.frames_bad += 1
            return None
        self.frames_ok += 1
        return raw[:-2]


# ----------------------------------------------------------------------------- host -> board

def quantize(value, lsb) -> np.ndarray:
    """The int16 the board receives (round half away from zero, saturating), as C's proto_quantize."""
    q = np.asarray(value, np.float32) / np.float32(lsb)
    q = np.where(np.isnan(q), 0, q)
    q = np.clip(q, -32767, 32767)
    return np.where(q >= 0, np.floor(q + np.float32(0.5)), np.ceil(q - np.float32(0.5))).astype(np.int16)


def hello() -> bytes:
    return bytes([HELLO])


def param(index: int, value: float) -> bytes:
    """Parameter `index` in the field order of est_params_t (native.EstimatorParams)."""
    return struct.pack("<BBf", PARAM, index, value)


def anchor(anchor_id: int, position, quaternion) -> bytes:
    return struct.pack("<BB3f4f", ANCHOR, anchor_id, *map(float, position), *map(float, quaternion))


def net_chunks(image: bytes) -> list[bytes]:
    return [struct.pack("<BH", NET_CHUNK, off) + image[off:off + NET_CHUNK_BYTES]
            for off in range(0, len(image), NET_CHUNK_BYTES)]


def net_commit(size: int) -> bytes:
    return struct.pack("<BH", NET_COMMIT, size)


def reset(t_us: int, position, quaternion) -> bytes:
    return struct.pack("<BI3f4h", RESET, t_us, *map(float, position), *quantize(quaternion, QUAT_LSB).tolist())


def imu(samples: list[tuple[int, np.ndarray, np.ndarray]]) -> bytes:
    """One or two samples (dt_us since the last STEP, accel m/s^2, gyro rad/s)."""
    if not 1 <= len(samples) <= 2:
        raise ProtocolError("an IMU message carries one or two samples")
    body = b"".join(struct.pack("<H3h3h", dt, *quantize(a, ACCEL_LSB).tolist(), *quantize(g, GYRO_LSB).tolist())
                    for dt, a, g in samples)
    return bytes([IMU]) + body


def tdoa(dt_us: int, id_a: int, id_b: int, value: float) -> bytes:
    return struct.pack("<BHBBf", TDOA, dt_us, id_a, id_b, value)


def step(t_us: int) -> bytes:
    return struct.pack("<BI", STEP, t_us)


# ----------------------------------------------------------------------------- board -> host

@dataclass
class HelloReply:
    version: int
    api_version: int
    unit: str
    max_anchors: int
    timer_hz: int
    net_size: int
    capabilities: int


@dataclass
class Ack:
    acked: int
    status: int


@dataclass
class Estimate:
    t_us: int
    pos: tuple
    vel: tuple


@dataclass
class Attitude:
    quat: tuple
    cov_diag: tuple


@dataclass
class Counters:
    steps: int
    accepted: int
    downweighted: int
    rejected: int
    resets: int
    imu_gaps: int
    gated: int


@dataclass
class Timing:
    t_us: int
    window: int
    predict: int
    tdoa_total: int
    tdoa_max: int
    n_tdoa: int


@dataclass
class Status:
    code: int
    frames_ok: int
    frames_bad: int
    bytes_dropped: int


_DECODERS = {
    HELLO_REPLY: ("<BBBBIHB", lambda v: HelloReply(v[0], v[1], UNITS.get(v[2], "?"), v[3], v[4], v[5], v[6])),
    ACK: ("<Bb", lambda v: Ack(*v)),
    ESTIMATE: ("<I3f3f", lambda v: Estimate(v[0], v[1:4], v[4:7])),
    ATTITUDE: ("<4h9e", lambda v: Attitude(tuple(float(np.float32(q) * QUAT_LSB) for q in v[:4]), v[4:])),
    COUNTERS: ("<IIIIHHH", lambda v: Counters(*v)),
    TIMING: ("<IIIIIB", lambda v: Timing(*v)),
    STATUS: ("<BIII", lambda v: Status(*v)),
}


def decode(payload: bytes):
    """A board message as its dataclass."""
    if not payload or payload[0] not in _DECODERS:
        raise ProtocolError(f"unknown message type {payload[:1].hex() or '(empty)'}")
    fmt, build = _DECODERS[payload[0]]
    if len(payload) - 1 != struct.calcsize(fmt):
        raise ProtocolError(f"message 0x{payload[0]:02x} of {len(payload)} bytes")
    return build(struct.unpack(fmt, payload[1:]))
