"""The rig's one recording format: MCAP with JSON-encoded messages.

Topics, schemas and units are documented in ``recordings/README.md``. In memory a
recording is a `Recording` of column arrays (one row per message), which keeps
1 kHz IMU streams cheap to handle.
"""

from __future__ import annotations

import json
import logging
import os
import struct
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np
from mcap.reader import make_reader
from mcap.exceptions import EndOfFile
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC, CompressionType, IndexType, Writer

from rig.data.errors import RecordingError
from rig.data.survey import Anchor

log = logging.getLogger(__name__)

LIBRARY = "uwb-rig"
METADATA_NAME = "recording"

TOPIC_ACCEL = "/imu/accel"
TOPIC_GYRO = "/imu/gyro"
TOPIC_TDOA = "/uwb/tdoa"
TOPIC_TRUTH = "/truth/pose"
TOPIC_ANCHORS = "/uwb/anchors"


def number_schema(description: str, unit: str | None = None) -> dict:
    schema = {"type": "number", "description": description}
    if unit:
        schema["description"] += f" [{unit}]"
    return schema


def vector_schema(description: str, unit: str) -> dict:
    return {
        "type": "object",
        "description": description,
        "properties": {axis: number_schema(f"{axis} component", unit) for axis in "xyz"},
        "required": list("xyz"),
    }


_QUATERNION = {
    "type": "object",
    "description": "unit quaternion",
    "properties": {c: {"type": "number"} for c in "xyzw"},
    "required": list("xyzw"),
}
_TIME = number_schema("time on the recording's single clock", "s")


def object_schema(title: str, properties: dict) -> dict:
    return {"title": title, "type": "object", "properties": properties, "required": list(properties)}


SCHEMAS: dict[str, dict] = {
    "uwb_rig.SpecificForce": object_schema("uwb_rig.SpecificForce", {
        "t": _TIME, **vector_schema("body-frame specific force, about +9.81 on z at rest", "m/s^2")["properties"]}),
    "uwb_rig.AngularRate": object_schema("uwb_rig.AngularRate", {
        "t": _TIME, **vector_schema("body-frame angular rate", "rad/s")["properties"]}),
    "uwb_rig.Tdoa": object_schema("uwb_rig.Tdoa", {
        "t": _TIME,
        "id_a": {"type": "integer", "description": "anchor A id"},
        "id_b": {"type": "integer", "description": "anchor B id"},
        "distance_diff": number_schema("|p - a_B| - |p - a_A| as measured", "m"),
    }),
    "uwb_rig.Pose": object_schema("uwb_rig.Pose", {
        "t": _TIME,
        "position": vector_schema("position in the world (motion-capture) frame", "m"),
        "orientation": {**_QUATERNION, "description": "unit quaternion body->world"},
    }),
    "uwb_rig.AnchorSet": object_schema("uwb_rig.AnchorSet", {
        "anchors": {"type": "array", "items": object_schema("uwb_rig.Anchor", {
            "id": {"type": "integer"},
            "position": vector_schema("antenna centre in the world frame", "m"),
            "orientation": {**_QUATERNION, "description": "unit quaternion anchor->world"},
        })},
    }),
}


class _Columns:
    """Shared behaviour of the column-array series: length and row selection."""

    t: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    def select(self, mask: np.ndarray):
        return type(self)(*(getattr(self, f.name)[mask] for f in fields(self)))


@dataclass
class Vec3Series(_Columns):
    """Time-stamped 3-vectors (IMU axes)."""

    t: np.ndarray
    xyz: np.ndarray

    @classmethod
    def empty(cls) -> "Vec3Series":
        return cls(np.zeros(0), np.zeros((0, 3)))


@dataclass
class TdoaSeries(_Columns):
    """TDOA measurements: distance_diff = |p - a_B| - |p - a_A| (+ errors)."""

    t: np.ndarray
    id_a: np.ndarray
    id_b: np.ndarray
    distance_diff: np.ndarray

    @classmethod
    def empty(cls) -> "TdoaSeries":
        return cls(np.zeros(0), np.zeros(0, int), np.zeros(0, int), np.zeros(0))


