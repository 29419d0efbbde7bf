"""The alarm-sink interface: what the daemon tells the plant's systems.

A sink receives the appliance status (with health), leak events (start, update, end) and
per-frame summaries. Every method must return at once: acquisition and recording never
wait for a sink, so a sink queues (boundedly) and sends from its own thread. MQTT is the
first transport (:mod:`appliance.alarms.mqtt`); another one (e.g. Modbus TCP registers for
a PLC) implements the same four methods.
"""

from __future__ import annotations

import abc
from dataclasses import asdict, dataclass
from typing import Any


@dataclass
class SinkStats:
    """Counters of one sink for the health report."""

    connected: bool = False
    published: int = 0
    dropped: int = 0
    queued: int = 0
    disconnects: int = 0
    outage_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class AlarmSink(abc.ABC):
    """Where status, events and summaries go; no method may block."""

    @abc.abstractmethod
    def status(self, status: dict[str, Any]) -> None:
        """The appliance is online; ``status`` holds its health in words and numbers."""

    @abc.abstractmethod
    def event(self, kind: str, event: dict[str, Any]) -> None:
        """A leak event changed: ``kind`` is ``"start"``, ``"update"`` or ``"end"``."""

    @abc.abstractmethod
    def summary(self, summary: dict[str, Any]) -> None:
        """The newest per-frame summary (a sink may rate-limit these)."""

    @abc.abstractmethod
    def stats(self) -> SinkStats:
        """Counters for the health report."""

    @abc.abstractmethod
    def close(self, timeout: float = 2.0) -> None:
        """Say goodbye and release the connection (bounded by ``timeout``)."""
