"""Stopping the rig by a signal without tearing what it writes: SIGINT, SIGTERM (`timeout`,
`docker stop`, a CI runner) and SIGHUP (a closed terminal) raise `Interrupted` in the
main thread, but never inside a `critical()` section — a message half-added to an MCAP
chunk would corrupt the chunk — where the signal waits for the section's end."""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_local = threading.local()            # each thread's depth of critical sections
_pending: list[int] = []              # a signal received inside the main thread's section


class Interrupted(KeyboardInterrupt):
    """The rig was asked to stop by a signal (its name is the exception's argument)."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _stop(signum, frame) -> None:
    if getattr(_local, "depth", 0):      # handlers run in the main thread: its own depth
        _pending.append(signum)          # raised when the critical section ends
        return
    raise Interrupted(signum)


def stop_on_signals() -> None:
    """SIGINT, SIGTERM and SIGHUP stop the rig alike (from the main thread only)."""
    if threading.current_thread() is threading.main_thread():
        for signum in SIGNALS:
            signal.signal(signum, _stop)


@contextmanager
def critical():
    """A section a signal does not interrupt: it takes effect once the section ends."""
    _local.depth = getattr(_local, "depth", 0) + 1
    try:
        yield
    finally:
        _local.depth -= 1
        if not _local.depth and _pending and threading.current_thread() is threading.main_thread():
            signum = _pending[0]
            _pending.clear()
            raise Interrupted(signum)