@dataclass
class PoseSeries(_Columns):
    """Ground-truth poses: position (m) and quaternion x,y,z,w body→world."""

    t: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray

    @classmethod
    def empty(cls) -> "PoseSeries":
        return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))



@dataclass
class Recording:
    """One flight: IMU, TDOA, ground truth, the anchor set and free-form metadata."""

    accel: Vec3Series
    gyro: Vec3Series
    tdoa: TdoaSeries
    truth: PoseSeries
    anchors: list[Anchor]
    metadata: dict[str, str] = field(default_factory=dict)

    def anchor_map(self) -> dict[int, Anchor]:
        return {a.id: a for a in self.anchors}

    def time_span(self) -> tuple[float, float]:
        starts = [s.t[0] for s in (self.accel, self.gyro, self.tdoa, self.truth) if len(s)]
        ends = [s.t[-1] for s in (self.accel, self.gyro, self.tdoa, self.truth) if len(s)]
        if not starts:
            raise RecordingError("the recording holds no samples")
        return float(min(starts)), float(max(ends))


# ----------------------------------------------------------------------------- writing

def _r(value: float) -> str:
    """Shortest exact text of a float (JSON has no NaN, so write null for non-finite)."""
    value = float(value)
    return repr(value) if np.isfinite(value) else "null"


def _xyz_json(v: np.ndarray) -> str:
    return f'{{"x":{_r(v[0])},"y":{_r(v[1])},"z":{_r(v[2])}}}'


def _quat_json(q: np.ndarray) -> str:
    return f'{{"x":{_r(q[0])},"y":{_r(q[1])},"z":{_r(q[2])},"w":{_r(q[3])}}}'


def _vec3_messages(series: Vec3Series) -> Iterator[tuple[float, str]]:
    for t, v in zip(series.t.tolist(), series.xyz.tolist()):
        yield t, f'{{"t":{_r(t)},"x":{_r(v[0])},"y":{_r(v[1])},"z":{_r(v[2])}}}'


def _tdoa_messages(series: TdoaSeries) -> Iterator[tuple[float, str]]:
    for t, a, b, d in zip(series.t.tolist(), series.id_a.tolist(), series.id_b.tolist(),
                          series.distance_diff.tolist()):
        yield t, f'{{"t":{_r(t)},"id_a":{int(a)},"id_b":{int(b)},"distance_diff":{_r(d)}}}'


def _pose_messages(series: PoseSeries) -> Iterator[tuple[float, str]]:
    for t, p, q in zip(series.t.tolist(), series.position, series.quaternion):
        yield t, f'{{"t":{_r(t)},"position":{_xyz_json(p)},"orientation":{_quat_json(q)}}}'


def anchors_message(anchors: Iterable[Anchor]) -> str:
    items = [
        f'{{"id":{a.id},"position":{_xyz_json(np.array(a.position))},'
        f'"orientation":{_quat_json(np.array(a.quaternion))}}}'
        for a in anchors
    ]
    return '{"anchors":[' + ",".join(items) + "]}"


def _nanoseconds(t: float) -> int:
    return max(0, int(round(t * 1e9)))


