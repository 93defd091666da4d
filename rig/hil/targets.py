"""Targets: a name to the board it means, built if it is ours and started, behind its link.

    native          build estimator_c/build/estimator_native and run it on a pty
    native-udp      the same program on its UDP endpoint, reached through cflib's udp:// driver
    qemu            build the STM32F405 firmware and run it in qemu-system-arm -M netduinoplus2,
                    its bytes through the bulk link (ARM semihosting on a socket chardev)
    qemu-usart      the same firmware and emulator, its bytes through the emulated USART1, one
                    byte per interrupt, as on a real board
    serial:URL      open URL with pyserial (a board that is already running)
    crazyflie:URI   a cflib link (radio://, usb:// or udp://) to a board running the estimator app
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import serial

from rig.estimator import native
from rig.hil.links import BoardLink, CrtpLink, Link, LinkError, open_crazyflie, open_url
from rig.hil.links.serial_port import PipePort, serial_for_url

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


# The bulk link (targets/stm32f405/board.h): the selector the firmware reads at reset, in
# the last RAM words, and semihosting, whose console (":tt") QEMU 7.2 maps to its own
# standard input and output.
BULK_MAGIC = 0x6B6C7562
BULK_SELECT_ADDRESS = 0x2001FFF0
QEMU_CHANNELS = ("bulk", "usart")
BULK_ARGS = ["-serial", "null", "-semihosting-config", "enable=on,target=native",
             "-device", f"loader,addr={BULK_SELECT_ADDRESS:#x},data={BULK_MAGIC:#x},data-len=4",
             "-device", f"loader,addr={BULK_SELECT_ADDRESS + 4:#x},data={~BULK_MAGIC & 0xFFFFFFFF:#x},data-len=4"]


def open_qemu(firmware: Path | None = None, read_timeout: float = 0.05, connect_timeout: float = 10.0,
              channel: str = "bulk") -> Link:
    """The firmware in QEMU: through the bulk link (default), or through the emulated
    USART on a local socket (`channel="usart"`, the path a real board's bytes take)."""
    if channel not in QEMU_CHANNELS:
        raise LinkError(f"unknown QEMU channel {channel!r} (one of {', '.join(QEMU_CHANNELS)})")
    if shutil.which(QEMU) is None:
        raise LinkError(f"{QEMU} is not installed (run scripts/setup.sh)")
    firmware = firmware or _build_for_target(native.FIRMWARE_ELF, "firmware")
    monitor_port = _free_port()
    args = [QEMU, *QEMU_ARGS, "-kernel", str(firmware), "-monitor",
            f"tcp:127.0.0.1:{monitor_port},server=on,wait=off"]
    if channel == "bulk":
        return _open_qemu_bulk(args, read_timeout, monitor_port)
    port_number = _free_port()
    serial_arg = f"tcp:127.0.0.1:{port_number},server=on,wait=on,nodelay=on"
    proc = start_child([*args, "-serial", serial_arg],
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
    return Link(port, f"qemu usart :{port_number}", proc, monitor_port)


def _open_qemu_bulk(args: list[str], read_timeout: float, monitor_port: int) -> Link:
    """QEMU with the bulk link on its standard input and output. Its input is non-blocking,
    so a semihosting read with nothing to read returns at once (the firmware polls, and
    QEMU's main loop, the monitor included, keeps running between calls)."""
    to_board, from_rig = os.pipe()
    os.set_blocking(to_board, False)
    try:
        proc = start_child([*args, *BULK_ARGS], stdin=to_board, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    except OSError:
        os.close(from_rig)
        raise
    finally:
        os.close(to_board)
    port = PipePort(from_rig, proc.stdout.fileno(), timeout=read_timeout)
    return Link(port, f"qemu bulk pid {proc.pid}", proc, monitor_port)


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
    if target == "qemu-usart":
        return open_qemu(channel="usart")
    if target.startswith("serial:"):
        return open_url(target[len("serial:"):])
    if target.startswith("crazyflie:"):
        return open_crazyflie(target[len("crazyflie:"):])
    raise LinkError(f"unknown target {target!r} (native, native-udp, qemu, qemu-usart, serial:URL or crazyflie:URI)")


def _build_for_target(artifact: Path, make_target: str) -> Path:
    try:
        return native.built(artifact, make_target)
    except native.NativeBuildError as exc:
        raise LinkError(str(exc)) from exc
