"""What replay needs of a link to a board, whatever carries it."""

from __future__ import annotations

import logging
import subprocess
import time
from collections import deque

from rig.hil import protocol

log = logging.getLogger(__name__)


class LinkError(Exception):
    """The board could not be reached, stopped answering or reset."""


class BoardLink:
    """What replay needs from a link: send payloads, take decoded messages, close. Owns
    the target process if it started one."""

    name: str
    process: subprocess.Popen | None
    bytes_sent: int
    bytes_received: int          # what the board sent, as the link carries it (frames, packets)
    pending: deque

    def send(self, payloads: list[bytes], framed: bytes | None = None) -> None:
        """Send `payloads`; a byte-stream link may take them already framed (`framed`,
        protocol.frames of the same payloads), as a replay prepares its windows."""
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
