"""SIGTERM and SIGINT as a request the daemon's main loop takes, not an action in the
handler."""

from __future__ import annotations

import logging
import signal
import threading
from typing import Any

log = logging.getLogger("ogiflow")

#: The signals that stop a run (systemd's stop, Ctrl-C).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class SignalLatch:
    """Remembers a stop signal until the main thread's wait loop takes it.

    Parameters
    ----------
    stop_event : threading.Event
        The run's stop event, set by :meth:`take` once a signal arrived.
    """

    def __init__(self, stop_event: threading.Event) -> None:
        self.stop_event = stop_event
        #: The signal (SIGTERM, SIGINT) that asked the run to stop, None until one does.
        self.signalled: int | None = None
        self._previous: dict[int, Any] = {}

    def install(self) -> None:
        """Catch the stop signals (the previous handlers come back with :meth:`restore`)."""
        self._previous = {sig: signal.signal(sig, self.on_signal) for sig in STOP_SIGNALS}

    def restore(self) -> None:
        """Put back the handlers :meth:`install` replaced."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def on_signal(self, signum: int, frame: Any) -> None:
        """The handler. Only an assignment: Python runs it in the main thread between two
        bytecodes, which may be inside ``stop_event.wait()`` while it holds the event's
        lock; ``stop_event.set()`` (or a log call, whose handler has a lock too) then
        waited for itself, and a SIGTERM from systemd left the daemon hanging with every
        file open (seen once in the test suite). The wait loop calls :meth:`take` within
        0.2 s."""
        self.signalled = signum

    def take(self) -> None:
        """Stop the run if a signal asked for it (the main thread's wait loop calls this)."""
        if self.signalled is not None and not self.stop_event.is_set():
            log.info("signal %d: shutting down", self.signalled)
            self.stop_event.set()
