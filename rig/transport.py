"""Links to boards: a pyserial port to the native program (over a pty), to QEMU's
emulated USART1 (over a TCP socket), or to any pyserial URL (a real tty,
``socket://``, ``rfc2217://``), all carrying rig.protocol frames; or a Crazyflie
link through cflib's link drivers, carrying the same messages unframed in CRTP
app-channel packets (port 13, channel 2), one message per packet.

Targets:
    native          build estimator_c/build/estimator_native and run it on a pty
    native-udp      the same program on its UDP endpoint, reached through cflib's udp:// driver
    qemu            build the STM32F405 firmware and run it in qemu-system-arm -M netduinoplus2
    serial:URL      open URL with pyserial (a board that is already running)
    crazyflie:URI   a cflib link (radio://, usb:// or udp://) to a board running the estimator app
"""

from __future__ import annotations

import fcntl
import select
import logging
import shutil
import socket
import struct
import subprocess
import termios
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import serial
from serial.urlhandler import protocol_socket

from rig import native, protocol

log = logging.getLogger(__name__)

QEMU = "qemu-system-arm"
# -icount shift=0: one instruction per virtual nanosecond, so TIM2 counts instructions
# deterministically; sleep=off: never wait for the host clock.
QEMU_ARGS = ["-M", "netduinoplus2", "-nographic", "-icount", "shift=0,sleep=off"]
# A board that stops reading fails the write after this long: without it the rig
# would block in the write for ever, deaf even to Ctrl-C when the signal lands on
# another of its threads.
WRITE_TIMEOUT_S = 10.0


class SocketPort(protocol_socket.Serial):
    """pyserial's socket:// port with a true `in_waiting`: the stock one says at most 1,
    so every read took one byte and a system call (QEMU sends a TCP segment per byte)."""

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise serial.PortNotOpenError()
        return struct.unpack("I", fcntl.ioctl(self._socket, termios.FIONREAD, b"\0\0\0\0"))[0]


def _serial_for_url(url: str, write_timeout: float = WRITE_TIMEOUT_S, **kwargs) -> serial.SerialBase:
    """Every link's port (a path, socket:// or another pyserial URL), with a bound on
    how long a write may wait for a board that stops reading."""
    if url.startswith("socket://"):
        return SocketPort(url, write_timeout=write_timeout, **kwargs)
    return serial.serial_for_url(url, write_timeout=write_timeout, **kwargs)


class LinkError(Exception):
    """The board could not be reached, stopped answering or reset."""


class BoardLink:
    """What replay needs from a link: send payloads, take decoded messages, close. Owns
    the target process if it started one."""

    name: str
    process: subprocess.Popen | None
    bytes_sent: int
    pending: deque

    def send(self, payloads: list[bytes]) -> None:
        raise NotImplementedError

    def receive_payloads(self, timeout: float) -> list[bytes]:
        """Verified payloads that arrive within `timeout` (at least one, or an empty list)."""
        raise NotImplementedError

    def receive(self, timeout: float) -> list:
        """Decoded messages that arrive within `timeout` (at least one, or an empty list)."""
        deadline = time.monotonic() + timeout
        while True:
            messages = self._decode(self.receive_payloads(max(0.0, deadline - time.monotonic())))
            if messages or time.monotonic() >= deadline:
                return messages

    def _close_channel(self) -> None:
        raise NotImplementedError

    def next_message(self, timeout: float):
        """The next decoded message, or None when none arrives within `timeout`."""
        if not self.pending:
            self.pending.extend(self.receive(timeout))
        return self.pending.popleft() if self.pending else None

    def _decode(self, payloads: list[bytes]) -> list:
        messages = []
        for payload in payloads:
            try:
                messages.append(protocol.decode(payload))
            except protocol.ProtocolError as exc:
                log.warning("%s: %s", self.name, exc)
        return messages

    def _check_alive(self) -> None:
        if self.process is not None and self.process.poll() is not None:
            err = self.process.stderr.read().decode(errors="replace")[-500:] if self.process.stderr else ""
            raise LinkError(f"{self.name}: target process exited with status {self.process.returncode}"
                            + (f": {err.strip()}" if err.strip() else ""))

    def close(self) -> None:
        try:
            self._close_channel()
        finally:
            if self.process is not None and self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()


