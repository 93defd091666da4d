"""Targets: a name to the board it means, built if it is ours and started, behind its link.

    native          build estimator_c/build/estimator_native and run it on a pty
    native-udp      the same program on its UDP endpoint, reached through cflib's udp:// driver
    qemu            build the STM32F405 firmware and run it in qemu-system-arm -M netduinoplus2
    serial:URL      open URL with pyserial (a board that is already running)
    crazyflie:URI   a cflib link (radio://, usb:// or udp://) to a board running the estimator app
"""

from __future__ import annotations

import ctypes
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import serial

from rig.estimator import native
from rig.hil.links import BoardLink, CrtpLink, Link, LinkError, open_crazyflie, open_url
from rig.hil.links.serial_port import serial_for_url

QEMU = "qemu-system-arm"
PR_SET_PDEATHSIG = 1
# looked up once, here: the child between fork and exec must not load anything
_prctl = ctypes.CDLL(None, use_errno=True).prctl


def _die_with_the_rig() -> None:
    """In a child, before it runs: the kernel sends it SIGTERM when the rig (the thread
    that started it) ends, however it ends, SIGKILL included, so no board process
    outlives the rig."""
    _prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def start_child(args: list[str], **kwargs) -> subprocess.Popen:
    """A board process of the rig's: in its own session (a Ctrl-C at the terminal reaches
    the rig, which then closes the board in order) and ended with the rig."""
    return subprocess.Popen(args, preexec_fn=_die_with_the_rig, start_new_session=True, **kwargs)
# -icount shift=0: one instruction per virtual nanosecond, so TIM2 counts instructions
# deterministically; sleep=off: never wait for the host clock.
QEMU_ARGS = ["-M", "netduinoplus2", "-nographic", "-icount", "shift=0,sleep=off"]
# A board that stops reading fails the write after this long: without it the rig


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def open_native(program: Path | None = None, read_timeout: float = 0.05) -> Link:
    program = program or _build_for_target(native.NATIVE_PROGRAM, "program")
    proc = start_child([str(program), "--pty"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = proc.stdout.readline().decode().strip()
    if not line.startswith("PTY "):
        proc.kill()
        raise LinkError(f"native target did not open a pty (said {line!r})")
    port = serial_for_url(line[4:], baudrate=1_000_000, timeout=read_timeout)
    return Link(port, f"native {line[4:]}", proc)


def open_qemu(firmware: Path | None = None, read_timeout: float = 0.05, connect_timeout: float = 10.0) -> Link:
    if shutil.which(QEMU) is None:
        raise LinkError(f"{QEMU} is not installed (run scripts/setup.sh)")
    firmware = firmware or _build_for_target(native.FIRMWARE_ELF, "firmware")
    port_number, monitor_port = _free_port(), _free_port()
    serial_arg = f"tcp:127.0.0.1:{port_number},server=on,wait=on,nodelay=on"
    monitor_arg = f"tcp:127.0.0.1:{monitor_port},server=on,wait=off"
    proc = start_child([QEMU, *QEMU_ARGS, "-kernel", str(firmware), "-serial", serial_arg,
                             "-monitor", monitor_arg],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + connect_timeout
    while True:
        try:
            port = serial_for_url(f"socket://127.0.0.1:{port_number}", timeout=read_timeout)
            break
        except (serial.SerialException, OSError) as exc:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise LinkError(f"QEMU did not open its serial socket: {exc}") from exc
            time.sleep(0.05)
    return Link(port, f"qemu :{port_number}", proc, monitor_port)


def open_native_udp(program: Path | None = None) -> CrtpLink:
    """The native program on its UDP endpoint, reached through cflib's udp:// driver."""
    program = program or _build_for_target(native.NATIVE_PROGRAM, "program")
    proc = start_child([str(program), "--udp", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = proc.stdout.readline().decode().strip()
    if not line.startswith("UDP "):
        proc.kill()
        raise LinkError(f"native target did not open its UDP endpoint (said {line!r})")
    try:
        return open_crazyflie(f"udp://127.0.0.1:{line[4:]}", proc)
    except LinkError:
        proc.kill()
        raise


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
