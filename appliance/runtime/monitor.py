"""The unattended monitor: leak events, emission rate window, status, alarms.

Runs in the daemon's results thread (it is cheap: a few mask operations per result) and
fans out to sinks that never block: the recorder (``/events``), the alarm sinks (MQTT) and
the live view's operator tab. The decisions themselves are pure
(:mod:`appliance.runtime.events`, :mod:`processing.emission.rate`).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from appliance.alarms.mqtt import MqttConfig, MqttSink
from appliance.live.status import OperatorStatus, health_words
from appliance.runtime.events import (
    EventConfig,
    EvidenceStream,
    LeakDetector,
    LeakEvent,
    zone_mask,
)
from appliance.runtime.health import camera_words
from processing.emission.rate import FrameRate, RateEstimate

log = logging.getLogger("ogiflow.monitor")

#: Events in the operator's list (the newest; the open one first).
EVENTS_SHOWN = 10


class LeakMonitor:
    """Feeds every result into the event logic and the rate window; reports changes.

    Parameters
    ----------
    events : EventConfig
        Thresholds and zones.
    image_size : (int, int)
        (W, H) of the left image (for the zones).
    on_event : callable
        ``(kind, event_dict)`` for every start/update/end (recorder, clips); it may return a
        mapping of more fields for the event (its clip folder), which the alarm sinks and
        the status's event list then carry.
    alarm_sinks : sequence
        :class:`appliance.alarms.sink.AlarmSink` objects (status and summaries too).
    live : LiveView, ViewFanout or None
        Receives :class:`OperatorStatus` items (the Rerun view and the operator's page).
    true_rate_g_s : float or None
        Simulated runs: the simulator's release rate, shown beside the measurement.
    nominal_fps : float
        The cameras' frame rate (a camera below a share of it is named as slow).
    """

    def __init__(self, events: EventConfig, image_size: tuple[int, int], *,
                 on_event: Callable[[str, dict[str, Any]], None] | None = None,
                 alarm_sinks: Sequence[Any] = (), live: Any = None,
                 true_rate_g_s: float | None = None, nominal_fps: float = 30.0) -> None:
        w, h = image_size
        self.nominal_fps = nominal_fps
        self.detector = LeakDetector(events)
        self.zones = zone_mask((h, w), events.watch_zones, events.ignore_zones)
        # The cameras' frame interval picks the evidence for the footage's speed: flow at
        # video rates, where gas stays (occupancy) for slow footage such as 1 frame/s.
        self.evidence = EvidenceStream(self.zones, frame_interval_s=1.0 / nominal_fps)
        self.on_event = on_event
        self.sinks = list(alarm_sinks)
        self.live = live
        self.true_rate_g_s = true_rate_g_s
        self.rate: RateEstimate | None = None
        self.wind: tuple[float, float, float] | None = None
        self._health: list[str] = []
        self._health_snapshot: dict[str, Any] | None = None
        #: Extra fields of recent events from ``on_event`` (clip folders), by event id.
        self._extra: dict[int, dict[str, Any]] = {}
        self._t_wall_ns = 0
        self._frame = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ inputs

    def on_result(self, t_wall_ns: int, frame: int, gas_mask: np.ndarray, flow: np.ndarray,
                  summary: dict[str, Any], *, wind: np.ndarray | None = None,
                  rate: FrameRate | None = None,
                  window: RateEstimate | None = None) -> None:
        """One published result (results thread).

        ``t_wall_ns`` is the daemon's wall time of the frame, a fixed offset from the
        monotonic clock (a step of the wall clock does not change event durations).
        ``flow`` is the image-plane flow, whole (H, W, 2) or at the gas pixels (N, 2)
        (:func:`~appliance.runtime.evidence.evidence_from_fields`).
        ``rate`` is this frame's emission estimate, ``window`` the publisher's windowed
        average after it (the one the summaries carry: one window, not two).
        """
        t_s = t_wall_ns / 1e9
        # None: the worker did not estimate this triple (emission.every); the last window
        # stands until the next estimate.
        with self._lock:
            if window is not None:
                self.rate = window
            self.wind = None if wind is None else tuple(float(v) for v in wind)  # type: ignore[assignment]
            self._t_wall_ns, self._frame = t_wall_ns, frame
            velocity = summary.get("mean_velocity_m_s")
            ev = self.evidence(
                t_s, frame, gas_mask, flow, rate_g_s=None if rate is None else rate.rate_g_s,
                velocity_m_s=tuple(velocity) if velocity else None, wind_m_s=self.wind)
            transitions = self.detector.update(ev)
        for kind, event in transitions:
            self._report(kind, event, t_wall_ns)
        for sink in self.sinks:
            sink.summary({"t_wall_ns": t_wall_ns, "frame": frame, **summary,
                          "rate_g_s": self.rate.rate_g_s if self.rate else None,
                          "leak": self.detector.current is not None})
        if transitions and any(k != "update" for k, _ in transitions):
            self.push_status()

    def on_health(self, snapshot: Any) -> None:
        """One health snapshot (health reporter thread)."""
        words = camera_words(snapshot) + health_words(snapshot, self.nominal_fps)
        with self._lock:
            self._health = words
            self._health_snapshot = snapshot.to_dict()
        for sink in self.sinks:
            sink.status({"health": words, "t_wall_ns": int(snapshot.t_wall_ns),
                         "leak": self.detector.current is not None,
                         "mode": snapshot.mode, "cameras": snapshot.cameras,
                         "counters": dict(snapshot.counters)})
        self.push_status(int(snapshot.t_wall_ns))

    def close(self) -> None:
        """End an ongoing event at shutdown (reason ``appliance stopped``), at the last frame."""
        with self._lock:
            t_wall_ns, frame = self._t_wall_ns, self._frame
            event = self.detector.close(t_wall_ns / 1e9, frame)
        if event is not None:
            self._report("end", event, t_wall_ns)

    # ------------------------------------------------------------------ outputs

    def _report(self, kind: str, event: LeakEvent, t_wall_ns: int) -> None:
        with self._lock:
            r = self.rate
        d = {"t_wall_ns": t_wall_ns, **event.to_dict(), **self._extra.get(event.id, {})}
        if kind != "update":
            log.warning("leak event %d %s: %s", event.id, kind,
                        {k: v for k, v in d.items() if v is not None})
        if self.on_event is not None:
            extra = self.on_event(kind, d)
            if extra:
                with self._lock:
                    self._extra.setdefault(event.id, {}).update(extra)
                    for old in sorted(self._extra)[:-EVENTS_SHOWN]:
                        del self._extra[old]
                d.update(extra)
        # The rate the operator reads now (the window), beside the event's own statistics.
        d.update({"rate_kg_h": None if r is None else r.rate_kg_h,
                  "rate_uncertainty_kg_h": None if r is None or r.uncertainty_g_s is None
                  else r.uncertainty_g_s * 3.6,
                  "rate_flags": [] if r is None else list(r.flags)})
        for sink in self.sinks:
            sink.event(kind, d)

    def status(self, t_wall_ns: int | None = None) -> OperatorStatus:
        """The operator's status now."""
        with self._lock:
            cur = self.detector.current
            shown = list(self.detector.finished[-(EVENTS_SHOWN - 1):])
            if cur is not None:
                shown.append(cur)
            events = [{**e.to_dict(), **self._extra.get(e.id, {})} for e in reversed(shown)]
            r = self.rate
            return OperatorStatus(
                t_capture_ns=t_wall_ns or self._t_wall_ns,
                leak=None if cur is None else {**cur.to_dict(), **self._extra.get(cur.id, {})},
                rate_kg_h=None if r is None or r.rate_kg_h is None else r.rate_kg_h,
                rate_uncertainty_kg_h=(None if r is None or r.uncertainty_g_s is None
                                       else r.uncertainty_g_s * 3.6),
                rate_flags=() if r is None else r.flags,
                true_rate_kg_h=(None if self.true_rate_g_s is None
                                else self.true_rate_g_s * 3.6),
                wind_m_s=self.wind, health=list(self._health), events=events,
                newest_result_ns=self._t_wall_ns or None,
                health_snapshot=self._health_snapshot)

    def push_status(self, t_wall_ns: int | None = None) -> None:
        if self.live is not None:
            self.live.push(self.status(t_wall_ns))


def monitor_from_config(cfg: Any, image_size: tuple[int, int], stack: Any, *, live: Any,
                        on_event: Callable[[str, dict[str, Any]], None],
                        true_rate_g_s: float | None, nominal_fps: float = 30.0
                        ) -> LeakMonitor:
    """The daemon's monitor from the ``events`` and ``alarms`` config sections; alarm sinks
    are started here and closed by ``stack`` (after the monitor has ended an open event,
    when the monitor's own close is registered after this call)."""
    ev = cfg.events
    events = EventConfig(**{f.name: getattr(ev, f.name) for f in dataclasses.fields(EventConfig)})
    sinks = []
    mq = cfg.alarms.mqtt
    if mq.enabled:

        sink = MqttSink(MqttConfig(**{f.name: getattr(mq, f.name)
                                      for f in dataclasses.fields(MqttConfig)})).start()
        stack.callback(sink.close)
        sinks.append(sink)
    return LeakMonitor(events, image_size, on_event=on_event,
                       alarm_sinks=sinks, live=live, true_rate_g_s=true_rate_g_s,
                       nominal_fps=nominal_fps)
