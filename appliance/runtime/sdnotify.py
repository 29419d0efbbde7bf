"""systemd notification protocol (sd_notify) without a dependency, and the watchdog policy.

systemd passes ``$NOTIFY_SOCKET`` to a ``Type=notify`` service: a datagram socket path, or an
abstract-namespace name starting with ``@``. Each notification is one datagram of
newline-separated ``KEY=value`` lines: ``READY=1`` once the appliance runs, ``STATUS=...`` for
``systemctl status``, ``WATCHDOG=1`` at least every ``WATCHDOG_USEC`` (we send at half of it),
``STOPPING=1`` on shutdown. Outside systemd (no ``$NOTIFY_SOCKET``) every call is a no-op.

:class:`Watchdog` sends ``WATCHDOG=1`` only while acquisition is alive: when no new frame has
arrived for ``stall_s`` seconds the pings stop, systemd's watchdog fires, and
``Restart=on-failure`` restarts the service.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import Mapping

__all__ = ["SdNotifier", "Watchdog", "watchdog_period_s"]

log = logging.getLogger("ogiflow.sdnotify")


def watchdog_period_s(env: Mapping[str, str] | None = None, pid: int | None = None
                      ) -> float | None:
    """Seconds between watchdog pings asked for by systemd (half of ``WATCHDOG_USEC``).

    None when no watchdog is configured, or ``WATCHDOG_PID`` names another process.
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    wpid = env.get("WATCHDOG_PID", "")
    if wpid and wpid.isdigit() and int(wpid) != (os.getpid() if pid is None else pid):
        return None
    return int(usec) / 2e6


class SdNotifier:
    """Send notifications to ``$NOTIFY_SOCKET`` (or ``address``). Never raises on send.

    Parameters
    ----------
    address
        Socket path or ``@abstract`` name; default ``$NOTIFY_SOCKET``. Empty/None: disabled.
    """

    def __init__(self, address: str | None = None) -> None:
        addr = os.environ.get("NOTIFY_SOCKET", "") if address is None else address
        self.address = addr
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self.errors = 0
        if addr:
            target = "\0" + addr[1:] if addr.startswith("@") else addr
            self._target = target
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        """True when running under a notify-aware service manager."""
        return self._sock is not None

    def notify(self, text: str) -> bool:
        """Send one raw notification (``"KEY=value\\n..."``); False when disabled or failed."""
        if self._sock is None:
            return False
        with self._lock:
            try:
                self._sock.sendto(text.encode("utf-8"), self._target)
                return True
            except OSError as exc:
                self.errors += 1
                if self.errors == 1 or self.errors % 100 == 0:
                    log.warning("sd_notify to %s failed (%d times): %s", self.address,
                                self.errors, exc)
                return False

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (and a status line): startup finished."""
        return self.notify("READY=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def status(self, text: str) -> bool:
        """``STATUS=...``: shown by ``systemctl status``."""
        return self.notify(f"STATUS={_one_line(text)}")

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: the service is alive."""
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        """``STOPPING=1``: shutdown began."""
        return self.notify("STOPPING=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _one_line(text: str) -> str:
    return " ".join(text.split())


class Watchdog:
    """Ping systemd's watchdog only while frames keep arriving.

    Parameters
    ----------
    notifier
        Where the pings go.
    period_s
        Seconds between pings (:func:`watchdog_period_s`); None disables the pings.
    stall_s
        Stop pinging when the last frame is older than this (``health.stall_s``).

    Acquisition calls :meth:`frame_arrived` (cheap: one store); the health thread calls
    :meth:`tick` often (at least every ``period_s``).
    """

    def __init__(self, notifier: SdNotifier, period_s: float | None, stall_s: float) -> None:
        self._notifier = notifier
        self.period_s = period_s
        self.stall_s = stall_s
        self._last_frame = time.monotonic()  # grace period from start
        self._last_ping = float("-inf")
        self.pings = 0

    def frame_arrived(self, now: float | None = None) -> None:
        """Record that acquisition delivered a frame (monotonic seconds)."""
        self._last_frame = time.monotonic() if now is None else now

    def stalled(self, now: float | None = None) -> bool:
        """True when no frame arrived for ``stall_s`` seconds."""
        now = time.monotonic() if now is None else now
        return now - self._last_frame > self.stall_s

    def tick(self, now: float | None = None) -> bool:
        """Ping if due and not stalled; returns True when a ping was sent."""
        if self.period_s is None:
            return False
        now = time.monotonic() if now is None else now
        if self.stalled(now) or now - self._last_ping < self.period_s:
            return False
        if self._notifier.watchdog():
            self._last_ping = now
            self.pings += 1
            return True
        return False
