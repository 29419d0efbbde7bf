"""Leak-event messages for plant systems: ``new``, ``update`` and ``end`` with one ``id``.

The leak monitor reports a transition for every processed frame of an ongoing event (about
15 a second). Event consumers (SCADA, Home Assistant, Frigate-style integrations) want one
``new`` when an event opens, an ``update`` only when something they act on changed, and one
``end`` with the final figures. :class:`EventThrottle` turns the monitor's transitions into
those messages:

- ``new``: the event opened (always sent);
- ``update``: the event's *key* changed since the last message of this event, and at least
  ``update_s`` passed since it (a change that comes sooner waits and goes out with the
  figures of the frame that releases it). The key is the state (``leak``), the rate class
  (:func:`rate_class`), the rate's flags (``line_of_sight``, ``single_camera``) and the
  source's place (a move of more than ``source_step_px`` from the last one sent);
- ``end``: the event ended (always sent, with the final figures).

Time is the frames' wall time (``t_wall_ns``), not the wall clock of the moment: a replay
or a slow results thread throttles the same way as live.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["RATE_CLASS_EDGES_KG_H", "EventThrottle", "event_message", "rate_class"]

#: Upper edges of the rate classes, kg/h (roughly a factor 3 apart: a class change is a
#: change an operator would call "more" or "less").
RATE_CLASS_EDGES_KG_H = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)

#: The monitor's transition kinds -> message types.
TYPES = {"start": "new", "update": "update", "end": "end"}


def rate_class(rate_kg_h: float | None) -> str:
    """The class of a windowed emission rate: ``"unknown"``, ``"<0.1"``, ``"0.1-0.3"``, ...,
    ``">=100"`` (kg/h)."""
    if rate_kg_h is None or not math.isfinite(rate_kg_h):
        return "unknown"
    lo = None
    for edge in RATE_CLASS_EDGES_KG_H:
        if rate_kg_h < edge:
            return f"<{edge:g}" if lo is None else f"{lo:g}-{edge:g}"
        lo = edge
    return f">={lo:g}"


def event_message(kind: str, event: Mapping[str, Any]) -> dict[str, Any]:
    """The payload of one event message (documented in docs/operator-page.md).

    ``event`` is what the leak monitor reports (``LeakEvent.to_dict()`` plus ``t_wall_ns``,
    the current window rate ``rate_kg_h``, ``rate_uncertainty_kg_h``, ``rate_flags`` and,
    when recorded, ``clip``).
    """
    msg: dict[str, Any] = {"type": TYPES[kind], "id": int(event["id"]),
                           "state": "ended" if kind == "end" else "leak"}
    msg.update({k: v for k, v in event.items() if k != "id"})
    msg["rate_class"] = rate_class(event.get("rate_kg_h"))
    start, end = event.get("start_t_s"), event.get("end_t_s")
    now = end if end is not None else event.get("t_wall_ns", 0) / 1e9
    msg["duration_s"] = None if start is None else max(0.0, float(now) - float(start))
    return msg


@dataclass
class _Sent:
    """What the last message of the open event said (its key) and when (frame time, s)."""

    t_s: float
    state: str
    rate_class: str
    flags: tuple[str, ...]
    source: tuple[float, float] | None


class EventThrottle:
    """Decides which of the monitor's transitions become messages (module docstring).

    Parameters
    ----------
    update_s : float
        Least time between two messages of one event, s (``alarms.mqtt.update_s``).
    source_step_px : float
        A source that moved more than this from the last one sent counts as a change, px.
    """

    def __init__(self, update_s: float = 1.0, source_step_px: float = 12.0) -> None:
        self.update_s = float(update_s)
        self.source_step_px = float(source_step_px)
        self._sent: dict[int, _Sent] = {}
        #: Transitions seen and messages let through (for tests and the health report).
        self.seen = 0
        self.passed = 0

    def offer(self, kind: str, event: Mapping[str, Any]) -> dict[str, Any] | None:
        """The message for transition ``kind`` of ``event``, or None when it is held back."""
        self.seen += 1
        msg = event_message(kind, event)
        eid = msg["id"]
        key = _Sent(float(msg.get("t_wall_ns", 0)) / 1e9, msg["state"], msg["rate_class"],
                    tuple(sorted(msg.get("rate_flags") or ())), _xy(msg.get("source_xy")))
        if kind == "end":
            self._sent.pop(eid, None)
        elif kind == "update":
            last = self._sent.get(eid)
            if last is not None and not (self._changed(last, key)
                                         and key.t_s - last.t_s >= self.update_s):
                return None
            self._sent[eid] = key
        else:
            self._sent[eid] = key
        self.passed += 1
        return msg

    def _changed(self, last: _Sent, now: _Sent) -> bool:
        if (last.state, last.rate_class, last.flags) != (now.state, now.rate_class, now.flags):
            return True
        if (last.source is None) != (now.source is None):
            return True
        if last.source is None or now.source is None:
            return False
        return math.dist(last.source, now.source) > self.source_step_px


def _xy(v: Sequence[float] | None) -> tuple[float, float] | None:
    return None if v is None else (float(v[0]), float(v[1]))