class McapJsonWriter:
    """A small wrapper over `mcap.writer.Writer` for JSON topics with JSON schemas.

    Use as a context manager: the file is always finished (its summary written),
    even when the body raises, so whatever was recorded stays readable.
    """

    def __init__(self, path: Path, *, compression: CompressionType = CompressionType.ZSTD,
                 chunk_size: int = 4 * 1024 * 1024):
        self.path = Path(path)
        self._stream = open(self.path, "wb")
        # Per-message indexes would cost 16 uncompressed bytes a message (more than the
        # compressed message itself at 1 kHz); chunk indexes keep seeking by time cheap.
        self._writer = Writer(self._stream, compression=compression,
                              index_types=IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA,
                              chunk_size=chunk_size)
        self._writer.start(profile="", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._closed = False

    def channel(self, topic: str, schema_name: str, schema: dict | None = None) -> int:
        if topic in self._channels:
            return self._channels[topic]
        if schema_name not in self._schemas:
            body = schema if schema is not None else SCHEMAS[schema_name]
            self._schemas[schema_name] = self._writer.register_schema(
                name=schema_name, encoding="jsonschema", data=json.dumps(body, sort_keys=True).encode())
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=self._schemas[schema_name])
        self._channels[topic] = channel_id
        self._sequence[channel_id] = 0
        return channel_id

    def write(self, channel_id: int, t: float, text: str | bytes) -> None:
        """One message: its JSON text, or those bytes already encoded."""
        stamp = _nanoseconds(t)
        data = text if isinstance(text, bytes) else text.encode()
        self._writer.add_message(channel_id, log_time=stamp, data=data, publish_time=stamp,
                                 sequence=self._sequence[channel_id])
        self._sequence[channel_id] += 1

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, {k: str(v) for k, v in data.items()})

    def close(self) -> None:
        """Finish the file. If that fails (a full disk), the file is still finished:
        cut back to its last whole record and closed with a footer that fits in the room
        the cut freed (`seal_unfinished`), then the error is raised on."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self._stream.close()
        except OSError:
            self._close_stream_quietly()
            seal_unfinished(self.path)
            raise
        except BaseException:             # an interruption: the descriptor is closed all the same
            self._close_stream_quietly()
            raise

    def _close_stream_quietly(self) -> None:
        try:
            self._stream.close()          # flushes again, which may fail again: the descriptor closes
        except OSError:
            pass

    def __enter__(self) -> "McapJsonWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# An MCAP file's end without a summary (the specification's DataEnd and Footer records):
# a reader then reads the data section from the start, as the stock readers do.
_OP_FOOTER, _OP_DATA_END = 0x02, 0x0F
_RECORD_HEAD = struct.Struct("<BQ")
_END_WITHOUT_SUMMARY = (_RECORD_HEAD.pack(_OP_DATA_END, 4) + struct.pack("<I", 0)
                        + _RECORD_HEAD.pack(_OP_FOOTER, 20) + struct.pack("<QQI", 0, 0, 0) + MCAP0_MAGIC)


def _whole_record_ends(stream, size: int) -> list[int]:
    """Where each whole record of an MCAP file's data section ends, from the first; the
    scan stops at a record cut short or at the data section's end."""
    ends, at = [], len(MCAP0_MAGIC)
    stream.seek(0)
    if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
        return ends
    while at + _RECORD_HEAD.size <= size:
        stream.seek(at)
        opcode, length = _RECORD_HEAD.unpack(stream.read(_RECORD_HEAD.size))
        if opcode in (_OP_DATA_END, _OP_FOOTER) or at + _RECORD_HEAD.size + length > size:
            break
        at += _RECORD_HEAD.size + length
        ends.append(at)
    return ends


def is_finished(path: Path) -> bool:
    """Whether an MCAP file ends as a finished one does (its footer's magic bytes)."""
    path = Path(path)
    size = path.stat().st_size
    if size < 2 * len(MCAP0_MAGIC):
        return False
    with open(path, "rb") as stream:
        stream.seek(size - len(MCAP0_MAGIC))
        return stream.read() == MCAP0_MAGIC


def seal_unfinished(path: Path) -> int | None:
    """Finish an MCAP file whose writing stopped (a full disk, a write error): cut it at
    the end of its last whole record and append the end of a file without a summary, so
    that any MCAP reader reads every whole record. Where even that does not fit, the
    last records are given up one at a time to make room (a chunk frees disk blocks).
    Returns how many bytes of whole records it kept; a file that is not a regular one, or
    whose header is cut, is left as it is (None)."""
    path = Path(path)
    if not path.is_file():
        return None
    with open(path, "r+b", buffering=0) as stream:       # unbuffered: a failed write leaves nothing held
        ends = _whole_record_ends(stream, path.stat().st_size)
        while ends:                    # ends[0] is the header's: without it nothing is a file
            try:
                os.ftruncate(stream.fileno(), ends[-1])
                if os.pwrite(stream.fileno(), _END_WITHOUT_SUMMARY, ends[-1]) == len(_END_WITHOUT_SUMMARY):
                    os.fsync(stream.fileno())
                    log.warning("%s: finished after a write error, %d bytes of whole records kept",
                                path, ends[-1])
                    return ends[-1]
            except OSError:
                pass
            ends.pop()
    return None


