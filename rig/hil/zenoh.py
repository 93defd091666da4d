"""Boards on eclipse-zenoh: the bridge (board side) and the link the rig uses (rig side).

Key expressions, for a board named NAME (docs/guide/service.md):

    rig/board/NAME/alive        liveliness token, held while the bridge owns the board
    rig/board/NAME/rx           the payloads the board sent, raw: a batch per sample as
                                on tx (application/octet-stream)
    rig/board/NAME/estimate     decoded messages (application/json): estimate, attitude, counters,
    rig/board/NAME/timing       timing, status, hello, ack (the last key segment is the
    rig/board/NAME/...          message kind)
    rig/board/NAME/tx           payloads for the board: a batch per sample, each payload
                                preceded by its length byte (application/octet-stream)

Sessions are configured with explicit endpoints and no multicast scouting, and stamp
every sample; each kind's latest message is answered to a query on its key (a late
joiner's `get`); publishers of board data use CongestionControl.BLOCK (the default drops under load, even on
loopback); every session is closed on every exit path (an open session with a
callback subscriber hangs the interpreter at exit).
"""

from __future__ import annotations

import json
import logging
import queue
import re
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import zenoh

from rig.data.errors import InputError
from rig.data.files import finite_json
from rig.hil import protocol
from rig.hil.links import BoardLink, LinkError

log = logging.getLogger(__name__)

PREFIX = "rig/board"
# Each board message's key leaf, by its type byte on the wire.
KINDS = {protocol.HELLO_REPLY: "hello", protocol.ACK: "ack", protocol.ESTIMATE: "estimate",
         protocol.ATTITUDE: "attitude", protocol.COUNTERS: "counters", protocol.TIMING: "timing",
         protocol.STATUS: "status"}


def key(board: str, leaf: str) -> str:
    return f"{PREFIX}/{board}/{leaf}"