@dataclass
class Link(BoardLink):
    """A serial link (pyserial port) carrying protocol frames."""

    port: serial.SerialBase
    name: str
    process: subprocess.Popen | None = None
    monitor_port: int | None = None          # QEMU's monitor, for a hardware reset
    parser: protocol.Parser = field(default_factory=protocol.Parser)
    bytes_sent: int = 0
    pending: deque = field(default_factory=deque)

    def send(self, payloads: list[bytes]) -> None:
        data = b"".join(protocol.frame(p) for p in payloads)
        try:
            self.port.write(data)
        except serial.SerialTimeoutException as exc:
            raise LinkError(f"{self.name}: the board stopped reading (a write waited "
                            f"{self.port.write_timeout:g} s)") from exc
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"{self.name}: write failed: {exc}") from exc
        self.bytes_sent += len(data)

    def receive_payloads(self, timeout: float) -> list[bytes]:
        deadline = time.monotonic() + timeout
        while True:
            self._check_alive()
            try:
                chunk = self._read(deadline)
            except (serial.SerialException, OSError) as exc:
                raise LinkError(f"{self.name}: read failed (board gone?): {exc}") from exc
            payloads = self.parser.feed(chunk) if chunk else []
            if payloads or time.monotonic() > deadline:
                return payloads

    def _read(self, deadline: float) -> bytes:
        """What is waiting, else wait until `deadline` at most (real-time pacing needs
        millisecond waits, not the port's read timeout) for the first byte."""
        waiting = self.port.in_waiting
        if not waiting and hasattr(self.port, "fileno"):
            wait = min(self.port.timeout or 0.05, max(0.0, deadline - time.monotonic()))
            if not select.select([self.port.fileno()], [], [], wait)[0]:
                return b""
        # readable with nothing waiting means the other end closed: read() raises then
        return self.port.read(max(1, self.port.in_waiting))

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


CRTP_APP_PORT, CRTP_APP_CHANNEL = 13, 2


