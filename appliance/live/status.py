"""The operator's status panel and event list, in words (markdown for Rerun's TextDocument).

An operator asks three things: is it leaking (and how much, for how long), where does the
wind blow, is the box healthy. These pure functions turn the daemon's state into those
answers; :class:`appliance.live.view.LiveView` shows them in the ``operator`` tab.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

#: Camera frame rates below this fraction of nominal count as a camera problem.
LOW_RATE_FRACTION = 0.8


@dataclass
class OperatorStatus:
    """What the status panel shows (one ``LiveView.push``).

    Attributes
    ----------
    t_capture_ns : int
        Wall-clock time of the newest result, UNIX ns.
    leak : dict or None
        The ongoing leak event (``LeakEvent.to_dict()``), None when there is none.
    rate_kg_h, rate_uncertainty_kg_h : float or None
        Windowed emission rate and its uncertainty.
    rate_flags : tuple of str
        Qualifiers of that rate (``line_of_sight``).
    true_rate_kg_h : float or None
        Simulated runs: the simulator's release rate.
    wind_m_s : (float, float, float) or None
        Anemometer wind in the camera frame (X right, Y down, Z forward).
    health : list of str
        Health in words (:func:`health_words`).
    events : list of dict
        Recent events, newest first (``LeakEvent.to_dict()``).
    newest_result_ns : int or None
        Capture time of the newest processed frame, UNIX ns: shown to the tenth of a second
        so that an operator sees how fresh the picture is (and the browser test measures the
        display latency from it).
    health_snapshot : dict or None
        The newest health snapshot whole (``HealthSnapshot.to_dict()``): every field the
        health monitor reports (streams, counters, gauges, stalled, and whatever it adds
        later) reaches the page and ``/status.json`` without a change here.
    """

    t_capture_ns: int
    leak: Mapping[str, Any] | None = None
    rate_kg_h: float | None = None
    rate_uncertainty_kg_h: float | None = None
    rate_flags: tuple[str, ...] = ()
    true_rate_kg_h: float | None = None
    wind_m_s: tuple[float, float, float] | None = None
    health: list[str] = field(default_factory=list)
    events: list[Mapping[str, Any]] = field(default_factory=list)
    newest_result_ns: int | None = None
    health_snapshot: Mapping[str, Any] | None = None

    @property
    def leak_state(self) -> str:
        """``"LEAK"`` while an event is open (the state MQTT publishes), else ``"NO LEAK"``."""
        return "NO LEAK" if self.leak is None else "LEAK"

    def to_dict(self) -> dict[str, Any]:
        """The JSON of ``/status.json`` and of the page's ``status`` messages (the payload is
        documented in docs/operator-page.md)."""
        now_s = self.t_capture_ns / 1e9
        leak = None if self.leak is None else dict(self.leak)
        wind = self.wind_m_s
        ok_wind = wind is not None and all(math.isfinite(v) for v in wind)
        return {
            "t_wall_ns": self.t_capture_ns,
            "leak": {
                "state": self.leak_state,
                "event": leak,
                "since_t_s": None if leak is None else leak.get("start_t_s"),
                "for_s": None if leak is None else max(
                    0.0, now_s - float(leak.get("start_t_s", now_s))),
                "words": (f"LEAK for {duration_words(now_s - float(leak['start_t_s']))}"
                          if leak is not None and leak.get("start_t_s") is not None
                          else self.leak_state),
            },
            "rate": {
                "kg_h": self.rate_kg_h, "uncertainty_kg_h": self.rate_uncertainty_kg_h,
                "flags": list(self.rate_flags), "true_kg_h": self.true_rate_kg_h,
            },
            "wind": {
                "vector_m_s": list(wind) if ok_wind else None,
                "speed_m_s": math.sqrt(sum(v * v for v in wind)) if ok_wind else None,
                "words": wind_words(wind),
            },
            "health": {"words": list(self.health), "snapshot": (
                None if self.health_snapshot is None else dict(self.health_snapshot))},
            "events": [dict(e) for e in self.events],
            "newest_result_ns": self.newest_result_ns,
        }


def duration_words(seconds: float) -> str:
    """``75`` -> ``"1 min 15 s"``; ``4000`` -> ``"1 h 6 min"``."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {(s % 3600) // 60} min"


def wind_words(wind: tuple[float, float, float] | None) -> str:
    """Wind in the camera frame as a sentence: speed and where it blows in the picture."""
    if wind is None or not all(math.isfinite(v) for v in wind):
        return "wind: no valid anemometer reading"
    x, y, z = wind
    speed = math.sqrt(x * x + y * y + z * z)
    if speed < 0.2:
        return f"wind: calm ({speed:.1f} m/s)"
    parts = []
    if abs(x) >= 0.3 * speed:
        parts.append("to the right" if x > 0 else "to the left")
    if abs(y) >= 0.3 * speed:
        parts.append("downwards" if y > 0 else "upwards")
    if abs(z) >= 0.3 * speed:
        parts.append("away from the camera" if z > 0 else "towards the camera")
    return f"wind: {speed:.1f} m/s, blowing {' and '.join(parts)}"