def _merged(*streams: tuple[int, Iterator[tuple[float, str]]]) -> list[tuple[float, int, str]]:
    """All messages of all streams in time order (stable, so ties keep stream order)."""
    rows = [(t, order, cid, text) for order, (cid, it) in enumerate(streams) for t, text in it]
    rows.sort(key=lambda r: (r[0], r[1]))
    return [(t, cid, text) for t, _, cid, text in rows]


def write_recording(rec: Recording, path: Path, progress: Callable[[Iterable], Iterable] | None = None) -> None:
    """Write `rec` to `path` atomically: a partial file never replaces a good one."""
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    try:
        _write_messages(rec, tmp, progress)
    except BaseException:            # a failed or interrupted write leaves nothing behind
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def _write_messages(rec: Recording, tmp: Path, progress) -> None:
    with McapJsonWriter(tmp) as out:
        out.metadata(METADATA_NAME, rec.metadata)
        anchors_cid = out.channel(TOPIC_ANCHORS, "uwb_rig.AnchorSet")
        streams = (
            (out.channel(TOPIC_TRUTH, "uwb_rig.Pose"), _pose_messages(rec.truth)),
            (out.channel(TOPIC_ACCEL, "uwb_rig.SpecificForce"), _vec3_messages(rec.accel)),
            (out.channel(TOPIC_GYRO, "uwb_rig.AngularRate"), _vec3_messages(rec.gyro)),
            (out.channel(TOPIC_TDOA, "uwb_rig.Tdoa"), _tdoa_messages(rec.tdoa)),
        )
        start, _ = rec.time_span()
        out.write(anchors_cid, start, anchors_message(rec.anchors))
        rows = _merged(*streams)
        for t, cid, text in (progress(rows) if progress else rows):
            out.write(cid, t, text)


# ----------------------------------------------------------------------------- reading

def _vec3(msgs: list[dict]) -> Vec3Series:
    if not msgs:
        return Vec3Series.empty()
    return Vec3Series(np.array([m["t"] for m in msgs], float),
                      np.array([[m["x"], m["y"], m["z"]] for m in msgs], float))


def _xyz_of(d: dict) -> list[float]:
    return [d["x"], d["y"], d["z"]]


def _tdoa(msgs: list[dict]) -> TdoaSeries:
    if not msgs:
        return TdoaSeries.empty()
    return TdoaSeries(np.array([m["t"] for m in msgs], float),
                      np.array([m["id_a"] for m in msgs], int),
                      np.array([m["id_b"] for m in msgs], int),
                      np.array([m["distance_diff"] for m in msgs], float))


def _poses(msgs: list[dict]) -> PoseSeries:
    if not msgs:
        return PoseSeries.empty()
    return PoseSeries(np.array([m["t"] for m in msgs], float),
                      np.array([_xyz_of(m["position"]) for m in msgs], float),
                      np.array([[m["orientation"][c] for c in "xyzw"] for m in msgs], float))


def _anchors(msgs: list[dict]) -> list[Anchor]:
    if not msgs:
        return []
    return [Anchor(int(a["id"]), tuple(_xyz_of(a["position"])),
                   tuple(a["orientation"][c] for c in "xyzw")) for a in msgs[-1]["anchors"]]


def read_topics(path: Path, topics: Iterable[str] | None = None) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]]]:
    """Decode every JSON message of `topics` (all when None), plus all metadata records.
    An unfinished or damaged file (a writer killed before it closed it, a copy cut
    short) yields the records before its first damaged one, with a warning; one with
    none is an error."""
    return _read_topics_checked(path, topics)[:2]


