"""Python twin of the wire protocol (estimator_c/include/protocol.h, docs/reference/protocol.md).

Frames are COBS(payload || CRC-16/CCITT-FALSE little-endian) + 0x00; a payload is a
type byte and little-endian fields, at most 30 bytes (one CRTP app-channel packet).
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field

import numpy as np

VERSION = 5
ESTIMATOR_API = 4      # EST_API_VERSION: est_params_t's fields (which PARAM indexes), and what COUNTERS count
MAX_PAYLOAD = 30
ACCEL_LSB = np.float32(0.005)
GYRO_LSB = np.float32(0.001)
QUAT_LSB = np.float32(1.0 / 32767.0)
TDOA_LSB = np.float32(0.001)

HELLO, PARAM, ANCHOR, NET_CHUNK, NET_COMMIT, RESET, IMU, TDOA, STEP, IMU_DELTA, TDOA_PACK, STEP_BRIEF, \
    ANCHORS_CLEAR = range(0x01, 0x0E)
HELLO_REPLY, ACK, ESTIMATE, ATTITUDE, COUNTERS, TIMING, STATUS = range(0x81, 0x88)
NET_CHUNK_BYTES = MAX_PAYLOAD - 3
IMU_AXES = 6
IMU_KEY_MAX_DELTAS = 2
IMU_DELTA_HEADER = 5          # type, seq, 24-bit layout
IMU_DELTA_MAX = 8             # samples in one packed delta message (3-bit count)
TDOA_PACK_MAX = 5
PACKED_ID_LIMIT = 16          # anchor ids that fit a nibble
UNITS = {0: "ns", 1: "cycles", 2: "instructions"}
STATUS_BOOT, STATUS_BAD_FRAME, STATUS_BAD_MESSAGE, STATUS_RX_OVERFLOW = 1, 2, 3, 4
STATUS_MEANING = {STATUS_BOOT: "started", STATUS_BAD_FRAME: "dropped a corrupt frame",
                  STATUS_BAD_MESSAGE: "refused a message it does not know",
                  STATUS_RX_OVERFLOW: "lost bytes to a full receive buffer"}
CAP_BIAS_NET, CAP_BRIEF_STEP = 0x01, 0x02      # capability bits of the hello reply
TRUST_FULL = 65535          # COUNTERS' correction trust for the whole correction (PROTO_TRUST_FULL)


class ProtocolError(Exception):
    """A message that cannot be encoded or a reply that makes no sense."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF), as the board computes it;
    binascii's CRC-CCITT is the same code in C."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """COBS for frames under 254 bytes (every frame here): each zero ends a block whose
    code byte is its length + 1."""
    return b"".join(bytes([len(block) + 1]) + block for block in data.split(b"\x00"))


def cobs_decode(data: bytes) -> bytes:
    """Each code byte but the first stands for the zero it replaced: set them to zero and
    drop the first, walking only from code to code (a frame's bytes are checked in C).
    A 0xFF code (a block with no zero after it, only in frames of 254 bytes or more)
    goes the long way."""
    if 0 in data:
        raise ProtocolError("bad COBS block")
    out, i = bytearray(data), 0
    while i < len(out):
        code = out[i]
        if code == 0xFF:
            return _cobs_decode_long(data)
        out[i] = 0
        i += code
    if i != len(out):
        raise ProtocolError("bad COBS block")
    return bytes(out[1:])


def _cobs_decode_long(data: bytes) -> bytes:
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


def frames(payloads: list[bytes]) -> bytes:
    """Several payloads framed back to back: what one write to the link carries."""
    return b"".join(map(frame, payloads))


@dataclass
class Parser:
    """Byte stream to verified payloads; corrupt frames are counted and skipped. A frame
    longer than `max_frame` is dropped whole (its bytes counted) and counted bad at its
    delimiter. The stream is cut at its zero bytes (in C), not walked byte by byte."""

    max_frame: int = MAX_PAYLOAD + 4
    frames_ok: int = 0
    frames_bad: int = 0
    bytes_dropped: int = 0
    _buf: bytes = b""
    _overflow: bool = False

    def feed(self, data: bytes) -> list[bytes]:
        *ended, rest = bytes(data).split(b"\x00")
        payloads = []
        for part in ended:
            if self._take(part):
                self.frames_bad += 1             # an overlong frame ends here
            elif self._buf:
                payload = self._finish(self._buf)
                if payload is not None:
                    payloads.append(payload)
            self._buf, self._overflow = b"", False
        self._take(rest)
        return payloads

    def _take(self, part: bytes) -> bool:
        """Add bytes of the current frame; True while it is overlong (its bytes dropped)."""
        if not self._overflow:
            self._buf += part
            if len(self._buf) <= self.max_frame:
                return False
            self._overflow, part, self._buf = True, self._buf, b""
        self.bytes_dropped += len(part)
        return True

    def _finish(self, encoded: bytes) -> bytes | None:
        try:
            raw = cobs_decode(encoded)
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
    with np.errstate(over="ignore", invalid="ignore"):     # beyond int16 saturates, as on the board
        q = np.asarray(value, np.float32) / np.float32(lsb)
    q = np.where(np.isnan(q), 0, q)
    q = np.clip(q, -32767, 32767)
    return np.where(q >= 0, np.floor(q + np.float32(0.5)), np.ceil(q - np.float32(0.5))).astype(np.int16)


def hello() -> bytes:
    return bytes([HELLO])


def param(index: int, value: float) -> bytes:
    """Parameter `index` in the field order of est_params_t (native.EstimatorParams)."""
    return struct.pack("<BBf", PARAM, index, value)


def anchors_clear() -> bytes:
    """Forget every anchor the board holds (from an earlier flight), before this one's."""
    return bytes([ANCHORS_CLEAR])


def anchor(anchor_id: int, position, quaternion) -> bytes:
    return struct.pack("<BB3f4f", ANCHOR, anchor_id, *map(float, position), *map(float, quaternion))


def net_chunks(image: bytes) -> list[bytes]:
    return [struct.pack("<BH", NET_CHUNK, off) + image[off:off + NET_CHUNK_BYTES]
            for off in range(0, len(image), NET_CHUNK_BYTES)]


def net_commit(size: int) -> bytes:
    return struct.pack("<BH", NET_COMMIT, size)


def reset(t_us: int, position, quaternion) -> bytes:
    return struct.pack("<BI3f4h", RESET, t_us, *map(float, position), *quantize(quaternion, QUAT_LSB).tolist())


def imu_counts(accel, gyro) -> np.ndarray:
    """IMU samples (n x 3 accel m/s^2, n x 3 gyro rad/s) as the int16 counts on the wire (n x 6)."""
    return np.hstack([quantize(accel, ACCEL_LSB), quantize(gyro, GYRO_LSB)]).reshape(-1, IMU_AXES)


def imu_values(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the board makes of int16 counts: float32 accel and gyro (n x 3 each)."""
    c = np.asarray(counts).reshape(-1, IMU_AXES).astype(np.float32)
    return c[:, :3] * ACCEL_LSB, c[:, 3:] * GYRO_LSB


@dataclass
class ImuStream:
    """Host side of the delta-coded IMU stream: a key message (absolute int16 sample) now
    and then, bit-packed differences in between. A key goes out at the start, whenever a
    difference does not fit int8, and every `key_every` messages, so a lost frame costs
    at most that many messages of IMU (the board counts them as lost)."""

    key_every: int = 50
    seq: int = 0
    last: np.ndarray | None = None
    since_key: int = 0

    def encode(self, counts: np.ndarray) -> list[bytes]:
        """One window's samples (n x 6 counts) as the stream's next messages."""
        return self.encode_windows([counts])[0]

    def encode_windows(self, windows: list[np.ndarray]) -> list[list[bytes]]:
        """encode() of each window in turn. Each sample's delta from the one before (the
        first's from the stream's last) and whether it fits int8 are computed in one
        pass over all windows; the messages are then cut on Python ints (a window holds
        about ten samples, too few for numpy to pay per window)."""
        sizes = [len(c) for c in windows]
        if not sum(sizes):
            return [[] for _ in windows]
        counts = np.concatenate([np.asarray(c, np.int32).reshape(-1, IMU_AXES) for c in windows])
        previous = counts[:1] if self.last is None else np.asarray(self.last, np.int32)[None]
        deltas = np.diff(np.vstack([previous, counts]), axis=0)
        fits = np.all(np.abs(deltas) <= 127, axis=1).tolist()
        if self.last is None:
            fits[0] = False
        rows, deltas = list(map(tuple, counts.tolist())), list(map(tuple, deltas.tolist()))
        out, first = [], 0
        for n in sizes:
            window = slice(first, first + n)
            out.append(self._messages(rows[window], deltas[window], fits[window]))
            first += n
        return out

    def _messages(self, rows: list[tuple], deltas: list[tuple], fits: list[bool]) -> list[bytes]:
        msgs, i = [], 0
        while i < len(rows):
            if self.since_key >= self.key_every or not fits[i]:
                n = 1 + _leading(fits[i + 1:i + 1 + IMU_KEY_MAX_DELTAS])
                flat = [d for delta in deltas[i + 1:i + n] for d in delta]
                msgs.append(struct.pack(f"<BB6h{len(flat)}b", IMU, self.seq, *rows[i], *flat))
                self.since_key = 0
            else:
                n, payload = _packed_deltas(deltas[i:i + _leading(fits[i:i + IMU_DELTA_MAX])])
                msgs.append(bytes([IMU_DELTA, self.seq]) + payload)
                self.since_key += 1
            self.seq = (self.seq + 1) & 0xFF
            self.last = rows[i + n - 1]
            i += n
        return msgs


def _leading(flags: list[bool]) -> int:
    """How many of `flags` are true before the first false."""
    for k, flag in enumerate(flags):
        if not flag:
            return k
    return len(flags)


def _packed_deltas(deltas: list[tuple]) -> tuple[int, bytes]:
    """The longest prefix of `deltas` (at least one) whose packed form fits one message.
    Each column's width is the two's-complement bits (1..8) of its largest magnitude so
    far; a longer prefix never needs fewer bits, so the first that does not fit ends it."""
    need, n, width = [0] * IMU_AXES, 0, None
    for row in deltas:
        need = [max(m, v if v >= 0 else -v - 1) for m, v in zip(need, row)]
        wider = [m.bit_length() + 1 for m in need]
        if n and IMU_DELTA_HEADER + ((n + 1) * sum(wider) + 7) // 8 > MAX_PAYLOAD:
            break
        n, width = n + 1, wider
    layout = sum((w - 1) << (3 * i) for i, w in enumerate(width)) | (n - 1) << 18
    bits, nbits = 0, 0
    for row in deltas[:n]:
        for value, w in zip(row, width):
            bits |= (value & ((1 << w) - 1)) << nbits
            nbits += w
    return n, layout.to_bytes(3, "little") + bits.to_bytes((nbits + 7) // 8, "little")


def tdoa(dt_us: int, id_a: int, id_b: int, value: float) -> bytes:
    """Any TDOA, with a float32 value (also NaN or huge ones, which the board rejects and counts)."""
    return struct.pack("<BHBBf", TDOA, dt_us, id_a, id_b, value)


def tdoa_item(dt_us: int, id_a: int, id_b: int, value: float, counts: int | None = None) -> bytes | None:
    """A packed TDOA item (5 bytes), or None when the ids or the value do not fit it.
    `counts`: the value already quantised (as `quantize` makes it), when known."""
    q = float(value) / float(TDOA_LSB)
    if not (math.isfinite(q) and abs(q) < 32767.0 and 0 <= id_a < PACKED_ID_LIMIT and 0 <= id_b < PACKED_ID_LIMIT
            and 0 <= dt_us <= 0xFFFF):
        return None
    return struct.pack("<HBh", dt_us, id_a << 4 | id_b, int(quantize(value, TDOA_LSB)) if counts is None else counts)


def tdoa_pack(items: list[bytes]) -> bytes:
    if not 1 <= len(items) <= TDOA_PACK_MAX:
        raise ProtocolError(f"a TDOA pack carries 1..{TDOA_PACK_MAX} items")
    return bytes([TDOA_PACK]) + b"".join(items)


def step(t_us: int, items: list[bytes] = ()) -> bytes:
    """End of a window, carrying the window's last (up to five) packed TDOA items."""
    if len(items) > TDOA_PACK_MAX:
        raise ProtocolError(f"a STEP carries at most {TDOA_PACK_MAX} TDOA items")
    return struct.pack("<BI", STEP, t_us) + b"".join(items)


def brief(step_payload: bytes) -> bytes:
    """The same STEP, answered by the estimate and attitude only (STEP_BRIEF): the
    counters and the timing come with the next full STEP, the timing then of the most
    expensive window since the last one reported."""
    if step_payload[:1] != bytes((STEP,)):
        raise ProtocolError("only a STEP can be made brief")
    return bytes((STEP_BRIEF,)) + step_payload[1:]


def tdoa_messages(tdoas: list[tuple[int, int, int, float]], t_step_us: int,
                  counts: list[int] | None = None) -> list[bytes]:
    """A window's TDOAs and its STEP: unpackable ones as TDOA, the rest packed, the last
    five of them riding on the STEP. `counts`: the values already quantised."""
    items, full = [], []
    if counts is None:
        counts = quantize([v for _, _, _, v in tdoas], TDOA_LSB).tolist() if tdoas else []
    for (dt, a, b, v), q in zip(tdoas, counts):
        item = tdoa_item(dt, a, b, v, q)
        items.append(item) if item is not None else full.append(tdoa(dt, a, b, v))
    split = max(0, len(items) - TDOA_PACK_MAX)
    packs = [tdoa_pack(items[k:min(k + TDOA_PACK_MAX, split)]) for k in range(0, split, TDOA_PACK_MAX)]
    return full + packs + [step(t_step_us, items[split:])]


@dataclass
class BoardView:
    """What the board's service makes of host messages (targets/common/service.c): the
    estimator events it generates, as (t_us, kind, id_a, id_b, value[3]) rows with kind
    'accel', 'gyro', 'tdoa' or 'step'. The twin the in-process library is compared with."""

    t_step: int = 0
    last: np.ndarray = field(default_factory=lambda: np.zeros(IMU_AXES, np.int32))
    next_seq: int = 0
    valid: bool = False
    lost: int = 0

    def events(self, payload: bytes) -> list[tuple]:
        kind = payload[0]
        if kind == IMU:
            self.last = np.array(struct.unpack_from("<6h", payload, 2), np.int32)
            self.valid, self.next_seq = True, (payload[1] + 1) & 0xFF
            return self._imu([self.last]) + self._deltas(payload[14:])
        if kind == IMU_DELTA:
            if not self.valid or payload[1] != self.next_seq:
                self.valid, self.lost = False, self.lost + 1
                return []
            self.next_seq = (self.next_seq + 1) & 0xFF
            return self._imu(self._unpack(payload))
        if kind == TDOA:
            dt, a, b, v = struct.unpack("<HBBf", payload[1:])
            return [(self.t_step + dt, "tdoa", a, b, (v, 0.0, 0.0))]
        if kind == TDOA_PACK:
            return self._packed(payload[1:])
        if kind in (STEP, STEP_BRIEF):
            out = self._packed(payload[5:])
            self.t_step = struct.unpack_from("<I", payload, 1)[0]
            return out + [(self.t_step, "step", 0, 0, (0.0, 0.0, 0.0))]
        return []

    def _unpack(self, payload: bytes) -> list[np.ndarray]:
        layout = int.from_bytes(payload[2:5], "little")
        width = [(layout >> (3 * i) & 7) + 1 for i in range(IMU_AXES)]
        bits, pos, samples = int.from_bytes(payload[IMU_DELTA_HEADER:], "little"), 0, []
        for _ in range((layout >> 18 & 7) + 1):
            self.last = self.last.copy()        # each sample its own array
            for i, w in enumerate(width):
                v = bits >> pos & ((1 << w) - 1)
                self.last[i] += v - (1 << w) if v >> (w - 1) else v
                pos += w
            samples.append(self.last)
        return samples

    def _deltas(self, data: bytes) -> list[tuple]:
        samples = []
        for k in range(0, len(data), IMU_AXES):
            self.last = self.last + np.frombuffer(data[k:k + IMU_AXES], np.int8)
            samples.append(self.last)
        return self._imu(samples)

    def _imu(self, samples) -> list[tuple]:
        acc, gyro = imu_values(np.array(samples))
        rows = []
        for a, g in zip(acc, gyro):
            rows += [(self.t_step, "accel", 0, 0, a), (self.t_step, "gyro", 0, 0, g)]
        return rows

    def _packed(self, data: bytes) -> list[tuple]:
        rows = []
        for k in range(0, len(data), 5):
            dt, ids, q = struct.unpack_from("<HBh", data, k)
            rows.append((self.t_step + dt, "tdoa", ids >> 4, ids & 0x0F, (np.float32(q) * TDOA_LSB, 0.0, 0.0)))
        return rows


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
    imu_lost: int
    trust: int = TRUST_FULL     # share of the bias correction applied, in 1/TRUST_FULL
    anchor_weighted: int = 0    # TDOA of blocked anchors down-weighted (protocol 5; held at 65535)

    @property
    def correction_trust(self) -> float:
        return self.trust / TRUST_FULL


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


_FLOAT32 = struct.Struct("<4f")


def _quaternion(counts: tuple) -> tuple:
    """int16 counts as the board scales them, in float32: the double product of two
    float32 numbers is exact, so rounding it once to float32 is the float32 product
    (without a numpy scalar per component, a tenth of a native replay's loop)."""
    lsb = float(QUAT_LSB)
    return _FLOAT32.unpack(_FLOAT32.pack(*(q * lsb for q in counts)))


_DECODERS = {kind: (struct.Struct(fmt), build) for kind, (fmt, build) in {
    HELLO_REPLY: ("<BBBBIHB", lambda v: HelloReply(v[0], v[1], UNITS.get(v[2], "?"), v[3], v[4], v[5], v[6])),
    ACK: ("<Bb", lambda v: Ack(*v)),
    ESTIMATE: ("<I3f3f", lambda v: Estimate(v[0], v[1:4], v[4:7])),
    ATTITUDE: ("<4h9e", lambda v: Attitude(_quaternion(v[:4]), v[4:])),
    COUNTERS: ("<IIIIHHHHHH", lambda v: Counters(*v)),
    TIMING: ("<IIIIIB", lambda v: Timing(*v)),
    STATUS: ("<BIII", lambda v: Status(*v)),
}.items()}


def decode(payload: bytes):
    """A board message as its dataclass."""
    if not payload or payload[0] not in _DECODERS:
        raise ProtocolError(f"unknown message type {payload[:1].hex() or '(empty)'}")
    layout, build = _DECODERS[payload[0]]
    if len(payload) - 1 != layout.size:
        raise ProtocolError(f"message 0x{payload[0]:02x} of {len(payload)} bytes")
    return build(layout.unpack_from(payload, 1))