def health_words(snapshot: Any, nominal_fps: float = 30.0) -> list[str]:
    """The box's health in short sentences, problems first (from a HealthSnapshot)."""
    problems, fine = [], []
    if getattr(snapshot, "stalled", False):
        problems.append("NO FRAMES: the cameras stopped delivering")
    streams = getattr(snapshot, "streams", {})
    for side in ("left", "right"):
        s = streams.get(f"cam/{side}")
        if s is None:
            continue
        if s.rate_hz < LOW_RATE_FRACTION * nominal_fps:
            problems.append(f"{side} camera slow or gone ({s.rate_hz:.0f} frames/s)")
    wind = streams.get("wind")
    if wind is not None and wind.rate_hz <= 0.0:
        problems.append("anemometer silent")
    counters = getattr(snapshot, "counters", {})
    if counters.get("recorder_drops"):
        problems.append(f"recording lost {counters['recorder_drops']} messages")
    if counters.get("recording_paused"):
        problems.append("recording paused (disk full?)")
    free = getattr(snapshot, "gauges", {}).get("disk_free_gb")
    if free is not None and free < 5.0:
        problems.append(f"disk almost full ({free:.1f} GB free)")
    if not problems:
        fine.append("all devices delivering")
    if free is not None:
        fine.append(f"{free:.0f} GB free for recordings")
    steps = offset_step_words(counters, getattr(snapshot, "uptime_s", 0.0))
    return problems + fine + ([steps] if steps else [])


def offset_step_words(counters: Mapping[str, int], uptime_s: float) -> str | None:
    """How often each camera's whole picture stepped (a flat-field shutter, a
    non-uniformity correction, a drift of its offset) and was levelled out, since the
    start; None when neither did. A camera that does so far more often than its
    maker's shutter interval is unsteady (its housing's temperature, its power)."""
    parts = []
    for side in ("left", "right"):
        n = int(counters.get(f"offset_steps_{side}", 0))
        if n:
            parts.append(f"{side} {n} (one per {duration_words(uptime_s / n)})")
    if not parts:
        return None
    return "offset steps levelled since the start: " + ", ".join(parts)


def _fmt_time(t_s: float | None) -> str:
    if t_s is None:
        return "-"
    return datetime.fromtimestamp(t_s, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def status_markdown(s: OperatorStatus) -> str:
    """The status panel: LEAK or no leak, rate, duration, wind, health."""
    lines = []
    now_s = s.t_capture_ns / 1e9
    if s.leak is not None:
        dur = duration_words(now_s - float(s.leak.get("start_t_s", now_s)))
        lines.append(f"# LEAK - for {dur}")
    else:
        lines.append("# No leak")
    if s.newest_result_ns:  # near the top: the panel is short and does not scroll by itself
        t = datetime.fromtimestamp(s.newest_result_ns / 1e9, tz=timezone.utc)
        lines.append(f"Newest frame: {t.strftime('%H:%M:%S')}.{t.microsecond // 100_000} UTC")
    if s.rate_kg_h is not None:
        unc = (f" +- {s.rate_uncertainty_kg_h:.2f}" if s.rate_uncertainty_kg_h is not None
               else "")
        lines.append(f"**Emission rate: {s.rate_kg_h:.2f}{unc} kg/h**")
        if "line_of_sight" in s.rate_flags:
            lines.append("(weak: the gas moves mostly along the line of sight)")
    elif s.leak is not None:
        lines.append("Emission rate: not measurable now (see flags)")
    if s.true_rate_kg_h is not None:
        lines.append(f"(simulation: true release {s.true_rate_kg_h:.2f} kg/h)")
    lines.append("")
    lines.append(wind_words(s.wind_m_s))
    lines.append("")
    lines.append("**Appliance:** " + ("; ".join(s.health) if s.health else "starting"))
    return "\n\n".join(x for x in lines if x is not None)


def events_markdown(events: Sequence[Mapping[str, Any]], limit: int = 10) -> str:
    """The newest ``limit`` events as a markdown table."""
    if not events:
        return "No leak events yet."
    rows = ["| # | start | duration | mean kg/h | peak kg/h | source (x, y) | ended |",
            "|---|---|---|---|---|---|---|"]
    for e in list(events)[:limit]:
        start = e.get("start_t_s")
        end = e.get("end_t_s")
        dur = duration_words(end - start) if start is not None and end is not None else "ongoing"
        mean = e.get("mean_rate_g_s")
        peak = e.get("peak_rate_g_s")
        src = e.get("source_xy")
        rows.append(
            f"| {e.get('id')} | {_fmt_time(start)} | {dur} | "
            f"{'-' if mean is None else f'{mean * 3.6:.2f}'} | "
            f"{'-' if peak is None else f'{peak * 3.6:.2f}'} | "
            f"{'-' if src is None else f'{src[0]:.0f}, {src[1]:.0f}'} | "
            f"{e.get('end_reason') or '-'} |")
    return "\n".join(rows)
