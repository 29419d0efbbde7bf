"""Health of the running appliance: rates, drops, latencies, counters, gauges, stall state.

Producers update cheap counters (one owner thread per :class:`StreamCounter` /
:class:`LatencyStat`; :meth:`HealthMonitor.count` takes a lock). Parts that keep their own
counters (recorder, ring, serial drivers, live view) are registered as *sources*: callables
returning ``{name: number}`` read at each snapshot. :class:`HealthReporter` takes a
:class:`HealthSnapshot` every ``health.interval_s`` and hands it to sinks (MCAP, live view, a
stderr line for journald) and drives the systemd watchdog and ``STATUS=`` line.
"""

from __future__ import annotations

import datetime
import logging
import math
import shutil
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from appliance.live.view import health_scalars
from appliance.recording.schemas import HEALTH, encode_json
from appliance.runtime.sdnotify import SdNotifier, Watchdog
from appliance.threads import NamedThread

__all__ = [
    "HealthMonitor",
    "HealthReporter",
    "HealthSnapshot",
    "LatencyStat",
    "StreamCounter",
    "StreamStats",
    "alarms",
    "camera_words",
    "disk_free_source",
    "live_sink",
    "log_sink",
    "mcap_sink",
    "status_line",
]

log = logging.getLogger("ogiflow.health")

#: A camera stream without frames for longer than this is named in the status line, s.
SILENT_S = 1.0


class StreamCounter:
    """Items and drops of one stream (frames of a camera, wind samples, pairs, results).

    Update from one thread (the stream's owner); read by the health thread.
    """

    def __init__(self) -> None:
        self.count = 0
        self.drops = 0
        self.last_mono: float | None = None
        self._snap_count = 0
        self._snap_time: float | None = None

    def tick(self, n: int = 1, now: float | None = None) -> None:
        """``n`` items arrived (monotonic seconds ``now``)."""
        self.count += n
        self.last_mono = time.monotonic() if now is None else now

    def drop(self, n: int = 1) -> None:
        """``n`` items were lost or skipped."""
        self.drops += n

    def rate(self, now: float) -> float:
        """Items per second since the previous call (the first call counts from creation)."""
        prev_t = self._snap_time
        prev_n = self._snap_count
        self._snap_time, self._snap_count = now, self.count
        if prev_t is None or now <= prev_t:
            return 0.0
        return (self.count - prev_n) / (now - prev_t)


class LatencyStat:
    """Latencies of one kind (ms); mean and max over each snapshot interval."""

    def __init__(self) -> None:
        self.count = 0
        self._sum = 0.0
        self._max = 0.0
        self._n = 0

    def add(self, ms: float) -> None:
        """One latency in milliseconds."""
        self.count += 1
        self._n += 1
        self._sum += ms
        self._max = max(self._max, ms)

    def interval(self) -> tuple[float | None, float | None]:
        """(mean, max) since the previous call, None when nothing arrived; then reset."""
        n, s, m = self._n, self._sum, self._max
        self._n, self._sum, self._max = 0, 0.0, 0.0
        return (s / n, m) if n else (None, None)


@dataclass
class StreamStats:
    """One stream in a snapshot."""

    count: int
    rate_hz: float
    drops: int
    last_age_s: float | None


