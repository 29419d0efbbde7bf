"""The appliance daemon: devices, pairing, ring buffer, workers, recorder, live view, health.

Data flow (DESIGN.md)::

    camera L thread --Frame--\\                        /--> recorder thread (every raw frame,
    camera R thread --Frame---> pairing thread ------+        every wind sample, pair, result)
    anemometer reader --WindSample--> wind history --+--> ring buffer --> worker processes
                                                     \\<------ results thread <-----------/
                                                      --> live view thread (drops when full)

Acquisition and recording never wait: camera threads hand frames to the pairing thread
through a bounded queue and to the recorder's own queue (both drop and count when full,
which they never are in normal operation); the pairing thread writes pairs into the
shared-memory ring, which overwrites the oldest slot instead of waiting; workers take the
newest consecutive windows and count what they skipped; the live view has its own small
queue that drops when full.
"""

from __future__ import annotations

import collections
import logging
import multiprocessing as mp
import queue
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from appliance.config import Config
from appliance.recording import schemas
from appliance.runtime.keepup import KeepUpCheck
from appliance.runtime.publishing import ResultPublisher
from appliance.runtime.stamping import StereoStamper
from appliance.runtime.workers import WorkerResult, worker_main
from processing.chain import ChainParameters, StereoGeometry

log = logging.getLogger("ogiflow")

SIDES = ("left", "right")
#: Mean wind of the simulated anemometer when the config gives none, in Gill axes (U toward
#: the north mark, V to its left, W up): with the default mounting (north mark along the
#: optical axis) this is 1.5 m/s to the camera's right and 0.3 m/s away from it, a wind the
#: stereo system sees mostly in the image plane, as in the paper's field test.
SIMULATED_MEAN_WIND = (0.3, -1.5, 0.0)
#: Exit codes of ``ogiflow run`` (also in the README).
EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2


@dataclass
class _Counters:
    """Counters shared by the daemon's threads (simple ints: the GIL makes += safe enough
    for statistics; nothing depends on exact values across threads)."""

    frames: dict[str, int] = field(default_factory=lambda: {s: 0 for s in SIDES})
    frame_queue_drops: int = 0
    camera_timeouts: int = 0
    camera_reconnects: int = 0
    pairs: int = 0
    results: int = 0
    result_errors: int = 0
    skipped_pairs: int = 0
    wind_samples: int = 0


def _peak_rss_mb(pid: int | None) -> float | None:
    """Peak resident memory (VmHWM) of a process in MB (None: this one); None if unknown.

    Read from /proc, not getrusage: a spawned child inherits its parent's ru_maxrss across
    fork and exec, which would report the daemon's peak for every worker.
    """
    try:
        text = Path(f"/proc/{pid or 'self'}/status").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024  # kB
    return None