@dataclass
class CrtpLink(BoardLink):
    """Protocol messages in CRTP app-channel packets through a cflib link driver (the
    link frames and checks packets, so messages travel bare: one per packet)."""

    driver: object
    name: str
    process: subprocess.Popen | None = None
    bytes_sent: int = 0
    pending: deque = field(default_factory=deque)
    errors: list = field(default_factory=list)

    def send(self, payloads: list[bytes]) -> None:
        from cflib.crtp.crtpstack import CRTPPacket

        self._raise_link_error()
        for payload in payloads:
            packet = CRTPPacket()
            packet.set_header(CRTP_APP_PORT, CRTP_APP_CHANNEL)
            packet.data = bytearray(payload)
            self.driver.send_packet(packet)
            self.bytes_sent += len(payload) + 1

    def receive_payloads(self, timeout: float) -> list[bytes]:
        deadline = time.monotonic() + timeout
        while True:
            self._check_alive()
            self._raise_link_error()
            packet = self.driver.receive_packet(max(0.001, min(0.05, deadline - time.monotonic())))
            if packet is not None and packet.port == CRTP_APP_PORT and packet.channel == CRTP_APP_CHANNEL:
                return [bytes(packet.data)]
            if time.monotonic() > deadline:
                return []

    def _raise_link_error(self) -> None:
        if self.errors:
            raise LinkError(f"{self.name}: {self.errors[0]}")

    def _close_channel(self) -> None:
        self.driver.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def open_native(program: Path | None = None, read_timeout: float = 0.05) -> Link:
    program = program or _build_for_target(native.NATIVE_PROGRAM, "program")
    proc = subprocess.Popen([str(program), "--pty"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = proc.stdout.readline().decode().strip()
    if not line.startswith("PTY "):
        proc.kill()
        raise LinkError(f"native target did not open a pty (said {line!r})")
    port = _serial_for_url(line[4:], baudrate=1_000_000, timeout=read_timeout)
    return Link(port, f"native {line[4:]}", proc)


def open_qemu(firmware: Path | None = None, read_timeout: float = 0.05, connect_timeout: float = 10.0) -> Link:
    if shutil.which(QEMU) is None:
        raise LinkError(f"{QEMU} is not installed (run scripts/setup.sh)")
    firmware = firmware or _build_for_target(native.FIRMWARE_ELF, "firmware")
    port_number, monitor_port = _free_port(), _free_port()
    serial_arg = f"tcp:127.0.0.1:{port_number},server=on,wait=on,nodelay=on"
    monitor_arg = f"tcp:127.0.0.1:{monitor_port},server=on,wait=off"
    proc = subprocess.Popen([QEMU, *QEMU_ARGS, "-kernel", str(firmware), "-serial", serial_arg,
                             "-monitor", monitor_arg],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + connect_timeout
    while True:
        try:
            port = _serial_for_url(f"socket://127.0.0.1:{port_number}", timeout=read_timeout)
            break
        except (serial.SerialException, OSError) as exc:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise LinkError(f"QEMU did not open its serial socket: {exc}") from exc
            time.sleep(0.05)
    return Link(port, f"qemu :{port_number}", proc, monitor_port)


def open_crazyflie(uri: str, process: subprocess.Popen | None = None) -> CrtpLink:
    """A cflib link driver for `uri` (radio://, usb://, udp://)."""
    import cflib.crtp

    if not cflib.crtp.CLASSES:
        cflib.crtp.init_drivers()
    errors: list[str] = []
    try:
        driver = cflib.crtp.get_link_driver(uri, link_error_callback=errors.append)
    except Exception as exc:  # cflib raises plain Exceptions for missing radios and dongles
        raise LinkError(f"cannot open {uri}: {exc}") from exc
    if driver is None:
        raise LinkError(f"no cflib link driver accepts {uri!r} (radio://, usb:// or udp://)")
    return CrtpLink(driver, f"crazyflie {uri}", process, errors=errors)


def open_native_udp(program: Path | None = None) -> CrtpLink:
    """The native program on its UDP endpoint, reached through cflib's udp:// driver."""
    program = program or _build_for_target(native.NATIVE_PROGRAM, "program")
    proc = subprocess.Popen([str(program), "--udp", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = proc.stdout.readline().decode().strip()
    if not line.startswith("UDP "):
        proc.kill()
        raise LinkError(f"native target did not open its UDP endpoint (said {line!r})")
    try:
        return open_crazyflie(f"udp://127.0.0.1:{line[4:]}", proc)
    except LinkError:
        proc.kill()
        raise


def open_url(url: str, read_timeout: float = 0.05, baudrate: int = 921_600,
             write_timeout: float = WRITE_TIMEOUT_S) -> Link:
    try:
        port = _serial_for_url(url, baudrate=baudrate, timeout=read_timeout, write_timeout=write_timeout)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(f"cannot open {url}: {exc}") from exc
    return Link(port, url)


def open_target(target: str) -> BoardLink:
    if target == "native":
        return open_native()
    if target == "native-udp":
        return open_native_udp()
    if target == "qemu":
        return open_qemu()
    if target.startswith("serial:"):
        return open_url(target[len("serial:"):])
    if target.startswith("crazyflie:"):
        return open_crazyflie(target[len("crazyflie:"):])
    raise LinkError(f"unknown target {target!r} (native, native-udp, qemu, serial:URL or crazyflie:URI)")


def _build_for_target(artifact: Path, make_target: str) -> Path:
    try:
        return native.built(artifact, make_target)
    except native.NativeBuildError as exc:
        raise LinkError(str(exc)) from exc
