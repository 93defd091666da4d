"""Decoder for the Crazyflie uSD-card event log, format version 2.

Layout (all little-endian), as specified in the shared data README:

    uint8  magic = 0xBC
    uint16 version = 2
    uint16 number of event types
    per event type: uint16 id, NUL-terminated name, uint16 number of variables,
                    per variable a NUL-terminated "name(T)" with T a `struct` code
    events until the last 4 bytes: uint16 id, uint64 timestamp [us], packed values
    uint32 CRC-32 of everything before it

The decoder is strict by default: a bad magic, version, CRC, an unknown event id or
an event cut short raises `LogFormatError`. With ``salvage=True`` the valid prefix
of the event stream is kept and `DecodedLog.dropped` says what was lost.
"""

from __future__ import annotations

import logging
import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rig.data.errors import LogFormatError

log = logging.getLogger(__name__)

MAGIC = 0xBC
SUPPORTED_VERSION = 2
CRC_SIZE = 4
EVENT_HEADER = struct.Struct("<HQ")  # event id, timestamp in microseconds
_VARIABLE_RE = re.compile(r"^(?P<name>.+)\((?P<code>[a-zA-Z?])\)$")


@dataclass(frozen=True)
class EventType:
    """One declared event type: its id, name and packed variables."""

    id: int
    name: str
    variables: tuple[str, ...]
    codes: str

    @property
    def payload(self) -> struct.Struct:
        return struct.Struct("<" + self.codes)


@dataclass
class EventSeries:
    """All events of one type: timestamps [us] and one column per variable."""

    type: EventType
    timestamps_us: np.ndarray
    values: np.ndarray  # shape (n, number of variables), float64

    def __len__(self) -> int:
        return len(self.timestamps_us)

    def column(self, variable: str) -> np.ndarray:
        return self.values[:, self.type.variables.index(variable)]


@dataclass
class DecodedLog:
    """A decoded log: the events of every declared type, in recording order."""

    version: int
    types: dict[str, EventType]
    events: dict[str, EventSeries]
    crc_ok: bool
    dropped: list[str] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        return {name: len(series) for name, series in self.events.items()}

    def series(self, name: str) -> EventSeries:
        if name not in self.events:
            raise LogFormatError(f"the log declares no event type {name!r}")
        return self.events[name]


class _Cursor:
    """Reads the header fields, raising LogFormatError when the data runs out."""

    def __init__(self, data: bytes, end: int):
        self.data = data
        self.pos = 0
        self.end = end

    def unpack(self, fmt: struct.Struct, what: str) -> tuple:
        if self.pos + fmt.size > self.end:
            raise LogFormatError(f"header truncated while reading {what} at byte {self.pos}")
        values = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return values

    def cstring(self, what: str) -> str:
        nul = self.data.find(b"\0", self.pos, self.end)
        if nul < 0:
            raise LogFormatError(f"header truncated inside {what} at byte {self.pos}")
        raw = self.data[self.pos : nul]
        self.pos = nul + 1
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError as exc:
            raise LogFormatError(f"non-ASCII {what} at byte {self.pos}") from exc


def _parse_variable(spec: str) -> tuple[str, str]:
    match = _VARIABLE_RE.match(spec)
    if not match:
        raise LogFormatError(f"malformed variable declaration {spec!r}")
    code = match["code"]
    try:
        struct.calcsize("<" + code)
    except struct.error as exc:
        raise LogFormatError(f"unknown type code {code!r} in {spec!r}") from exc
    return match["name"], code


def _parse_header(cur: _Cursor) -> tuple[int, dict[int, EventType]]:
    (magic,) = cur.unpack(struct.Struct("<B"), "magic")
    if magic != MAGIC:
        raise LogFormatError(f"bad magic 0x{magic:02X} (expected 0x{MAGIC:02X}): not a uSD event log")
    version, n_types = cur.unpack(struct.Struct("<HH"), "version")
    if version != SUPPORTED_VERSION:
        raise LogFormatError(f"unsupported log version {version} (this decoder reads version {SUPPORTED_VERSION})")
    types: dict[int, EventType] = {}
    for _ in range(n_types):
        (type_id,) = cur.unpack(struct.Struct("<H"), "event type id")
        name = cur.cstring("event type name")
        (n_vars,) = cur.unpack(struct.Struct("<H"), f"variable count of {name}")
        parsed = [_parse_variable(cur.cstring(f"variable of {name}")) for _ in range(n_vars)]
        if type_id in types:
            raise LogFormatError(f"event type id {type_id} declared twice")
        types[type_id] = EventType(
            id=type_id,
            name=name,
            variables=tuple(v for v, _ in parsed),
            codes="".join(c for _, c in parsed),
        )
    return version, types


def _check_crc(data: bytes) -> bool:
    if len(data) < CRC_SIZE:
        return False
    (stored,) = struct.unpack_from("<I", data, len(data) - CRC_SIZE)
    return zlib.crc32(data[: len(data) - CRC_SIZE]) == stored