@dataclass
class HealthSnapshot:
    """State of the appliance at one time (matches the ``ogiflow.Health`` JSON schema)."""

    t_mono_ns: int
    t_wall_ns: int
    uptime_s: float
    streams: dict[str, StreamStats] = field(default_factory=dict)
    latencies: dict[str, dict[str, float | int | None]] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)
    gauges: dict[str, float | None] = field(default_factory=dict)
    stalled: bool = False
    #: ``stereo``, ``degraded`` (a camera of the pair lost) or ``single_camera``.
    mode: str = "stereo"
    #: Per camera: ``configured``, ``lost``, ``lost_since_wall_ns`` (UNIX ns of its last
    #: frame before the loss; None while it delivers).
    cameras: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (``appliance.recording.schemas.HEALTH``)."""
        return asdict(self)


def disk_free_source(path: Path) -> Callable[[], dict[str, float | None]]:
    """A gauge source reporting free disk space at ``path`` in GB (1e9 bytes)."""

    def read() -> dict[str, float | None]:
        p = Path(path)
        while not p.exists() and p != p.parent:
            p = p.parent  # the record dir may not exist yet
        try:
            return {"disk_free_gb": shutil.disk_usage(p).free / 1e9}
        except OSError:
            return {"disk_free_gb": None}

    return read


class HealthMonitor:
    """Registry of the appliance's health numbers; :meth:`snapshot` reads them all."""

    def __init__(self, stall_s: float = 10.0, frame_streams: tuple[str, ...] = (
            "cam/left", "cam/right"), clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock  # monotonic seconds (tests inject one)
        self._start = clock()
        self.stall_s = stall_s
        self.frame_streams = frame_streams
        self._streams: dict[str, StreamCounter] = {}
        self._latencies: dict[str, LatencyStat] = {}
        self._counters: dict[str, int] = {}
        self._counter_sources: list[Callable[[], Mapping[str, int]]] = []
        self._gauge_sources: list[Callable[[], Mapping[str, float | None]]] = []
        self._cameras: Any = None
        self._lock = threading.Lock()

    def stream(self, name: str) -> StreamCounter:
        """The counter of stream ``name`` (created on first use; keep the object)."""
        with self._lock:
            return self._streams.setdefault(name, StreamCounter())

    def latency(self, name: str) -> LatencyStat:
        """The latency statistic ``name`` (created on first use)."""
        with self._lock:
            return self._latencies.setdefault(name, LatencyStat())

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to counter ``name`` (thread-safe)."""
        with self._lock:
            self._counters[name] = self._counters.get(name, 0) + n

    def add_counters(self, source: Callable[[], Mapping[str, int]]) -> None:
        """Register a callable returning counters (e.g. serial errors, recorder drops)."""
        self._counter_sources.append(source)

    def add_gauges(self, source: Callable[[], Mapping[str, float | None]]) -> None:
        """Register a callable returning gauges (e.g. ring occupancy, disk free)."""
        self._gauge_sources.append(source)

    def watch_cameras(self, watch: Any) -> None:
        """Report which cameras deliver (a :class:`~appliance.runtime.degraded.CameraWatch`)."""
        self._cameras = watch

    def last_frame_age(self, now: float) -> float | None:
        """Seconds since the newest frame of any camera stream (None: none yet)."""
        times = [s.last_mono for n, s in self._streams.items()
                 if n in self.frame_streams and s.last_mono is not None]
        return now - max(times) if times else None

    def snapshot(self) -> HealthSnapshot:
        """Read everything; rates and latency means are over the time since the last call."""
        now = self._clock()
        snap = HealthSnapshot(t_mono_ns=time.monotonic_ns(), t_wall_ns=time.time_ns(),
                              uptime_s=now - self._start)
        with self._lock:
            streams = dict(self._streams)
            lats = dict(self._latencies)
            snap.counters = dict(self._counters)
        for name, s in streams.items():
            age = None if s.last_mono is None else now - s.last_mono
            snap.streams[name] = StreamStats(s.count, s.rate(now), s.drops, age)
        for name, lat in lats.items():
            mean, mx = lat.interval()
            snap.latencies[name] = {"count": lat.count, "mean_ms": mean, "max_ms": mx}
        for src in self._counter_sources:
            try:
                snap.counters.update({k: int(v) for k, v in src().items()})
            except Exception as exc:  # a broken source must not stop health reporting
                log.warning("health counter source %r failed: %s", src, exc)
        for src in self._gauge_sources:
            try:
                for k, v in src().items():
                    snap.gauges[k] = None if v is None or not math.isfinite(v) else float(v)
            except Exception as exc:
                log.warning("health gauge source %r failed: %s", src, exc)
        if self._cameras is not None:
            snap.mode, snap.cameras = self._cameras.mode, self._cameras.status()
        age = self.last_frame_age(now)
        snap.stalled = (now - self._start if age is None else age) > self.stall_s
        return snap


def camera_words(snap: HealthSnapshot) -> list[str]:
    """``DEGRADED: right camera lost since 01:02:03 UTC, single-camera chain on the left``
    while a camera of the pair is lost (empty otherwise)."""
    if snap.mode != "degraded":
        return []
    out = []
    alive = [s for s, c in snap.cameras.items() if c.get("configured") and not c.get("lost")]
    for side, c in sorted(snap.cameras.items()):
        if not c.get("lost"):
            continue
        since = c.get("lost_since_wall_ns")
        when = "" if since is None else " since " + datetime.datetime.fromtimestamp(
            since / 1e9, datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
        rest = (f", single-camera chain on the {alive[0]}" if len(alive) == 1
                else ", no camera delivers")
        out.append(f"DEGRADED: {side} camera lost{when}{rest}")
    return out


def alarms(snap: HealthSnapshot) -> list[str]:
    """What is wrong right now, most serious first (empty when all is well)."""
    out = []
    if snap.stalled:
        out.append("STALLED: no frames")
    out.extend(camera_words(snap))
    if snap.counters.get("recording_paused"):
        out.append("RECORDING PAUSED (write error; see log)")
    for name, s in sorted(snap.streams.items()):
        if name.startswith("cam/") and s.last_age_s is not None and s.last_age_s > SILENT_S:
            out.append(f"{name} SILENT for {s.last_age_s:.0f} s")
    return out


def status_line(snap: HealthSnapshot) -> str:
    """One short human line (systemd STATUS=, journal): alarms first, then rates."""
    parts = alarms(snap)
    if snap.mode == "single_camera":
        parts.append("single camera")
    for name, s in sorted(snap.streams.items()):
        drops = f" ({s.drops} lost)" if s.drops else ""
        parts.append(f"{name} {s.rate_hz:.1f}/s{drops}")
    for key in ("skipped_pairs", "recorder_drops", "live_drops", "serial_errors",
                "frames_lost_left", "frames_lost_right", "worker_restarts"):
        if snap.counters.get(key):
            parts.append(f"{key} {snap.counters[key]}")
    free = snap.gauges.get("disk_free_gb")
    if free is not None:
        parts.append(f"disk {free:.1f} GB free")
    return ", ".join(parts) or "starting"


class HealthReporter:
    """Thread that snapshots health every ``interval_s`` and feeds sinks and systemd.

    Parameters
    ----------
    monitor
        What to read.
    interval_s
        Seconds between snapshots.
    sinks
        Callables taking each :class:`HealthSnapshot` (record to MCAP, push to the live view,
        log to stderr). A failing sink is logged and skipped.
    notifier, watchdog
        systemd notification; the watchdog is ticked several times per ping period and told
        of frames by the acquisition code (``watchdog.frame_arrived()``).
    """

    def __init__(self, monitor: HealthMonitor, interval_s: float,
                 sinks: list[Callable[[HealthSnapshot], None]] | None = None,
                 notifier: SdNotifier | None = None, watchdog: Watchdog | None = None) -> None:
        self.monitor = monitor
        self.interval_s = interval_s
        self.sinks = list(sinks or [])
        self.notifier = notifier
        self.watchdog = watchdog
        self.last: HealthSnapshot | None = None
        self._stop = threading.Event()
        self._thread = NamedThread(target=self._run, name="health", daemon=True)

    def start(self) -> HealthReporter:
        """Start the thread."""
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (no final snapshot)."""
        self._stop.set()
        self._thread.join(timeout)

    def _run(self) -> None:
        step = self.interval_s
        if self.watchdog is not None and self.watchdog.period_s is not None:
            step = min(step, self.watchdog.period_s / 4)
        next_snap = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if self.watchdog is not None:
                self.watchdog.tick(now)
            if now >= next_snap:
                next_snap = now + self.interval_s
                self.report()
            self._stop.wait(max(0.01, min(step, next_snap - time.monotonic())))

    def report(self) -> HealthSnapshot:
        """Take one snapshot now and hand it to the sinks and systemd."""
        snap = self.monitor.snapshot()
        self.last = snap
        for sink in self.sinks:
            try:
                sink(snap)
            except Exception as exc:  # health must keep running whatever a sink does
                log.warning("health sink %r failed: %s", sink, exc)
        if self.notifier is not None:
            self.notifier.status(status_line(snap))
        return snap


# --------------------------------------------------------------------------- ready-made sinks


def mcap_sink(recorder: Any, topic: str = "/health") -> Callable[[HealthSnapshot], None]:
    """Sink recording each snapshot as ``ogiflow.Health`` JSON through ``recorder.record``."""
    def sink(snap: HealthSnapshot) -> None:
        recorder.record(topic, HEALTH, encode_json(HEALTH, snap.to_dict()), snap.t_wall_ns)

    return sink


def live_sink(view: Any) -> Callable[[HealthSnapshot], None]:
    """Sink pushing each snapshot's numbers to the live view (``health/...`` plots)."""
    def sink(snap: HealthSnapshot) -> None:
        view.push(health_scalars(snap))

    return sink


def log_sink(logger: logging.Logger = log, every: int = 10) -> Callable[[HealthSnapshot], None]:
    """Sink writing :func:`status_line` to the log (journald) every ``every`` snapshots, and at
    once whenever :func:`alarms` starts or stops having something to say."""
    state: dict[str, Any] = {"n": 0, "stalled": False, "mode": None}

    def sink(snap: HealthSnapshot) -> None:
        line = status_line(snap)
        # At once when something starts or stops being wrong (an outage, a paused recording)
        # and when a camera is lost or back (the mode changes).
        alarm = bool(alarms(snap))
        changed = alarm != state["stalled"] or snap.mode != state["mode"]
        state["stalled"], state["mode"] = alarm, snap.mode
        if changed or state["n"] % every == 0:
            (logger.warning if alarm else logger.info)("health: %s", line)
        state["n"] += 1

    return sink
