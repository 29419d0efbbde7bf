"""Acquisition: camera threads, stamping and pairing into the ring, raw wind recording.

Camera threads record every raw frame and hand it to the pairing thread through a
bounded queue (which drops and counts when full, which it never is in normal operation);
the pairing thread stamps frames (a clock model per camera), pairs them and writes pairs
into the shared-memory ring, which overwrites the oldest slot instead of waiting. Nothing
here ever waits for processing, the live view or an alarm sink.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appliance.config import Config
from appliance.recording import schemas
from appliance.runtime.clock import ClockModel
from appliance.runtime.degraded import CameraWatch
from appliance.runtime.simsite import SimulatedSite
from appliance.runtime.stamping import SIDES, StereoStamper
from drivers.anemometer.reader import AnemometerReader
from drivers.anemometer.registry import make_anemometer
from drivers.camera import mcap_format
from drivers.camera.base import CameraError, CameraTimeout, EndOfStream
from drivers.camera.registry import create_camera
from drivers.camera.replay_folder import folder_frame_rate_hz

log = logging.getLogger("ogiflow")

#: Reconnection back-off of a vanished camera, seconds (first try, cap): short, because
#: every moment spent waiting after the device is back loses its frames (with a 1 s cap a
#: 3 s outage lost 0.77 s more); an attempt is cheap (one open, or one GigE discovery on
#: the camera's own link) and blocks only this camera's thread.
RECONNECT_BACKOFF_S = (0.02, 0.1)
#: A camera that stays away is logged again every this many seconds, not at every attempt.
RECONNECT_LOG_EVERY_S = 10.0


def _per_side() -> dict[str, int]:
    return {s: 0 for s in SIDES}


@dataclass
class Counters:
    """Counters shared by the daemon's threads (simple ints: the GIL makes += safe enough
    for statistics; nothing depends on exact values across threads)."""

    frames: dict[str, int] = field(default_factory=_per_side)
    #: Frames the device numbered but never delivered (frame-id gaps, reconnections).
    frames_lost: dict[str, int] = field(default_factory=_per_side)
    unpaired: dict[str, int] = field(default_factory=_per_side)
    frame_queue_drops: int = 0
    camera_timeouts: int = 0
    camera_reconnects: int = 0
    pairs: int = 0
    results: int = 0
    result_errors: int = 0
    skipped_pairs: int = 0
    #: Results whose solvers started cold (full pyramid, SGM start): about twice the work.
    cold_results: int = 0
    wind_samples: int = 0
    worker_restarts: int = 0
    #: Frames of one camera written alone (a camera lost, or a single-camera site).
    single_frames: int = 0
    #: Results of the single-camera chain (among ``results``).
    single_results: int = 0
    #: Steps of a camera's offset (a flat-field shutter, a drift) levelled out of the
    #: processed triples' differences, one per frame pair.
    offset_steps: dict[str, int] = field(default_factory=_per_side)


class Acquisition:
    """The acquisition threads' shared state and loops.

    Parameters
    ----------
    cfg : Config
    counters : object
        The daemon's counters (``frames``, ``pairs``, ``wind_samples``, ... attributes).
    health : HealthMonitor
    stop_event : threading.Event
        Set when the daemon stops.
    wall_ns : callable
        Host monotonic ns -> UNIX ns.
    site : SimulatedSite
        Simulated camera/anemometer defaults.
    recorder, publisher, ring, watchdog
        Where frames, pairs and wind samples go (recorder may be None).
    watch : CameraWatch, optional
        Which cameras deliver (default: a new one for the configured cameras).
    """

    def __init__(self, cfg: Config, counters: Any, health: Any, stop_event: threading.Event,
                 wall_ns: Callable[[int], int], site: SimulatedSite, *, recorder: Any,
                 publisher: Any, ring: Any, watchdog: Any,
                 watch: CameraWatch | None = None, pictures: Any = None) -> None:
        self.cfg = cfg
        self.counters = counters
        self.health = health
        self.stop_event = stop_event
        self.wall_ns = wall_ns
        self.site = site
        self.recorder = recorder
        self.publisher = publisher
        self.ring = ring
        self.watchdog = watchdog
        #: The operator page's hub (``push_camera``, never waits), or None.
        self.pictures = pictures
        self._last_frame_id: dict[str, int | None] = {s: None for s in SIDES}
        self.anemometer: Any = None
        #: multiprocessing.Value the workers read the gas temperature from (K), or None.
        self.sonic_k: Any = None
        self._frame_q: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=512)
        self._pair_frame_ids: collections.OrderedDict[int, int | None] = (
            collections.OrderedDict())
        self._pair_lock = threading.Lock()
        #: Which cameras deliver (lost, returned; the pairing thread keeps it).
        self.watch = watch if watch is not None else camera_watch(cfg, wall_ns)
        #: The nominal frame rate pairing and the clock models assume, Hz.
        self.frame_rate_hz = nominal_frame_rate_hz(cfg)

    def frame_ids(self, *pair_indices: int) -> list[int | None]:
        """Device frame numbers of the left frames of recent pairs (None when unknown)."""
        with self._pair_lock:
            return [self._pair_frame_ids.get(i) for i in pair_indices]

    def make_camera(self, side: str) -> Any:
        cam_cfg = getattr(self.cfg.cameras, side)
        return create_camera(cam_cfg.backend, **self.site.camera_options(side, cam_cfg))

    def camera_loop(self, side: str) -> None:
        """Grab frames of one camera forever; reconnect with back-off when it vanishes."""
        backoff = RECONNECT_BACKOFF_S[0]
        logged_at: float | None = None  # last warning of the current outage (monotonic s)
        stream = self.health.stream(f"cam/{side}")
        cache: dict[str, schemas.MessageSchema] = {}
        while not self.stop_event.is_set():
            camera = None
            try:
                camera = self.make_camera(side)
                camera.open()
                camera.start()
                if logged_at is not None:
                    log.warning("camera %s: back", side)
                backoff, logged_at = RECONNECT_BACKOFF_S[0], None
                while not self.stop_event.is_set():
                    try:
                        frame = camera.grab(timeout=0.5)
                    except CameraTimeout:
                        self.counters.camera_timeouts += 1
                        continue
                    stream.tick()
                    if self.watchdog is not None:
                        self.watchdog.frame_arrived()
                    self.counters.frames[side] += 1
                    self._count_lost(side, frame)
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
                now = time.monotonic()
                if logged_at is None or now - logged_at >= RECONNECT_LOG_EVERY_S:
                    log.warning("camera %s: %s; reconnecting every %.2f s", side, exc,
                                RECONNECT_BACKOFF_S[1])
                    logged_at = now
                self.stop_event.wait(backoff)
                backoff = min(backoff * 2, RECONNECT_BACKOFF_S[1])
            finally:
                if camera is not None:
                    try:
                        camera.close()
                    except (CameraError, OSError):
                        pass

    def _count_lost(self, side: str, frame: Any) -> None:
        """Frames lost before this one: the device's frame-id gap (it spans reconnections),
        or what the back end reported when the device does not number its frames."""
        last, fid = self._last_frame_id[side], frame.device_frame_id
        if fid is not None and last is not None and fid > last:
            self.counters.frames_lost[side] += fid - last - 1
        elif fid is None:
            self.counters.frames_lost[side] += frame.lost
        self._last_frame_id[side] = fid

    def pairing_loop(self) -> None:
        """Stamp frames (clock model per camera), pair them, write pairs to the ring; while
        a camera is lost (or at a single-camera site) write the other camera's frames alone.
        """
        stamper = StereoStamper(self.frame_rate_hz, self.cfg.pairing.tolerance_s,
                                self.cfg.pairing.max_delay_s)
        watch = self.watch
        stream = self.health.stream("pairs")
        mono_stream = self.health.stream("single_camera")
        index = 0
        while True:
            try:
                side, frame = self._frame_q.get(timeout=0.05)
            except queue.Empty:
                if self.stop_event.is_set():
                    break
                now = time.monotonic_ns()
                self._note_lost(watch.check(now))
                pairs = stamper.poll(now) if watch.survivor is None else []
            else:
                # "Now" is the frame's arrival, not this thread's clock: when this thread
                # lags, the partner may already wait in the queue and must not be given up.
                if watch.frame(side, frame.host_ns):
                    log.warning("camera %s: delivering again; stereo resumes", side)
                    # its clock restarted with the device: a model of its own from scratch
                    stamper.clocks[side] = ClockModel(nominal_period_ns=stamper.period_ns)
                self._note_lost(watch.check(frame.host_ns))
                if watch.survivor is None:
                    pairs = stamper.push(side, frame, frame.host_ns)
                else:
                    pairs = []
                    if side == watch.survivor:
                        # the survivor's clock model goes on: its frames keep one timeline
                        t = stamper.clocks[side].update(frame.host_ns, frame.device_ts_ns,
                                                        frame.device_frame_id)
                        self._write_single(index, side, frame, t)
                        mono_stream.tick()
                        index += 1
            for p in pairs:
                self._write_pair(index, p)
                stream.tick()
                index += 1
            self.counters.unpaired = stamper.unpaired()

    def _note_lost(self, sides: list[str]) -> None:
        for side in sides:
            other = self.watch.survivor
            log.warning("camera %s: lost (nothing for %.1f s); %s", side,
                        self.cfg.cameras.lost_after_s,
                        f"going on with the {other} camera alone" if other
                        else "no camera delivers")

    def _write_pair(self, index: int, p: Any) -> None:
        left, right = p.left, p.right
        self.ring.write(left.image, right.image, pair_index=index, left_seq=left.seq,
                        right_seq=right.seq, t_left_mono_ns=p.left_ns, t_right_mono_ns=p.right_ns,
                        t_wall_ns=self.wall_ns(p.time_ns))
        self.counters.pairs += 1
        self._remember_frame_id(index, left.device_frame_id)
        self.publisher.record_pair(index, p)
        if self.pictures is not None:
            self.pictures.push_camera("left", left.image, left.seq, self.wall_ns(p.left_ns))

    def _write_single(self, index: int, side: str, frame: Any, t_ns: int) -> None:
        """One camera's frame alone into the ring (its capture time ``t_ns`` in both time
        fields, so the window's times are that camera's)."""
        images = {"left": None, "right": None, side: frame.image}
        self.ring.write(images["left"], images["right"], pair_index=index,
                        left_seq=frame.seq if side == "left" else -1,
                        right_seq=frame.seq if side == "right" else -1,
                        t_left_mono_ns=t_ns, t_right_mono_ns=t_ns, t_wall_ns=self.wall_ns(t_ns))
        self.counters.single_frames += 1
        self._remember_frame_id(index, frame.device_frame_id if side == "left" else None)
        if self.pictures is not None:
            self.pictures.push_camera(side, frame.image, frame.seq, self.wall_ns(t_ns))

    def _remember_frame_id(self, index: int, frame_id: int | None) -> None:
        with self._pair_lock:
            self._pair_frame_ids[index] = frame_id
            while len(self._pair_frame_ids) > 4 * self.cfg.ring.capacity + 64:
                self._pair_frame_ids.popitem(last=False)

    def start_anemometer(self, history: Any, mounting: Any) -> Any:
        """Create the anemometer back end and start its reader thread (returned)."""
        a = self.cfg.anemometer
        options = self.site.anemometer_options()
        if a.backend == "simulated":
            # The simulator's log of sent frames is for tests that compare; in a run it
            # would grow the daemon by ~17 MB/h until it trims at 200 000 frames.
            options.setdefault("history", 1000)
        if a.backend == "serial":
            options.setdefault("protocol", a.protocol)
            options.setdefault("url", a.port)
            options.setdefault("baudrate", a.baud)
            options.setdefault("parity", a.parity)
        self.anemometer = make_anemometer(a.backend, **options)
        return AnemometerReader(self.anemometer, on_sample=self.on_wind, history=history,
                                mounting=mounting).start()

    def on_wind(self, sample: Any) -> None:
        """Reader-thread callback: record the raw sample (never blocks)."""
        self.counters.wind_samples += 1
        self.health.stream("wind").tick()
        t_sonic = sample.sonic_temperature
        if self.sonic_k is not None and t_sonic is not None and np.isfinite(t_sonic):
            self.sonic_k.value = float(t_sonic) + 273.15  # the workers' gas temperature
        self.publisher.record_json("/wind/raw", schemas.WIND_SAMPLE, {
            "t_mono_ns": sample.host_ns, "t_wall_ns": self.wall_ns(sample.host_ns),
            "t_device": sample.counter, "sensor": self.cfg.anemometer.protocol,
            "u": _finite_or_none(sample.u), "v": _finite_or_none(sample.v),
            "w": _finite_or_none(sample.w),
            "speed_of_sound_m_s": _finite_or_none(sample.speed_of_sound),
            "sonic_temperature_c": _finite_or_none(sample.sonic_temperature),
            "status": sample.status_code, "valid": bool(sample.valid),
        }, sample.host_ns)


def camera_watch(cfg: Config, wall_ns: Callable[[int], int]) -> CameraWatch:
    """The :class:`CameraWatch` of the configured cameras (``cameras.lost_after_s``)."""
    present = {s: getattr(cfg.cameras, s) is not None for s in SIDES}
    return CameraWatch(present, cfg.cameras.lost_after_s, wall_ns)


def nominal_frame_rate_hz(cfg: Config) -> float:
    """The frame rate of the reference camera: a replayed folder's own (its
    ``labels.json`` ``frame_interval_s``, e.g. GasVid at 1 frame/s) unless the back end's
    ``fps`` option or nothing says otherwise, else ``frame_rate_hz``."""
    cam = cfg.cameras.left
    assert cam is not None
    if cam.backend == "replay_folder" and "fps" not in cam.options and "path" in cam.options:
        own = folder_frame_rate_hz(cam.options["path"])
        if own is not None:
            return own
    return float(cam.options.get("fps", cam.frame_rate_hz)) if cam.backend in (
        "replay_folder", "simulated") else cam.frame_rate_hz


def _finite_or_none(x: Any) -> float | None:
    """A number for JSON; None (null) for a missing or non-finite one. A failed axis or a
    2-D sensor's missing w must not read as a real 0.0 m/s calm."""
    if x is None:
        return None
    v = float(x)
    return v if np.isfinite(v) else None
