"""A pyserial port carrying rig.hil.protocol frames: the native program's pty, QEMU's
emulated USART1 over a TCP socket, any pyserial URL (a real tty, ``socket://``,
``rfc2217://``), or a child's standard input and output (QEMU's bulk link)."""

from __future__ import annotations

import fcntl
import os
import select
import socket
import struct
import subprocess
import termios
import time
from collections import deque
from dataclasses import dataclass, field

import serial
from serial.urlhandler import protocol_socket

from rig.hil import protocol
from rig.hil.links.base import BoardLink, LinkError

# would block in the write for ever, deaf even to Ctrl-C when the signal lands on
# another of its threads.
WRITE_TIMEOUT_S = 10.0
READ_CHUNK = 65536


class SocketPort(protocol_socket.Serial):
    """pyserial's socket:// port with a true `in_waiting`: the stock one says at most 1,
    so every read took one byte and a system call (QEMU sends a TCP segment per byte)."""

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise serial.PortNotOpenError()
        return struct.unpack("I", fcntl.ioctl(self._socket, termios.FIONREAD, b"\0\0\0\0"))[0]


def _read_fd(fd: int) -> bytes | None:
    """Everything waiting on a non-blocking descriptor in one system call (pyserial's read
    costs two more and a select); None or b"" when nothing is (a raw tty reads b"")."""
    try:
        return os.read(fd, READ_CHUNK)
    except BlockingIOError:
        return None


def _write_fd(port, data: bytes) -> int:
    """Write what the port's descriptor takes at once, in one system call (pyserial's
    write adds a select and a loop to every window); what is left goes through the
    port's own write, which waits for the board within its write timeout."""
    fd = getattr(port, "write_fd", None)
    if fd is None and type(port) is serial.Serial:     # a POSIX tty or pty, which pyserial opens non-blocking
        fd = port.fileno()
    if fd is None:
        return 0
    try:
        return os.write(fd, data)
    except BlockingIOError:
        return 0


class PipePort:
    """The part of a pyserial port that `Link` uses, on two pipes: what is written goes to
    `write_fd`, what is read comes from `read_fd` (a child's standard input and output)."""

    def __init__(self, write_fd: int, read_fd: int, timeout: float = 0.05,
                 write_timeout: float = WRITE_TIMEOUT_S):
        self.write_fd, self.read_fd = write_fd, read_fd
        self.timeout, self.write_timeout = timeout, write_timeout
        os.set_blocking(write_fd, False)
        os.set_blocking(read_fd, False)
        self.is_open = True

    def fileno(self) -> int:
        return self.read_fd

    @property
    def in_waiting(self) -> int:
        return struct.unpack("I", fcntl.ioctl(self.read_fd, termios.FIONREAD, b"\0\0\0\0"))[0]

    def read(self, size: int = 1) -> bytes:
        data = os.read(self.read_fd, size)
        if not data:
            raise serial.SerialException("the board closed its output")
        return data

    def write(self, data: bytes) -> int:
        view, deadline = memoryview(data), time.monotonic() + self.write_timeout
        while view:
            if not select.select([], [self.write_fd], [], max(0.0, deadline - time.monotonic()))[1]:
                raise serial.SerialTimeoutException("write timeout")
            view = view[os.write(self.write_fd, view):]
        return len(data)

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            os.close(self.write_fd)


def serial_for_url(url: str, write_timeout: float = WRITE_TIMEOUT_S, **kwargs) -> serial.SerialBase:
    """Every link's port (a path, socket:// or another pyserial URL), with a bound on
    how long a write may wait for a board that stops reading."""
    if url.startswith("socket://"):
        return SocketPort(url, write_timeout=write_timeout, **kwargs)
    return serial.serial_for_url(url, write_timeout=write_timeout, **kwargs)


@dataclass
class Link(BoardLink):
    """A serial link (pyserial port) carrying protocol frames."""

    port: serial.SerialBase
    name: str
    process: subprocess.Popen | None = None
    monitor_port: int | None = None          # QEMU's monitor, for a hardware reset
    parser: protocol.Parser = field(default_factory=protocol.Parser)
    bytes_sent: int = 0
    bytes_received: int = 0
    pending: deque = field(default_factory=deque)

    def send(self, payloads: list[bytes], framed: bytes | None = None) -> None:
        data = protocol.frames(payloads) if framed is None else framed
        try:
            written = _write_fd(self.port, data)
            if written < len(data):
                self.port.write(data[written:])
        except serial.SerialTimeoutException as exc:
            raise LinkError(f"{self.name}: the board stopped reading (a write waited "
                            f"{self.port.write_timeout:g} s)") from exc
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"{self.name}: write failed: {exc}") from exc
        self.bytes_sent += len(data)

    def receive_payloads(self, timeout: float) -> list[bytes]:
        deadline = time.monotonic() + timeout
        while True:
            try:
                chunk = self._read(deadline)
            except (serial.SerialException, OSError) as exc:
                self._check_alive()          # a board process that exited says so
                raise LinkError(f"{self.name}: read failed (board gone?): {exc}") from exc
            self.bytes_received += len(chunk)
            payloads = self.parser.feed(chunk) if chunk else []
            if payloads:
                return payloads
            # nothing whole came: has the board's process gone? (asked only now: a
            # waitpid for every answer was a tenth of a native replay's loop)
            self._check_alive()
            if time.monotonic() > deadline:
                return payloads

    def _read(self, deadline: float) -> bytes:
        """What is waiting, else wait until `deadline` at most (real-time pacing needs
        millisecond waits, not the port's read timeout) for the first byte."""
        fd = self.port.fileno() if hasattr(self.port, "fileno") else None
        if fd is None:
            return self.port.read(max(1, self.port.in_waiting))
        data = _read_fd(fd)
        if data:
            return data
        wait = min(self.port.timeout or 0.05, max(0.0, deadline - time.monotonic()))
        if not select.select([fd], [], [], wait)[0]:
            return b""
        data = _read_fd(fd)
        if not data:       # readable with nothing to read: the other end closed
            raise serial.SerialException("the board closed its end of the link")
        return data

    def _close_channel(self) -> None:
        self.port.close()

    def reset_board(self) -> None:
        """Reset the emulated board as its reset pin would (QEMU's `system_reset`)."""
        if self.monitor_port is None:
            raise LinkError(f"{self.name}: no way to reset this board from the rig")
        try:
            with socket.create_connection(("127.0.0.1", self.monitor_port), timeout=5) as monitor:
                monitor.sendall(b"system_reset\n")
                # the monitor prompts once on connection and again once the command has
                # run: closing before that may drop the command
                said = b""
                while said.count(b"(qemu)") < 2:
                    chunk = monitor.recv(4096)
                    if not chunk:
                        raise LinkError(f"{self.name}: the QEMU monitor closed before confirming the reset")
                    said += chunk
        except OSError as exc:
            raise LinkError(f"{self.name}: cannot reset through the QEMU monitor: {exc}") from exc


def open_url(url: str, read_timeout: float = 0.05, baudrate: int = 921_600,
             write_timeout: float = WRITE_TIMEOUT_S) -> Link:
    try:
        port = serial_for_url(url, baudrate=baudrate, timeout=read_timeout, write_timeout=write_timeout)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(f"cannot open {url}: {exc}") from exc
    return Link(port, url)