def config(mode: str = "peer", listen: list[str] = (), connect: list[str] = ()) -> zenoh.Config:
    """A session configuration with explicit endpoints only (no multicast scouting), which
    stamps every sample it publishes (the hybrid logical clock of zenoh's timestamps)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("timestamping/enabled", "true")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


ENDPOINT = re.compile(r"[a-z][a-z0-9-]*/\S+")       # zenoh's PROTOCOL/ADDRESS[?metadata][#config]


class EndpointError(InputError):
    """A zenoh endpoint that is not PROTOCOL/ADDRESS."""


def check_endpoints(endpoints: list[str]) -> None:
    """EndpointError naming the first endpoint that is not PROTOCOL/ADDRESS (zenoh's own
    error for it is a JSON5 parse message)."""
    for endpoint in endpoints:
        if not ENDPOINT.fullmatch(endpoint):
            raise EndpointError(f"zenoh endpoint {endpoint!r} is not PROTOCOL/ADDRESS (e.g. tcp/127.0.0.1:7447)")


def open_session(mode: str | None = None, listen: list[str] = (), connect: list[str] = ()) -> zenoh.Session:
    """A session; by default a client when it only connects (to a router: two peers that
    reach each other only through a router do not exchange data), else a peer. A
    malformed endpoint is bad input (EndpointError), one that cannot be reached a LinkError."""
    check_endpoints([*listen, *connect])
    mode = mode or ("client" if connect and not listen else "peer")
    try:
        return zenoh.open(config(mode, listen, connect))
    except zenoh.ZError as exc:
        raise LinkError(f"zenoh: cannot open a {mode} session (listen {list(listen)}, connect "
                        f"{list(connect)}): {exc}") from exc


def pack_batch(payloads: list[bytes]) -> bytes:
    return b"".join(bytes([len(p)]) + p for p in payloads)


def unpack_batch(data: bytes) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = data[i]
        if n == 0 or i + 1 + n > len(data):
            raise protocol.ProtocolError("malformed payload batch")
        out.append(data[i + 1:i + 1 + n])
        i += 1 + n
    return out


def message_json(msg) -> bytes:
    """A decoded message as strict JSON (its fields are numbers and tuples of numbers; a
    diverged board's NaN is null, as application/json readers expect)."""
    return json.dumps(finite_json(vars(msg)), allow_nan=False).encode()


RAW_ENCODING = zenoh.Encoding.APPLICATION_OCTET_STREAM
JSON_ENCODING = zenoh.Encoding.APPLICATION_JSON


class BoardPublishers:
    """What a board says on zenoh: its payloads raw (a batch per read) and each decoded
    under its kind, with declared encodings, BLOCK congestion control (never dropped)
    and the session's timestamps. A key nobody subscribes to costs nothing: each
    publisher's matching listener says whether anyone listens, and only then is a
    message turned into JSON and put. The latest message of each kind is kept and
    answered to a query on its key, so a late joiner gets every board's state
    (`session.get("rig/board/*/estimate")`)."""

    def __init__(self, session: zenoh.Session, board: str) -> None:
        self.board, self.latest, self._lock = board, {}, threading.Lock()
        block = zenoh.CongestionControl.BLOCK
        self._publishers = {leaf: session.declare_publisher(key(board, leaf), congestion_control=block,
                                                            encoding=RAW_ENCODING if leaf == "rx" else JSON_ENCODING)
                            for leaf in ["rx", *KINDS.values()]}
        self.listened = {leaf: publisher.matching_status.matching for leaf, publisher in self._publishers.items()}
        self._listeners = [publisher.declare_matching_listener(self._on_matching(leaf))
                           for leaf, publisher in self._publishers.items()]
        self._queryables = [session.declare_queryable(key(board, leaf), self._answer) for leaf in KINDS.values()]

    def _on_matching(self, leaf: str):
        def on_matching(status: zenoh.MatchingStatus) -> None:
            self.listened[leaf] = status.matching
        return on_matching

    def publish(self, payloads: list[bytes]) -> None:
        """The payloads raw (one batch), and each decoded under its kind."""
        if not payloads:
            return
        if self.listened["rx"]:
            self._publishers["rx"].put(pack_batch(payloads))
        for payload in payloads:
            kind = KINDS.get(payload[0])
            if kind is None:
                log.warning("bridge %s: unknown message type 0x%02x", self.board, payload[0])
                continue
            with self._lock:
                self.latest[kind] = (payload, None)   # decoded only when asked for
            if self.listened[kind]:
                self._put_decoded(kind, payload)

    def put_json(self, kind: str, data: bytes) -> None:
        """A message the bridge itself says, as JSON."""
        with self._lock:
            self.latest[kind] = (None, data)
        self._publishers[kind].put(data)

    def _put_decoded(self, kind: str, payload: bytes) -> None:
        try:
            self._publishers[kind].put(message_json(protocol.decode(payload)))
        except protocol.ProtocolError as exc:
            log.warning("bridge %s: %s", self.board, exc)

    def _answer(self, query: zenoh.Query) -> None:
        kind = str(query.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            latest = self.latest.get(kind)
        if latest is None:
            return
        payload, data = latest
        try:
            data = data if payload is None else message_json(protocol.decode(payload))
        except protocol.ProtocolError:
            return
        query.reply(key(self.board, kind), data, encoding=JSON_ENCODING)

    def undeclare(self) -> None:
        for entity in [*self._listeners, *self._publishers.values(), *self._queryables]:
            entity.undeclare()
        self._listeners, self._publishers, self._queryables = [], {}, []


def wait_interruptibly(stop: threading.Event, timeout: float | None = None) -> None:
    """Wait for `stop` (or `timeout`) in short slices, so Ctrl-C is honoured."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while not stop.wait(0.2):
        if deadline is not None and time.monotonic() > deadline:
            return


@dataclass
class Bridge:
    """Owns one board link and serves it on a zenoh session until stopped."""

    session: zenoh.Session
    name: str
    link: BoardLink
    error: str | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _entities: list = field(default_factory=list)
    _publishers: BoardPublishers | None = None

    def start(self) -> "Bridge":
        self._publishers = BoardPublishers(self.session, self.name)
        self._entities = [self.session.declare_subscriber(key(self.name, "tx"), self._on_tx),
                          self.session.liveliness().declare_token(key(self.name, "alive"))]
        self._thread = threading.Thread(target=self._pump, name=f"bridge {self.name}", daemon=True)
        self._thread.start()
        return self

    def _on_tx(self, sample: zenoh.Sample) -> None:
        try:
            self.link.send(unpack_batch(sample.payload.to_bytes()))
        except (LinkError, protocol.ProtocolError) as exc:
            self._fail(str(exc))

    def _pump(self) -> None:
        """Board -> zenoh."""
        while not self._stop.is_set():
            try:
                payloads = self.link.receive_payloads(0.05)
            except LinkError as exc:
                self._fail(str(exc))
                return
            self._publishers.publish(payloads)

    def _fail(self, reason: str) -> None:
        """The board is gone: say so, and drop the liveliness token so rigs notice."""
        if self.error is None:
            self.error = reason
            log.error("bridge %s: %s", self.name, reason)
            status = protocol.Status(code=-1, frames_ok=0, frames_bad=0, bytes_dropped=0)
            self._publishers.put_json("status", json.dumps({**vars(status), "error": reason}).encode())
            self._stop.set()

    def wait(self) -> None:
        """Block (Ctrl-C-friendly) until stopped."""
        wait_interruptibly(self._stop)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for entity in self._entities:
            entity.undeclare()
        if self._publishers is not None:
            self._publishers.undeclare()
        self._entities, self._publishers = [], None
        self.link.close()


@dataclass
class TapLink(BoardLink):
    """The in-process bridge for a local board: the rig drives the board's link directly
    (no extra round trip) while everything the board says is published on zenoh as the
    served bridge would, under the same keys and liveliness token."""

    link: BoardLink
    session: zenoh.Session
    board: str
    name: str = ""
    process: object | None = None
    bytes_sent: int = 0
    bytes_received: int = 0
    pending: deque = field(default_factory=deque)
    _publishers: BoardPublishers | None = None
    _token: object | None = None

    def __post_init__(self) -> None:
        self.name = self.name or f"{self.link.name} (zenoh {self.board})"
        self._publishers = BoardPublishers(self.session, self.board)
        self._token = self.session.liveliness().declare_token(key(self.board, "alive"))

    def send(self, payloads: list[bytes], framed: bytes | None = None) -> None:
        self.link.send(payloads, framed)
        self.bytes_sent = self.link.bytes_sent

    def receive_payloads(self, timeout: float) -> list[bytes]:
        payloads = self.link.receive_payloads(timeout)
        self.bytes_received = self.link.bytes_received
        self._publishers.publish(payloads)
        return payloads

    def _close_channel(self) -> None:
        try:
            self.link.close()
        finally:
            if self._publishers is not None:
                self._publishers.undeclare()
            if self._token is not None:
                self._token.undeclare()
            self._publishers, self._token = None, None


@dataclass
class ZenohLink(BoardLink):
    """The rig's side: a board reached through its bridge, over a zenoh session."""

    session: zenoh.Session
    name: str
    process: object | None = None
    bytes_sent: int = 0
    bytes_received: int = 0
    pending: deque = field(default_factory=deque)
    _inbox: queue.Queue = field(default_factory=queue.Queue)
    _gone: threading.Event = field(default_factory=threading.Event)
    _entities: list = field(default_factory=list)
    _tx: object | None = None

    def open(self, timeout: float = 30.0) -> "ZenohLink":
        alive = key(self.name, "alive")
        self._entities = [
            self.session.declare_subscriber(key(self.name, "rx"), self._on_rx),
            self.session.liveliness().declare_subscriber(alive, self._on_liveliness),
        ]
        self._tx = self.session.declare_publisher(key(self.name, "tx"), encoding=RAW_ENCODING,
                                                  congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + timeout
        while not list(self.session.liveliness().get(alive, timeout=1.0)):
            if time.monotonic() > deadline:
                self.close()
                raise LinkError(f"zenoh board {self.name!r}: no bridge announced {alive} within {timeout:.0f} s")
        return self

    def _on_rx(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        self.bytes_received += len(data)          # only this callback's thread adds to it
        try:
            payloads = unpack_batch(data)
        except protocol.ProtocolError as exc:
            log.warning("zenoh board %s: %s", self.name, exc)
            return
        for payload in payloads:
            self._inbox.put(payload)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            self._gone.set()

    def send(self, payloads: list[bytes], framed: bytes | None = None) -> None:
        self._check_alive()
        data = pack_batch(payloads)
        self._tx.put(data)
        self.bytes_sent += len(data)

    def receive_payloads(self, timeout: float) -> list[bytes]:
        self._check_alive()
        try:
            first = self._inbox.get(timeout=max(0.001, timeout))
        except queue.Empty:
            return []
        out = [first]
        while not self._inbox.empty():
            out.append(self._inbox.get_nowait())
        return out

    def _check_alive(self) -> None:
        if self._gone.is_set() and self._inbox.empty():
            raise LinkError(f"zenoh board {self.name!r}: its bridge went away (liveliness token dropped)")

    def _close_channel(self) -> None:
        for entity in self._entities + ([self._tx] if self._tx is not None else []):
            entity.undeclare()
        self._entities, self._tx = [], None


@dataclass
class EstimateCounter:
    """Counts the estimates each board publishes (a subscriber, for `rig watch`)."""

    session: zenoh.Session
    boards: str = "*"
    target: int | None = None
    counts: dict = field(default_factory=dict)
    last: dict = field(default_factory=dict)
    done: threading.Event = field(default_factory=threading.Event)
    _subscriber: object | None = None

    def start(self) -> "EstimateCounter":
        self._subscriber = self.session.declare_subscriber(key(self.boards, "estimate"), self._on_estimate)
        return self

    def _on_estimate(self, sample: zenoh.Sample) -> None:
        board = str(sample.key_expr).split("/")[2]
        self.counts[board] = self.counts.get(board, 0) + 1
        self.last[board] = json.loads(sample.payload.to_bytes())
        if self.target is not None and sum(self.counts.values()) >= self.target:
            self.done.set()

    def stop(self) -> None:
        if self._subscriber is not None:
            self._subscriber.undeclare()
            self._subscriber = None
