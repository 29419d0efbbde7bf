"""The appliance daemon: starts and stops every part of a run in order.

Data flow (docs/design.md)::

    camera L thread --Frame--\\                        /--> recorder thread (every raw frame,
    camera R thread --Frame---> pairing thread ------+        every wind sample, pair, result)
    anemometer reader --WindSample--> wind history --+--> ring buffer --> worker processes
                                                     \\<------ results thread <-----------/
                                                      --> live view thread (drops when full)
                                                      --> operator page (own thread, drops)

Acquisition and recording never wait: camera threads hand frames to the pairing thread
through a bounded queue and to the recorder's own queue (both drop and count when full,
which they never are in normal operation); the pairing thread writes pairs into the
shared-memory ring, which overwrites the oldest slot instead of waiting; workers take the
newest consecutive windows and count what they skipped; the live view has its own small
queue that drops when full; so has the operator's page, and each of its browsers.

Where each box lives: camera and pairing threads and the raw wind recording in
``runtime.acquisition``; the worker pool (ring, worker processes, results thread) in
``runtime.pool``, each worker in ``runtime.workers``; ring in ``runtime.ring``; the stereo
geometry in ``runtime.site_geometry``; signals in ``runtime.signals``; result
publishing in ``runtime.publishing``; recorder in ``recording.recorder`` (started by
``runtime.recorder_start``); live view in ``live.view``; the operator's page in ``page``;
health in ``runtime.health``; the simulated site in ``runtime.simsite``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Any

import numpy as np

from appliance.config import Config
from appliance.exitcodes import EXIT_FAILURE, EXIT_OK
from appliance.live.fanout import views_of
from appliance.live.view import LiveView
from appliance.memory import PeriodicTrim
from appliance.runtime.acquisition import Acquisition, Counters, camera_watch, nominal_frame_rate_hz
from appliance.runtime.banner import announce_end, announce_start
from appliance.runtime.counters import health_counters
from appliance.runtime.emission_setup import emission_setup
from appliance.runtime.gas_temperature import GateTemperature, configured_gas_temperature_k
from appliance.runtime.health import (
    HealthMonitor,
    HealthReporter,
    disk_free_source,
    live_sink,
    log_sink,
    mcap_sink,
)
from appliance.runtime.keepup import KeepUpCheck, StageTimes, keep_up_advice, peak_rss_mb
from appliance.runtime.metrics import metrics_text
from appliance.runtime.monitor import monitor_from_config
from appliance.runtime.page_service import start_page, stop_page
from appliance.runtime.pool import WorkerPool
from appliance.runtime.publishing import ResultPublisher
from appliance.runtime.recorder_start import start_recorder
from appliance.runtime.sdnotify import SdNotifier, Watchdog, watchdog_period_s
from appliance.runtime.signals import SignalLatch
from appliance.runtime.simsite import SimulatedSite
from appliance.runtime.single_camera import probe_image_size
from appliance.runtime.site_geometry import check_radiometry, site_geometry
from appliance.runtime.worker_result import WorkerResult
from appliance.threads import NamedThread
from drivers.anemometer.history import WindHistory
from drivers.anemometer.mounting import Mounting
from processing.chain import StereoGeometry

log = logging.getLogger("ogiflow")

SIDES = ("left", "right")


class Appliance:
    """One run of the appliance (``ogiflow run`` and the systemd service).

    Parameters
    ----------
    cfg : Config
        Validated configuration.
    duration_s : float or None
        Stop after this many seconds (None: until SIGTERM/SIGINT).
    announce : bool
        Tell the user on stderr what runs where, and print a final summary.
    """

    def __init__(self, cfg: Config, *, duration_s: float | None = None,
                 announce: bool = False) -> None:
        self.cfg = cfg
        self.duration_s = duration_s
        self.announce = announce
        self.stop_event = threading.Event()
        #: SIGTERM/SIGINT, taken by the main thread's wait loop.
        self.signals = SignalLatch(self.stop_event)
        self.counters = Counters()
        self._threads: list[threading.Thread] = []
        self._t_wall0 = time.time_ns() - time.monotonic_ns()
        self.recorder: Any = None
        self.clips: Any = None
        self.monitor: Any = None
        self.live: Any = None
        self.ring: Any = None
        self.pool: Any = None
        self.site: SimulatedSite | None = None
        self.acquisition: Any = None
        self.watch: Any = None  # which cameras deliver (runtime.degraded.CameraWatch)
        self.history: Any = None
        self.geometry: StereoGeometry | None = None
        #: (W, H) of the images (the ring's slots, the zones).
        self.image_size: tuple[int, int] = (0, 0)
        self.live_url: str | None = None
        #: The operator's page (``live.page``): its hub and HTTP server.
        self.page_hub: Any = None
        self.page_server: Any = None
        #: Faults that end the run with exit code 1 (a thread died, files not finalised).
        self.failures: list[str] = []
        self._keep_up = KeepUpCheck()
        self.stage_times = StageTimes()
        #: Peak resident memory of the daemon and each worker, MB (filled at shutdown).
        self.peak_rss_mb: list[float | None] = []
        self.t_start = time.monotonic()

    # ------------------------------------------------------------------ helpers

    def wall_ns(self, mono_ns: int) -> int:
        """Wall-clock UNIX ns of a host monotonic time (offset fixed at start)."""
        return int(mono_ns + self._t_wall0)

    # ------------------------------------------------------------------ set-up

    def _handle_result(self, res: WorkerResult) -> None:
        self.counters.skipped_pairs += res.skipped
        self.health.latency("processing").add((res.done_mono_ns - res.t_mono_ns[2]) / 1e6)
        self.health.stream("results").tick()
        if res.skipped:
            self.health.stream("skipped").tick(res.skipped)  # skipped triples per second
        if res.error is None and res.timings_ms:
            self.stage_times.add(res.timings_ms)
        verdict = self._keep_up.observe(time.monotonic(), self.counters.results + 1,
                                        self.counters.skipped_pairs)
        if verdict is not None:
            where = self.stage_times.describe()
            (log.info if verdict[0] else log.warning)(
                "%s%s", verdict[1], "" if where is None else f"; {where}")
        if res.error is not None:
            self.counters.result_errors += 1
            log.warning("processing of pairs %s failed: %s", res.pair_indices, res.error)
        elif self.publisher.publish(res) is not None:
            self.counters.results += 1
            self.counters.cold_results += not res.warm and res.single_camera is None
            self.counters.single_results += res.single_camera is not None
            for side, levelled in zip(("left", "right"), res.offset_levelled, strict=True):
                self.counters.offset_steps[side] += levelled

    def _truth_for(self, pair_index0: int) -> np.ndarray | None:
        """Simulator ground truth of the triple starting at ``pair_index0`` (simulated runs)."""
        if self.site is None or self.acquisition is None:
            return None
        k0, k2 = self.acquisition.frame_ids(pair_index0, pair_index0 + 2)
        return self.site.true_velocity(k0, k2)

    def _true_rate_for(self, pair_index: int) -> float | None:
        """Simulator's true release rate (g/s) at the scene frame of pair ``pair_index``."""
        if self.site is None or self.site.truth is None or self.acquisition is None:
            return None
        (k,) = self.acquisition.frame_ids(pair_index)
        return None if k is None else self.site.truth.release_rate_g_s(k)

    # ------------------------------------------------------------------ run

    def run(self) -> int:
        """Run until the duration elapses or SIGTERM/SIGINT; every file is finalised.

        Each ``_start_*`` step registers its own teardown on one ExitStack, so whatever
        fails, everything started so far is released in reverse order: acquisition first
        (nothing new enters), then health, processing, live view, and the recorder last
        (it drains everything queued before it closes). The operator's page starts before
        everything (a busy port is a configuration error, exit 2, before any device opens)
        and stops after the final summary.

        Raises
        ------
        ConfigError
            ``live.page.port`` cannot be bound.
        """
        self._start_page()
        try:
            self._run()
            if self.announce:
                announce_end(self)
        finally:
            self._stop_page()
        for text in self.failures:
            log.error("run failed: %s", text)
        return EXIT_FAILURE if self.failures else EXIT_OK

    def _run(self) -> None:
        self.prepare()
        with contextlib.ExitStack() as stack:
            stack.callback(self.signals.restore)
            if self.site is not None:
                stack.callback(self.site.close)  # a background scene render
            self._start_recording(stack)
            self._start_live(stack)
            views = views_of(self.live, self.page_hub)  # Rerun view and operator's page
            self.monitor = self._make_monitor(stack, views)
            stack.callback(self.monitor.close)
            self.publisher = ResultPublisher(
                self.recorder, views, self.wall_ns, self.cfg.recording.fields_every,
                wind_at=self.history.at,
                truth_for=self._truth_for if self.site.truth is not None else None,
                monitor=self.monitor, rate_window_s=self.cfg.events.rate_window_s,
                true_rate_for=self._true_rate_for if self.site.truth is not None else None)
            self._start_processing(stack)
            self._start_health(stack)
            self._start_acquisition(stack)
            stack.callback(self._begin_shutdown)
            self.signals.install()
            self.notifier.ready(f"acquiring; live view: {self.live_url or 'off'}")
            if self.announce:
                announce_start(self)
            self._wait()

    def prepare(self, *, full_scene: bool = False) -> None:
        """Health, watchdog, wind history, simulated site, geometry and chain parameters."""
        cfg = self.cfg
        self.health = HealthMonitor(cfg.health.stall_s)
        self.watch = camera_watch(cfg, self.wall_ns)
        self.health.watch_cameras(self.watch)  # the first status already says the mode
        self.notifier = SdNotifier()
        period = watchdog_period_s() if cfg.health.watchdog else None
        self.watchdog = Watchdog(self.notifier, period, cfg.health.stall_s) if period else None
        self._mounting = Mounting.from_config(cfg.anemometer.protocol, cfg.anemometer.mounting)
        # Results need the wind of their pair's time, seconds to a minute back: 6000 samples
        # (5 min at 20 Hz) is plenty and keeps the history's memory flat (~1 MB) within
        # minutes; the default 20 000 (40 000 between trims) took 33 min to level off.
        self.history = WindHistory(capacity=6000)
        self.site = SimulatedSite(cfg, self._mounting.rotation)
        self.site.prepare(full=full_scene)
        self.geometry = site_geometry(cfg, self.site)
        self.image_size = (self.geometry.image_size if self.geometry is not None
                           else probe_image_size(cfg, self.site))  # a single-camera site
        defaults = ({} if self.geometry is None else
                    self.site.chain_defaults(self.geometry.camera_constant,
                                             self.geometry.baseline))
        self.params = cfg.processing.chain_parameters(defaults, site=True)
        self.gate = (GateTemperature(configured_gas_temperature_k(cfg, self.site.truth))
                     if cfg.processing.opaque_gate else None)
        if self.gate is not None:  # at the start's temperature; each worker follows it
            self.params = self.gate.parameters(self.params)
        check_radiometry(self.params, self.geometry)
        self._keep_up.advice = keep_up_advice(self.image_size, self.params.binning,
                                              rendering=self.site.background is not None)
        self.emission = emission_setup(cfg, self.site.truth)

    def _start_recording(self, stack: contextlib.ExitStack) -> None:
        if not self.cfg.recording.enabled:
            return
        self.recorder, self.clips = start_recorder(self.cfg, self.geometry, self.params,
                                                   self.emission, stack)
        stack.callback(self._close_recorder)

    def _start_live(self, stack: contextlib.ExitStack) -> None:
        if self.cfg.live.mode == "off":
            return

        self.live = LiveView(self.cfg.live,
                             server_memory_limit=f"{self.cfg.live.server_memory_mb}MB",
                             max_image_hz=self.cfg.live.max_image_hz).start()
        stack.callback(self.live.close)
        self.live_url = getattr(self.live, "url", None)

    def _start_processing(self, stack: contextlib.ExitStack) -> None:
        """The shared-memory ring, the worker processes and the thread that takes results."""
        self.pool = WorkerPool(self.cfg, self.geometry, self.image_size, self.params,
                               self.emission, self._handle_result,
                               self.counters, self.gate).start(stack, self._spawn)
        self.ring = self.pool.ring
        self.publisher.fields_wanted = self.pool.fields_wanted
        stack.callback(self._note_peak_rss)  # runs before the pool stops its workers

    def _note_peak_rss(self) -> None:
        self.peak_rss_mb = [peak_rss_mb(None), *self.pool.worker_peak_rss_mb()]

    def _start_page(self) -> None:
        """The operator's page (``live.page``): its hub and HTTP server."""
        self.page_hub, self.page_server = start_page(
            self.cfg.live.page, clock=lambda: self.wall_ns(time.monotonic_ns()),
            metrics=lambda: metrics_text(self))

    def _stop_page(self) -> None:
        stop_page(self.page_hub, self.page_server)

    def _make_monitor(self, stack: contextlib.ExitStack, views: Any) -> Any:
        assert self.site is not None
        return monitor_from_config(self.cfg, self.image_size, stack, live=views,
                                   on_event=self._on_event,
                                   true_rate_g_s=self.site.shown_true_rate_g_s(),
                                   nominal_fps=nominal_frame_rate_hz(self.cfg))

    def _on_event(self, kind: str, event: dict[str, Any]) -> dict[str, Any] | None:
        """A leak event changed: record it, and keep its raw frames as a clip (whose folder
        is returned for the event's messages and the operator's list)."""
        self.publisher.record_event(kind, event)
        if self.clips is None:
            return None
        if kind == "start":
            folder = self.clips.event_started(int(event["id"]), float(event["start_t_s"]),
                                              event)
            return {"clip": str(folder)}
        if kind == "end":
            self.clips.event_ended(int(event["id"]), float(event["end_t_s"] or
                                                           event["start_t_s"]), event)
        return None

    def _start_health(self, stack: contextlib.ExitStack) -> None:
        sinks = [log_sink()]
        if self.recorder is not None:
            sinks.append(mcap_sink(self.recorder))
        if self.live is not None:
            sinks.append(live_sink(self.live))
        sinks.append(self.monitor.on_health)
        if self.clips is not None:
            sinks.append(lambda _snap: self.clips.poll())  # link newly closed raw files
        self.health.add_counters(self._health_counters)
        if self.cfg.recording.enabled:
            self.health.add_gauges(disk_free_source(self.cfg.recording.dir))
        reporter = HealthReporter(self.health, self.cfg.health.interval_s, sinks,
                                  self.notifier, self.watchdog).start()
        stack.callback(reporter.stop)

    def _start_acquisition(self, stack: contextlib.ExitStack) -> None:
        """Anemometer, pairing thread and camera threads (the anemometer starts once the
        recorder and publisher exist, so every sample it delivers is recorded)."""
        assert self.site is not None
        self.acquisition = Acquisition(
            self.cfg, self.counters, self.health, self.stop_event, self.wall_ns, self.site,
            recorder=self.recorder, publisher=self.publisher, ring=self.ring,
            watchdog=self.watchdog, watch=self.watch, pictures=self.page_hub)
        self.acquisition.sonic_k = self.pool.sonic_k
        reader = self.acquisition.start_anemometer(self.history, self._mounting)
        stack.callback(reader.stop, timeout=1.0)
        self._spawn(self.acquisition.pairing_loop, "pairing")
        for side in SIDES:
            if getattr(self.cfg.cameras, side) is not None:
                self._spawn(self.acquisition.camera_loop, f"camera-{side}", side)
        stack.callback(self._join_acquisition)

    # ------------------------------------------------------------------ teardown

    def _begin_shutdown(self) -> None:
        self.notifier.stopping()
        self.stop_event.set()

    def _join_acquisition(self) -> None:
        for t in self._threads:
            if t.name.startswith("camera") or t.name == "pairing":
                t.join(timeout=2.0)

    def _close_recorder(self) -> None:
        if not self.recorder.close(timeout=5.0):
            self.failures.append("the recorder did not finish its files within 5 s")

    # ------------------------------------------------------------------ waiting

    def _wait(self) -> None:
        t_end = None if self.duration_s is None else time.monotonic() + self.duration_s
        trim = PeriodicTrim()
        while not self.stop_event.is_set():
            timeout = 0.2 if t_end is None else max(0.0, min(0.2, t_end - time.monotonic()))
            self.stop_event.wait(timeout)
            self.signals.take()
            self.pool.supervise(self.stop_event.is_set())
            trim.tick()
            if t_end is not None and time.monotonic() >= t_end:
                break

    def _spawn(self, target: Any, name: str, *args: Any) -> threading.Thread:
        t = NamedThread(target=self._guarded, name=name, args=(target, name, *args),
                        daemon=True)
        t.start()
        self._threads.append(t)
        return t

    def _guarded(self, target: Any, name: str, *args: Any) -> None:
        """Run a thread's loop; an exception escaping it stops the run with exit code 1
        (systemd restarts the service) instead of leaving a half-working appliance."""
        try:
            target(*args)
        except BaseException as exc:
            log.exception("thread %s died", name)
            self.failures.append(f"thread {name} died: {type(exc).__name__}: {exc}")
            self.stop_event.set()

    def _health_counters(self) -> dict[str, int]:
        return health_counters(self)

