"""Links to boards: a pyserial port to the native program (over a pty), to QEMU's
emulated USART1 (over a TCP socket), or to any pyserial URL (a real tty,
``socket://``, ``rfc2217://``). Every link speaks rig.protocol frames.

Targets:
    native          build estimator_c/build/estimator_native and run it on a pty
    qemu            build the STM32F405 firmware and run it in qemu-system-arm -M netduinoplus2
    serial:URL      open URL with pyserial (a board that is already running)
"""

from __future__ import annotations

import logging
import shutil
import socket
import subprocess
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import serial

from rig import native, protocol

log = logging.getLogger(__name__)

QEMU = "qemu-system-arm"
# -icount shift=0: one instruction per virtual nanosecond, so TIM2 counts instructions
# deterministically; sleep=off: never wait for the host clock.
QEMU_ARGS = ["-M", "netduinoplus2", "-nographic", "-monitor", "none", "-icount", "shift=0,sleep=off"]


class LinkError(Exception):
    """The board could not be reached, stopped answering or reset."""


@dataclass
class Link:
    """A serial link carrying protocol frames; owns the target process if it started one."""

    port: serial.SerialBase
    name: str
    process: subprocess.Popen | None = None
    parser: protocol.Parser = field(default_factory=protocol.Parser)
    bytes_sent: int = 0
    pending: deque = field(default_factory=deque)

    def send(self, payloads: list[bytes]) -> None:
        data = b"".join(protocol.frame(p) for p in payloads)
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"{self.name}: write failed: {exc}") from exc
        self.bytes_sent += len(data)

    def next_message(self, timeout: float):
        """The next decoded message, or None when none arrives within `timeout`."""
        if not self.pending:
            self.pending.extend(self.receive(timeout))
        return self.pending.popleft() if self.pending else None

    def receive(self, timeout: float) -> list:
        """Decoded messages that arrive within `timeout` (at least one, or an empty list)."""
        deadline = time.monotonic() + timeout
        while True:
            self._check_alive()
            try:
                waiting = self.port.in_waiting
                chunk = self.port.read(max(1, waiting))
            except (serial.SerialException, OSError) as exc:
                raise LinkError(f"{self.name}: read failed (board gone?): {exc}") from exc
            if chunk:
                messages = []
                for payload in self.parser.feed(chunk):
                    try:
                        messages.append(protocol.decode(payload))
                    except protocol.ProtocolError as exc:
                        log.warning("%s: %s", self.name, exc)
                if messages:
                    return messages
            if time.monotonic() > deadline:
                return []

    def _check_alive(self) -> None:
        if self.process is not None and self.process.poll() is not None:
            err = self.process.stderr.read().decode(errors="replace")[-500:] if self.process.stderr else ""
            raise LinkError(f"{self.name}: target process exited with status {self.process.returncode}"
                            + (f": {err.strip()}" if err.strip() else ""))

    def close(self) -> None:
        try:
            self.port.close()
        finally:
            if self.process is not None and self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()


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
    port = serial.serial_for_url(line[4:], baudrate=1_000_000, timeout=read_timeout)
    return Link(port, f"native {line[4:]}", proc)


def open_qemu(firmware: Path | None = None, read_timeout: float = 0.05, connect_timeout: float = 10.0) -> Link:
    if shutil.which(QEMU) is None:
        raise LinkError(f"{QEMU} is not installed (run scripts/setup.sh)")
    firmware = firmware or _build_for_target(native.FIRMWARE_ELF, "firmware")
    port_number = _free_port()
    serial_arg = f"tcp:127.0.0.1:{port_number},server=on,wait=on,nodelay=on"
    proc = subprocess.Popen([QEMU, *QEMU_ARGS, "-kernel", str(firmware), "-serial", serial_arg],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + connect_timeout
    while True:
        try:
            port = serial.serial_for_url(f"socket://127.0.0.1:{port_number}", timeout=read_timeout)
            break
        except (serial.SerialException, OSError) as exc:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise LinkError(f"QEMU did not open its serial socket: {exc}") from exc
            time.sleep(0.05)
    return Link(port, f"qemu :{port_number}", proc)


def open_url(url: str, read_timeout: float = 0.05, baudrate: int = 921_600) -> Link:
    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=read_timeout)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(f"cannot open {url}: {exc}") from exc
    return Link(port, url)


def open_target(target: str) -> Link:
    if target == "native":
        return open_native()
    if target == "qemu":
        return open_qemu()
    if target.startswith("serial:"):
        return open_url(target[len("serial:"):])
    raise LinkError(f"unknown target {target!r} (native, qemu or serial:URL)")


def _build_for_target(artifact: Path, make_target: str) -> Path:
    try:
        return native.built(artifact, make_target)
    except native.NativeBuildError as exc:
        raise LinkError(str(exc)) from exc