class Appliance:
    """One run of the appliance (``ogiflow run`` and the systemd service).

    Parameters
    ----------
    cfg : Config
        Validated configuration.
    duration_s : float or None
        Stop after this many seconds (None: until SIGTERM/SIGINT).
    """

    def __init__(self, cfg: Config, *, duration_s: float | None = None) -> None:
        self.cfg = cfg
        self.duration_s = duration_s
        self.stop_event = threading.Event()
        self.counters = _Counters()
        self._threads: list[threading.Thread] = []
        self._frame_q: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=512)
        self._pair_frame_ids: collections.OrderedDict[int, int | None] = collections.OrderedDict()
        self._pair_lock = threading.Lock()
        self._t_wall0 = time.time_ns() - time.monotonic_ns()
        self.recorder: Any = None
        self.live: Any = None
        self.ring: Any = None
        self.truth: Any = None
        self.history: Any = None
        self.geometry: StereoGeometry | None = None
        self.live_url: str | None = None
        self._keep_up = KeepUpCheck()

    # ------------------------------------------------------------------ helpers

    def wall_ns(self, mono_ns: int) -> int:
        """Wall-clock UNIX ns of a host monotonic time (offset fixed at start)."""
        return int(mono_ns + self._t_wall0)

    # ------------------------------------------------------------------ set-up

    def _simulated_scene(self, wind_camera: tuple[float, float, float]) -> Path | None:
        """Render (once) and return the scene folder when a camera is simulated."""
        from appliance.runtime.simsite import SceneTruth, ensure_scene

        cams = (self.cfg.cameras.left, self.cfg.cameras.right)
        if not any(c.backend == "simulated" and "source" not in c.options for c in cams):
            return None
        folder = ensure_scene(self.cfg.simulation, wind_camera)
        self.truth = SceneTruth(folder)
        return folder

    def _geometry(self, scene: Path | None) -> StereoGeometry:
        from processing.calibration import load_calibration

        if self.cfg.calibration is not None:
            return StereoGeometry.from_calibration(load_calibration(self.cfg.calibration))
        if self.truth is not None:
            return StereoGeometry.from_synthetic_camera(self.truth.camera)
        raise ValueError(
            "calibration: a stereo calibration file is required for real cameras "
            "(run `ogiflow calibrate stereo`, then set calibration: in the config)"
        )

    def _make_camera(self, side: str, scene: Path | None) -> Any:
        from drivers.camera.registry import create_camera

        cam_cfg = getattr(self.cfg.cameras, side)
        options = dict(cam_cfg.options)
        if cam_cfg.backend == "simulated":
            options.setdefault("side", side)
            options.setdefault("fps", cam_cfg.frame_rate_hz)
            if scene is not None:
                options.setdefault("source", str(scene))
            # The two cameras are not triggered together (paper Sec. 4.1).
            options.setdefault("phase_s", 0.0 if side == "left" else 0.004)
            options.setdefault("seed", 1 if side == "left" else 2)
        return create_camera(cam_cfg.backend, **options)

    # ------------------------------------------------------------------ threads

    def _camera_loop(self, side: str, scene: Path | None) -> None:
        """Grab frames of one camera forever; reconnect with back-off when it vanishes."""
        from drivers.camera import mcap_format
        from drivers.camera.base import CameraError, CameraTimeout, EndOfStream

        backoff = 0.5
        stream = self.health.stream(f"cam/{side}")
        cache: dict[str, schemas.MessageSchema] = {}
        while not self.stop_event.is_set():
            camera = None
            try:
                camera = self._make_camera(side, scene)
                camera.open()
                camera.start()
                backoff = 0.5
                while not self.stop_event.is_set():
                    try:
                        frame = camera.grab(timeout=0.5)
                    except CameraTimeout:
                        self.counters.camera_timeouts += 1
                        continue
                    stream.tick()
                    self.watchdog_frame()
                    self.counters.frames[side] += 1
                    if self.recorder is not None:
                        for m in mcap_format.frame_to_messages(side, frame,
                                                               self.wall_ns(frame.host_ns)):
                            schema = cache.get(m.schema_name)
                            if schema is None:
                                schema = schemas.MessageSchema(m.schema_name, m.schema_encoding,
                                                               m.schema_data, m.message_encoding)
                                cache[m.schema_name] = schema
                            self.recorder.record(m.topic, schema, m.data, m.log_time,
                                                 m.publish_time)
                    try:
                        self._frame_q.put_nowait((side, frame))
                    except queue.Full:
                        self.counters.frame_queue_drops += 1
            except EndOfStream:
                log.info("camera %s: end of stream", side)
                return
            except (CameraError, OSError, ValueError) as exc:
                if self.stop_event.is_set():
                    break
                self.counters.camera_reconnects += 1
                log.warning("camera %s: %s; reconnecting in %.1f s", side, exc, backoff)
                self.stop_event.wait(backoff)
                backoff = min(backoff * 2, 10.0)
            finally:
                if camera is not None:
                    try:
                        camera.close()
                    except (CameraError, OSError):
                        pass

    def watchdog_frame(self) -> None:
        if self.watchdog is not None:
            self.watchdog.frame_arrived()

    def _pairing_loop(self) -> None:
        """Stamp frames (clock model per camera), pair them, write pairs to the ring."""
        stamper = StereoStamper(self.cfg.cameras.left.frame_rate_hz, self.cfg.pairing.tolerance_s)
        stream = self.health.stream("pairs")
        index = 0
        while True:
            try:
                side, frame = self._frame_q.get(timeout=0.05)
            except queue.Empty:
                if self.stop_event.is_set():
                    break
                pairs = stamper.poll(time.monotonic_ns())
            else:
                pairs = stamper.push(side, frame, time.monotonic_ns())
            for p in pairs:
                self._write_pair(index, p)
                stream.tick()
                index += 1
        self.unpaired = stamper.unpaired()

    def _write_pair(self, index: int, p: Any) -> None:
        left, right = p.left, p.right
        self.ring.write(left.image, right.image, pair_index=index, left_seq=left.seq,
                        right_seq=right.seq, t_left_mono_ns=p.left_ns, t_right_mono_ns=p.right_ns,
                        t_wall_ns=self.wall_ns(p.time_ns))
        self.counters.pairs += 1
        with self._pair_lock:
            self._pair_frame_ids[index] = left.device_frame_id
            while len(self._pair_frame_ids) > 4 * self.cfg.ring.capacity + 64:
                self._pair_frame_ids.popitem(last=False)
        self.publisher.record_pair(index, p)

    def _on_wind(self, sample: Any) -> None:
        """Reader-thread callback: record the raw sample (never blocks)."""
        self.counters.wind_samples += 1
        self.health.stream("wind").tick()
        self.publisher.record_json("/wind/raw", schemas.WIND_SAMPLE, {
            "t_mono_ns": sample.host_ns, "t_wall_ns": self.wall_ns(sample.host_ns),
            "t_device": sample.counter, "sensor": self.cfg.anemometer.protocol,
            "u": _finite(sample.u), "v": _finite(sample.v), "w": _finite(sample.w),
            "speed_of_sound_m_s": _finite_or_none(sample.speed_of_sound),
            "sonic_temperature_c": _finite_or_none(sample.sonic_temperature),
            "status": sample.status_code, "valid": bool(sample.valid),
        }, sample.host_ns)

    def _results_loop(self, results: Any) -> None:
        while True:
            try:
                res: WorkerResult = results.get(timeout=0.1)
            except queue.Empty:
                if self.stop_event.is_set() and self._workers_done.is_set():
                    break
                continue
            try:
                self._handle_result(res)
            except Exception:
                log.exception("result of pair %s could not be handled", res.pair_indices)

    def _handle_result(self, res: WorkerResult) -> None:
        self.counters.skipped_pairs += res.skipped
        self.health.latency("processing").add((res.done_mono_ns - res.t_mono_ns[2]) / 1e6)
        self.health.stream("results").tick()
        if res.skipped:
            self.health.stream("skipped").tick(res.skipped)  # skipped triples per second
        verdict = self._keep_up.observe(time.monotonic(), self.counters.results + 1,
                                        self.counters.skipped_pairs)
        if verdict is not None:
            (log.info if verdict[0] else log.warning)("%s", verdict[1])
        if res.error is not None:
            self.counters.result_errors += 1
            log.warning("processing of pairs %s failed: %s", res.pair_indices, res.error)
        elif self.publisher.publish(res) is not None:
            self.counters.results += 1

    def _truth_for(self, pair_index0: int) -> np.ndarray | None:
        """Simulator ground truth of the triple starting at ``pair_index0`` (simulated runs)."""
        if self.truth is None:
            return None
        with self._pair_lock:
            k0 = self._pair_frame_ids.get(pair_index0)
            k2 = self._pair_frame_ids.get(pair_index0 + 2)
        if k0 is None or k2 is None or k2 - k0 != 2:
            return None  # a dropped frame: the triple is not three consecutive scene frames
        return self.truth.mean_velocity(k0)

    # ------------------------------------------------------------------ run

    def run(self) -> int:
        from appliance.runtime.health import (
            HealthMonitor,
            HealthReporter,
            disk_free_source,
            live_sink,
            log_sink,
            mcap_sink,
        )
        from appliance.runtime.sdnotify import SdNotifier, Watchdog, watchdog_period_s

        cfg = self.cfg
        self.health = HealthMonitor(cfg.health.stall_s)
        notifier = SdNotifier()
        period = watchdog_period_s() if cfg.health.watchdog else None
        self.watchdog = Watchdog(notifier, period, cfg.health.stall_s) if period else None
        self.unpaired = {s: 0 for s in SIDES}

        from drivers.anemometer.history import WindHistory
        from drivers.anemometer.mounting import Mounting

        self._mounting = Mounting.from_config(cfg.anemometer.protocol, cfg.anemometer.mounting)
        self.history = WindHistory()
        wind_cam = self._mean_simulated_wind()
        scene = self._simulated_scene(wind_cam)
        self.geometry = self._geometry(scene)
        sim_defaults: dict[str, Any] = {}
        if scene is not None:
            # The synthetic scene has no jitter and a featureless background (the paper's
            # ideal conditions): registration could only lock onto the gas. The minimum
            # disparity d0 is that of twice the plume distance.
            s_px, b_m = self.geometry.camera_constant, self.geometry.baseline
            sim_defaults = {"register": False,
                            "d0": s_px * b_m / (2.0 * cfg.simulation.distance_m)}
        params = ChainParameters.from_mapping({**sim_defaults, **cfg.processing.parameters})

        # Everything created from here on is released in the finally block, whatever fails.
        reader = reporter = None
        workers: list[Any] = []
        stop_workers: Any = None
        previous: dict[int, Any] = {}
        self._workers_done = threading.Event()
        try:
            if cfg.recording.enabled:
                from appliance.recording.recorder import Recorder, file_metadata
                from appliance.recording.recovery import recover_unfinished

                cfg.recording.dir.mkdir(parents=True, exist_ok=True)
                for rep in recover_unfinished(cfg.recording.dir):
                    log.warning("recovered %s after a crash", rep)
                cal_text = (Path(cfg.calibration).read_text() if cfg.calibration is not None
                            else None)
                metadata = file_metadata(cfg, cal_text)
                metadata.update(processing_metadata(self.geometry, params))
                self.recorder = Recorder(cfg.recording, metadata).start()
            if cfg.live.mode != "off":
                from appliance.live.view import LiveView

                self.live = LiveView(cfg.live).start()
                self.live_url = getattr(self.live, "url", None)
            self.publisher = ResultPublisher(
                self.recorder, self.live, self.wall_ns, cfg.recording.fields_every,
                wind_at=self.history.at,
                truth_for=self._truth_for if self.truth is not None else None)

            from appliance.runtime.ring import PairRing

            w, h = self.geometry.image_size
            self.ring = PairRing.create(cfg.ring.capacity, (h, w), np.uint16)
            ctx = mp.get_context("spawn")
            results = ctx.Queue(maxsize=64)
            stop_workers = ctx.Event()
            if cfg.processing.enabled:
                for i in range(cfg.processing.workers):
                    p = ctx.Process(target=worker_main, name=f"ogiflow-worker-{i}",
                                    args=(i, self.ring.handle(), results, stop_workers,
                                          self.geometry, params, cfg.processing.workers),
                                    daemon=True)
                    p.start()
                    workers.append(p)
            else:
                self._workers_done.set()

            sinks = [log_sink()]
            if self.recorder is not None:
                sinks.append(mcap_sink(self.recorder))
            if self.live is not None:
                sinks.append(live_sink(self.live))
            self.health.add_counters(self._health_counters)
            if cfg.recording.enabled:
                self.health.add_gauges(disk_free_source(cfg.recording.dir))
            reporter = HealthReporter(self.health, cfg.health.interval_s, sinks, notifier,
                                      self.watchdog).start()

            # The anemometer starts once the recorder and publisher exist: every sample it
            # delivers is recorded.
            reader = self._start_anemometer()
            self._spawn(self._pairing_loop, "pairing")
            self._spawn(self._results_loop, "results", results)
            for side in SIDES:
                self._spawn(self._camera_loop, f"camera-{side}", side, scene)

            previous = {sig: signal.signal(sig, self._on_signal)
                        for sig in (signal.SIGTERM, signal.SIGINT)}
            notifier.ready(f"acquiring; live view: {self.live_url or 'off'}")
            if getattr(self, "_banner", False):
                import sys

                where = self.live_url or "off"
                rec = str(cfg.recording.dir) if cfg.recording.enabled else "off"
                sys.stderr.write(f"ogiflow: running. live view: {where}  recording: {rec}  "
                                 f"(Ctrl-C or SIGTERM stops)\n")
            t_end = None if self.duration_s is None else time.monotonic() + self.duration_s
            while not self.stop_event.is_set():
                timeout = 0.2 if t_end is None else max(0.0, min(0.2, t_end - time.monotonic()))
                self.stop_event.wait(timeout)
                if t_end is not None and time.monotonic() >= t_end:
                    break
        finally:
            notifier.stopping()
            self.stop_event.set()
            for t in self._threads:
                if t.name.startswith("camera") or t.name == "pairing":
                    t.join(timeout=2.0)
            if reader is not None:
                reader.stop(timeout=1.0)
            self._peak_rss_mb = [_peak_rss_mb(None), *(_peak_rss_mb(p.pid) for p in workers)]
            if stop_workers is not None:
                stop_workers.set()
            for p in workers:
                p.join(timeout=2.0)
                if p.is_alive():
                    p.terminate()
            self._workers_done.set()
            for t in self._threads:
                t.join(timeout=1.0)
            if reporter is not None:
                reporter.stop()
            if self.live is not None:
                self.live.close()
            if self.recorder is not None:
                self.recorder.close(timeout=5.0)
            if self.ring is not None:
                self.ring.close()
                self.ring.unlink()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return EXIT_OK

    def run_with_banner(self) -> int:
        """:meth:`run`, telling the user on stderr what runs where, and a final summary."""
        import sys

        self._banner = True
        t_start = time.monotonic()
        code = self.run()
        c = self.counters
        elapsed = max(time.monotonic() - t_start, 1e-9)
        share = c.results / max(c.results + c.skipped_pairs, 1)
        sys.stderr.write(
            f"ogiflow: stopped. frames {c.frames['left']}/{c.frames['right']} (left/right), "
            f"pairs {c.pairs}, processed {c.results} ({c.results / elapsed:.1f}/s, "
            f"{100 * share:.0f} %), skipped {c.skipped_pairs} "
            f"({c.skipped_pairs / elapsed:.1f}/s), failed {c.result_errors}, "
            f"wind samples {c.wind_samples}\n")
        peaks = getattr(self, "_peak_rss_mb", [])
        if peaks:
            sys.stderr.write("ogiflow: peak RSS (MB): " + ", ".join(
                f"{name} {'n/a' if mb is None else f'{mb:.0f}'}" for name, mb in zip(
                    ["daemon", *(f"worker {i}" for i in range(len(peaks) - 1))], peaks,
                    strict=True)) + "\n")
        comparison = self.publisher.truth_comparison()
        if comparison is not None:
            sys.stderr.write(
                "ogiflow: simulated ground truth vs measured mean gas velocity over "
                f"{comparison['frames']} valid frames: truth "
                f"{_fmt(comparison['truth_m_s'])} m/s, measured "
                f"{_fmt(comparison['measured_m_s'])} m/s, magnitude error "
                f"{comparison['magnitude_error_pct']:.1f} %, direction error "
                f"{comparison['direction_error_deg']:.1f} deg\n")
        return code

    def _spawn(self, target: Any, name: str, *args: Any) -> None:
        t = threading.Thread(target=target, name=name, args=args, daemon=True)
        t.start()
        self._threads.append(t)

    def _on_signal(self, signum: int, frame: Any) -> None:
        log.info("signal %d: shutting down", signum)
        self.stop_event.set()

    def _health_counters(self) -> dict[str, int]:
        c = self.counters
        out = {
            "frames_left": c.frames["left"], "frames_right": c.frames["right"],
            "pairs": c.pairs, "results": c.results, "result_errors": c.result_errors,
            "skipped_pairs": c.skipped_pairs, "frame_queue_drops": c.frame_queue_drops,
            "camera_timeouts": c.camera_timeouts, "camera_reconnects": c.camera_reconnects,
            "wind_samples": c.wind_samples,
        }
        if self.recorder is not None:
            out["recorder_drops"] = int(self.recorder.stats().messages_dropped)
        if self.live is not None:
            out["live_drops"] = int(self.live.stats().dropped)
        if self.ring is not None:
            out["ring_overwrites"] = int(self.ring.stats().overwrites)
        if getattr(self, "_anemometer", None) is not None:
            counts = self._anemometer.counts
            out["serial_errors"] = int(counts.checksum_failures + counts.malformed)
        return out

    # ------------------------------------------------------------------ anemometer

    def _start_anemometer(self) -> Any:
        from drivers.anemometer.reader import AnemometerReader
        from drivers.anemometer.registry import make_anemometer

        a = self.cfg.anemometer
        options = dict(a.options)
        if a.backend == "simulated":
            options.setdefault("mean_wind", SIMULATED_MEAN_WIND)
        if a.backend == "serial":
            options.setdefault("protocol", a.protocol)
            options.setdefault("url", a.port)
            options.setdefault("baudrate", a.baud)
            options.setdefault("parity", a.parity)
        self._anemometer = make_anemometer(a.backend, **options)
        return AnemometerReader(self._anemometer, on_sample=self._on_wind,
                                history=self.history, mounting=self._mounting).start()

    def _mean_simulated_wind(self) -> tuple[float, float, float]:
        """Mean wind in the camera frame that drives the simulated plume.

        The simulated anemometer's mean wind rotated by the site mounting, so the plume
        moves with the wind the anemometer reports; with a real anemometer and simulated
        cameras, 1.5 m/s to the right.
        """
        a = self.cfg.anemometer
        if a.backend != "simulated":
            return (1.5, 0.0, 0.0)
        sensor = np.asarray(a.options.get("mean_wind", SIMULATED_MEAN_WIND), dtype=np.float64)
        v = self._mounting.rotation @ sensor
        return (float(v[0]), float(v[1]), float(v[2]))


def processing_metadata(geometry: StereoGeometry, params: ChainParameters
                        ) -> dict[str, dict[str, str]]:
    """MCAP metadata records that let ``ogiflow replay`` reprocess a file as it was run:
    the geometry of Eq. 4 (``geometry``) and the chain parameters (``processing``)."""
    import dataclasses
    import json

    geo = {"camera_constant": geometry.camera_constant,
           "principal_point": list(geometry.principal_point), "baseline": geometry.baseline,
           "image_size": list(geometry.image_size),
           "rectified": geometry.maps_left is None and geometry.maps_right is None}
    return {"geometry": {"json": json.dumps(geo)},
            "processing": {"json": json.dumps(dataclasses.asdict(params), default=str)}}


def _fmt(v: Any) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def _finite(x: Any) -> float:
    v = float(x)
    return v if np.isfinite(v) else 0.0


def _finite_or_none(x: Any) -> float | None:
    if x is None:
        return None
    v = float(x)
    return v if np.isfinite(v) else None
