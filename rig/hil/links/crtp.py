"""A Crazyflie link through cflib's link drivers (radio://, usb://, udp://): the same
messages unframed in CRTP app-channel packets (port 13, channel 2), one message per
packet; the link frames and checks packets itself."""

from __future__ import annotations

import subprocess
import time
from collections import deque
from dataclasses import dataclass, field

from rig.hil.links.base import BoardLink, LinkError

CRTP_APP_PORT, CRTP_APP_CHANNEL = 13, 2


@dataclass
class CrtpLink(BoardLink):
    """Protocol messages in CRTP app-channel packets through a cflib link driver (the
    link frames and checks packets, so messages travel bare: one per packet)."""

    driver: object
    name: str
    process: subprocess.Popen | None = None
    bytes_sent: int = 0
    bytes_received: int = 0
    pending: deque = field(default_factory=deque)
    errors: list = field(default_factory=list)

    def send(self, payloads: list[bytes], framed: bytes | None = None) -> None:
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
                self.bytes_received += len(packet.data) + 1          # with the CRTP header byte
                return [bytes(packet.data)]
            if time.monotonic() > deadline:
                return []

    def _raise_link_error(self) -> None:
        if self.errors:
            raise LinkError(f"{self.name}: {self.errors[0]}")

    def _close_channel(self) -> None:
        self.driver.close()


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