def _read_topics_checked(path: Path, topics: Iterable[str] | None
                         ) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]], bool]:
    """read_topics, and whether the file was read whole (not salvaged)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"recording {path} does not exist")
    if path.stat().st_size == 0:
        raise RecordingError(f"recording {path} is empty (0 bytes)")
    with open(path, "rb") as stream:
        if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
            raise RecordingError(f"{path} is not an MCAP file: it does not begin with MCAP's magic bytes "
                                 f"({path.stat().st_size} bytes)")
    wanted = set(topics) if topics is not None else None
    try:
        return (*_read_whole(path, wanted), True)
    except Exception as exc:  # the mcap reader raises many types for damaged files
        messages, metadata, stop = _read_prefix(path, wanted)
        count = sum(map(len, messages.values()))
        if not count:
            raise RecordingError(f"cannot read {path} as MCAP: {stop or exc or type(exc).__name__} "
                                 "(and no message before the damage)") from exc
        log.warning("%s is unfinished or damaged: read the %d messages before its first damaged record (%s)",
                    path, count, stop or exc)
        return messages, metadata, False


def _read_whole(path: Path, wanted: set[str] | None) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]]]:
    messages: dict[str, list[dict]] = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        for _, channel, message in reader.iter_messages(topics=wanted, log_time_order=False):
            messages.setdefault(channel.topic, []).append(json.loads(message.data))
        metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
    return messages, metadata


def _read_prefix(path: Path, wanted: set[str] | None
                 ) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]], str]:
    """The records of `path` in file order up to the first one that is cut short or
    fails its CRC (chunks are checked, so nothing damaged is decoded), and what stopped
    the read there ("" if nothing did)."""
    messages: dict[str, list[dict]] = {}
    metadata: dict[str, dict[str, str]] = {}
    topic_of: dict[int, str] = {}
    stop = ""
    with open(path, "rb") as stream:
        try:
            for record in StreamReader(stream, validate_crcs=True).records:
                if isinstance(record, Channel):
                    topic_of[record.id] = record.topic
                elif isinstance(record, Message) and (wanted is None or topic_of.get(record.channel_id) in wanted):
                    messages.setdefault(topic_of[record.channel_id], []).append(json.loads(record.data))
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
        except EndOfFile:
            stop = f"it ends inside a record, at byte {stream.tell()}: cut short?"
        except Exception as exc:  # the damaged record: what came before it stands
            stop = f"{exc or type(exc).__name__}"
        log.debug("%s: stopped: %s", path, stop)
    return messages, metadata, stop


def read_recording(path: Path) -> Recording:
    """Read a recording written by `write_recording` (or a run record holding its topics)."""
    return read_recording_checked(path)[0]


def read_recording_checked(path: Path) -> tuple[Recording, bool]:
    """read_recording, and whether the file was read whole (not salvaged)."""
    topics = (TOPIC_ACCEL, TOPIC_GYRO, TOPIC_TDOA, TOPIC_TRUTH, TOPIC_ANCHORS)
    messages, metadata, whole = _read_topics_checked(path, topics)
    rec = Recording(
        accel=_vec3(messages.get(TOPIC_ACCEL, [])),
        gyro=_vec3(messages.get(TOPIC_GYRO, [])),
        tdoa=_tdoa(messages.get(TOPIC_TDOA, [])),
        truth=_poses(messages.get(TOPIC_TRUTH, [])),
        anchors=_anchors(messages.get(TOPIC_ANCHORS, [])),
        metadata=metadata.get(METADATA_NAME, {}),
    )
    if not rec.anchors:
        raise RecordingError(f"{path} has no anchor set on {TOPIC_ANCHORS}")
    check_anchor_set(path, rec.anchors)
    return rec, whole


def check_anchor_set(path: Path, anchors: list[Anchor]) -> None:
    """An anchor set the estimator can use: each id once, every coordinate finite (a
    survey is checked the same way when it is parsed)."""
    ids = [a.id for a in anchors]
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise RecordingError(f"{path}: anchor id(s) {twice} appear more than once in the anchor set on "
                             f"{TOPIC_ANCHORS}: which position is right cannot be told")
    bad = [a.id for a in anchors if not np.isfinite(np.array([*a.position, *a.quaternion], dtype=float)).all()]
    if bad:
        raise RecordingError(f"{path}: anchor(s) {bad} on {TOPIC_ANCHORS} have a non-finite position or orientation")