def decode(data: bytes, *, salvage: bool = False, source: str = "<bytes>") -> DecodedLog:
    """Decode a whole log held in memory. See the module docstring for the rules."""
    if not data or data[0] != MAGIC:         # before the CRC: a file that is no log at all says so
        found = f"starts with 0x{data[0]:02X}" if data else "is empty"
        raise LogFormatError(f"{source}: not a uSD event log (it {found}; a log starts with the magic 0x{MAGIC:02X})")
    crc_ok = _check_crc(data)
    dropped: list[str] = []
    if not crc_ok:
        message = f"{source}: CRC-32 mismatch or missing (file truncated or corrupted)"
        if not salvage:
            raise LogFormatError(message + "; `rig import --salvage` imports its valid prefix")
        dropped.append(message)
    # Without a valid CRC we cannot know where the events end, so scan to the end of file.
    end = len(data) - CRC_SIZE if crc_ok else len(data)
    cur = _Cursor(data, end)
    version, types = _parse_header(cur)

    rows: dict[int, list[tuple]] = {tid: [] for tid in types}
    stamps: dict[int, list[int]] = {tid: [] for tid in types}
    order: list[tuple[int, int]] = []           # (type id, stamp) in recording order
    payloads = {tid: t.payload for tid, t in types.items()}
    pos = cur.pos
    while pos < end:
        if pos + EVENT_HEADER.size > end:
            problem = f"{end - pos} trailing bytes at offset {pos} do not form an event"
            break
        type_id, stamp = EVENT_HEADER.unpack_from(data, pos)
        payload = payloads.get(type_id)
        if payload is None:
            problem = f"unknown event id {type_id} at offset {pos}"
            break
        if pos + EVENT_HEADER.size + payload.size > end:
            problem = f"event {types[type_id].name} at offset {pos} is cut short"
            break
        rows[type_id].append(payload.unpack_from(data, pos + EVENT_HEADER.size))
        stamps[type_id].append(stamp)
        order.append((type_id, stamp))
        pos += EVENT_HEADER.size + payload.size
    else:
        problem = ""
    if problem:
        message = f"{source}: {problem}; {end - pos} of {len(data)} bytes not decoded"
        if not salvage:
            raise LogFormatError(message)
        dropped.append(message)

    keep = _plausible_stamps(order) if not crc_ok else None
    if keep is not None and not keep.all():
        dropped.append(f"{source}: {int((~keep).sum())} events whose timestamps leave the log's time range or "
                       f"run backwards (damaged stamps) dropped")
    events = {}
    for tid, etype in types.items():
        values = np.array(rows[tid], dtype=np.float64).reshape(len(rows[tid]), len(etype.variables))
        times = np.array(stamps[tid], dtype=np.uint64)
        if keep is not None:
            mine = keep[[k for k, (type_id, _) in enumerate(order) if type_id == tid]]
            values, times = values[mine], times[mine]
        events[etype.name] = EventSeries(etype, times, values)
    return DecodedLog(version=version, types={t.name: t for t in types.values()}, events=events,
                      crc_ok=crc_ok, dropped=dropped)


# A stamp further than this from the median of its neighbours in recording order is
# damaged: a log is recorded in time order but for a few events a few milliseconds apart.
STAMP_SLACK_US = 1_000_000
STAMP_NEIGHBOURS = 25                # on each side


def _plausible_stamps(order: list[tuple[int, int]]) -> np.ndarray:
    """Which events of a salvaged log (no CRC to vouch for them) have a plausible stamp:
    within STAMP_SLACK_US of the median of their neighbours in recording order."""
    stamps = np.array([s for _, s in order], dtype=np.float64)
    if len(stamps) < 3:
        return np.ones(len(stamps), bool)
    half = min(STAMP_NEIGHBOURS, (len(stamps) - 1) // 2)
    padded = np.pad(stamps, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.abs(stamps - np.median(windows, axis=1)) <= STAMP_SLACK_US


def read_log(path: Path, *, salvage: bool = False) -> DecodedLog:
    """Decode the log file at `path` (see `decode`)."""
    path = Path(path)
    if path.is_dir():
        raise LogFormatError(f"{path} is a directory, not a log file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LogFormatError(f"cannot read {path}: {exc.strerror}") from exc
    decoded = decode(data, salvage=salvage, source=str(path))
    for message in decoded.dropped:
        log.warning("salvaged: %s", message)
    return decoded


def encode(types: list[EventType], events: list[tuple[str, int, tuple]]) -> bytes:
    """Build a log from declared types and (type name, timestamp µs, values) events.

    The inverse of `decode`, used to craft logs for tests and tools."""
    out = bytearray(struct.pack("<BHH", MAGIC, SUPPORTED_VERSION, len(types)))
    for etype in types:
        out += struct.pack("<H", etype.id) + etype.name.encode() + b"\0"
        out += struct.pack("<H", len(etype.variables))
        for name, code in zip(etype.variables, etype.codes):
            out += f"{name}({code})".encode() + b"\0"
    by_name = {t.name: t for t in types}
    for name, stamp, values in events:
        etype = by_name[name]
        out += EVENT_HEADER.pack(etype.id, stamp) + etype.payload.pack(*values)
    out += struct.pack("<I", zlib.crc32(bytes(out)))
    return bytes(out)
