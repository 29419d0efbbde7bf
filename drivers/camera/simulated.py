"""Simulated camera: pre-rendered frames delivered with a realistic timing model.

Timing model (per camera, all times in ns on the host monotonic timeline, ``t = 0`` at the
shared epoch):

- the device clock reads ``D(t) = offset + (1 + drift) t``;
- the camera exposes frame ``k`` when its own clock reads ``D_k = D(phase) + k P`` (its frame
  timer runs on the device clock, so a drifting camera also runs slightly fast or slow);
  the true capture time is ``t_k = (D_k - offset) / (1 + drift)``;
- the frame reaches the host at ``a_k = t_k + latency + j_k``, ``j_k`` exponential with mean
  ``jitter_s`` (never negative; transport delivers in order, so ``a_k >= a_{k-1}``);
- with probability ``drop_rate`` frame ``k`` is lost; the next delivered frame reports it in
  ``lost`` (its ``device_frame_id`` jumps).

``device_ts_ns`` is ``D_k`` (or None with ``device_clock=False``), ``device_frame_id`` is
``k``. The random draws depend only on ``seed`` and ``k`` (blocks of 1024 frames), so a run is
reproducible and :meth:`TimingModel.capture_time_ns` gives the ground truth of any frame.

Outage (fault injection, realtime only): with ``outage_after_s`` set, the camera vanishes
that many seconds after the first ``open`` of a camera with the same label in this process,
for ``outage_s`` seconds: ``grab`` raises :class:`CameraDisconnected` and ``open`` fails
until it is back; frames exposed meanwhile are never delivered (the frame ids jump).
:func:`vanish` starts such an outage on demand (a fault test that needs the outage at a
given state of the daemon rather than at a given time).

With ``realtime=True`` (the daemon) ``grab`` sleeps until each arrival and stamps the frame
with ``time.monotonic_ns()``; with ``realtime=False`` it returns at once and stamps the
modelled arrival on a virtual timeline starting at ``epoch_ns`` (tests, benchmarks: ten
minutes of simulated time take seconds).

Images come from a shared pre-rendered :class:`~drivers.camera.sources.FrameSource`
(left camera: the left image of frame ``k % n_frames``); the only per-frame work is an
optional sub-pixel shift (``image_jitter_px``, one ``cv2.warpAffine``, ~0.1 ms) and an
optional flat-field shutter (``shutter_every_s``): every that many seconds the camera's
whole picture steps by ``shutter_counts``, up and back down in turn, as a camera's
non-uniformity correction moves its offset (the chain levels such steps out and counts
them, :func:`processing.preprocess.differential.levelled_difference`); with
``shutter_pattern_counts`` each correction also leaves a new fixed pattern (a residual
non-uniformity, white, that standard deviation in counts) until the next.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drivers.camera.base import Camera, CameraDisconnected, CameraTimeout, Capture, EndOfStream
from drivers.camera.sources import FrameSource, load_source

log = logging.getLogger(__name__)

_BLOCK = 1024
#: Shared epoch of realtime simulated cameras in this process, so a left and a right camera
#: started at different moments still share one true timeline.
_PROCESS_EPOCH_NS = time.monotonic_ns()
#: First open of each camera label in this process: outages are timed from it, so they
#: span the new camera objects a reconnecting daemon creates.
_FIRST_OPEN_NS: dict[str, int] = {}
#: The outage window (monotonic ns, start and end) of each camera label in this process.
_OUTAGE_NS: dict[str, tuple[int, int]] = {}


def vanish(label: str, seconds: float) -> None:
    """Make the realtime simulated camera(s) labelled ``label`` vanish now for ``seconds``
    (fault injection; replaces any outage of that label set by ``outage_after_s``)."""
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds!r}")
    now = time.monotonic_ns()
    _OUTAGE_NS[label] = (now, now + int(seconds * 1e9))


@dataclass(frozen=True)
class TimingParams:
    """Timing of one simulated camera (seconds, ppm; see the module docstring)."""

    fps: float = 30.0
    latency_s: float = 0.008
    jitter_s: float = 0.002
    clock_offset_s: float = 0.0
    drift_ppm: float = 0.0
    drop_rate: float = 0.0
    phase_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.fps > 0:
            raise ValueError(f"fps must be > 0, got {self.fps}")
        if self.latency_s < 0 or self.jitter_s < 0:
            raise ValueError("latency_s and jitter_s must be >= 0")
        if not 0 <= self.drop_rate < 1:
            raise ValueError(f"drop_rate must be in [0, 1), got {self.drop_rate}")
        if abs(self.drift_ppm) >= 1e5:
            raise ValueError(f"drift_ppm is unrealistic: {self.drift_ppm}")


@dataclass(frozen=True)
class FrameEvents:
    """Frames ``k0 .. k0+n-1``: arrays of length n (int64 ns, bool)."""

    k0: int
    capture_ns: np.ndarray
    device_ns: np.ndarray
    arrival_ns: np.ndarray
    dropped: np.ndarray


class TimingModel:
    """Deterministic capture/device/arrival times of every frame of one camera."""

    def __init__(self, params: TimingParams) -> None:
        self.p = params
        self.period_ns = 1e9 / params.fps
        self.rate = 1.0 + params.drift_ppm * 1e-6
        self.offset_ns = params.clock_offset_s * 1e9
        self._d0 = self.offset_ns + self.rate * params.phase_s * 1e9
        self._cache: dict[int, FrameEvents] = {}

    def device_time_ns(self, k: np.ndarray | int) -> np.ndarray:
        """Device timestamp of frame(s) ``k`` (float ns)."""
        return self._d0 + np.asarray(k, dtype=np.float64) * self.period_ns

    def capture_time_ns(self, k: np.ndarray | int) -> np.ndarray:
        """True capture time of frame(s) ``k`` on the host timeline (float ns)."""
        return (self.device_time_ns(k) - self.offset_ns) / self.rate

    def block(self, b: int) -> FrameEvents:
        """Events of frames ``b*1024 .. b*1024+1023`` (cached; two blocks kept)."""
        if b in self._cache:
            return self._cache[b]
        k = np.arange(b * _BLOCK, (b + 1) * _BLOCK)
        rng = np.random.default_rng([self.p.seed, b])
        jitter = rng.exponential(self.p.jitter_s * 1e9, _BLOCK) if self.p.jitter_s > 0 else 0.0
        dropped = rng.random(_BLOCK) < self.p.drop_rate
        capture = self.capture_time_ns(k)
        arrival = capture + self.p.latency_s * 1e9 + jitter
        # In-order delivery; the first frame of a block also respects the previous block.
        np.maximum.accumulate(arrival, out=arrival)
        events = FrameEvents(
            k0=b * _BLOCK,
            capture_ns=np.round(capture).astype(np.int64),
            device_ns=np.round(self.device_time_ns(k)).astype(np.int64),
            arrival_ns=np.round(arrival).astype(np.int64),
            dropped=dropped,
        )
        if len(self._cache) >= 2:
            self._cache.pop(min(self._cache))
        self._cache[b] = events
        return events

    def first_frame_after(self, t_ns: float) -> int:
        """Index of the first frame captured after host time ``t_ns``."""
        k = int(np.ceil((t_ns * self.rate + self.offset_ns - self._d0) / self.period_ns))
        return max(k, 0)


class SimulatedCamera(Camera):
    """A simulated OGI camera (one side of a stereo pair).

    Parameters
    ----------
    side : {"left", "right"}
        Which image of the source's stereo pair this camera delivers.
    source : str, Path or FrameSource
        ``"pattern"`` (deterministic texture), a synthetic frame directory
        (``ogiflow-synthetic/1``), or a source object; shared between cameras.
    fps, latency_s, jitter_s, clock_offset_s, drift_ppm, drop_rate, phase_s, seed
        Timing model (module docstring). ``phase_s`` is when this camera's first frame is
        exposed after the epoch: the two cameras are not triggered together.
    image_jitter_px : float
        Standard deviation of a random sub-pixel image shift per frame, px (camera shake).
    device_clock : bool
        False simulates a device without timestamps (``device_ts_ns`` None).
    realtime : bool
        Sleep until each frame's arrival (True) or return immediately on a virtual timeline.
    epoch_ns : int or None
        Host time of ``t = 0``. Default: a process-wide monotonic epoch when realtime, else 0.
    max_frames : int or None
        Deliver this many frames, then raise EndOfStream (None: endless).
    label : str
        Name for messages; defaults to ``side``.
    outage_after_s, outage_s : float
        Simulated outage (module docstring): vanish ``outage_after_s`` seconds after the
        first open of this label, for ``outage_s`` seconds (None: never).
    shutter_every_s : float or None
        A flat-field shutter every this many seconds (at least one frame; None: never):
        frames ``k`` with ``(k // period) % 2 == 1`` read ``shutter_counts`` more.
    shutter_counts : int
        The step of the picture's offset at a shutter, counts (1-65535).
    shutter_pattern_counts : float
        Standard deviation of the fixed pattern each shutter leaves, counts (0: none); one
        pattern per shutter interval, drawn from ``seed`` and the interval's number.
    """

    backend = "simulated"

    def __init__(
        self,
        side: str = "left",
        source: str | Path | FrameSource = "pattern",
        *,
        fps: float = 30.0,
        latency_s: float = 0.008,
        jitter_s: float = 0.002,
        clock_offset_s: float = 0.0,
        drift_ppm: float = 0.0,
        drop_rate: float = 0.0,
        phase_s: float = 0.0,
        seed: int = 0,
        image_jitter_px: float = 0.0,
        device_clock: bool = True,
        realtime: bool = True,
        epoch_ns: int | None = None,
        max_frames: int | None = None,
        label: str | None = None,
        outage_after_s: float | None = None,
        outage_s: float = 5.0,
        shutter_every_s: float | None = None,
        shutter_counts: int = 200,
        shutter_pattern_counts: float = 0.0,
    ) -> None:
        super().__init__(label=label or side)
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        if image_jitter_px < 0:
            raise ValueError(f"image_jitter_px must be >= 0, got {image_jitter_px}")
        if outage_after_s is not None and not (outage_after_s >= 0 and outage_s > 0):
            raise ValueError("outage_after_s must be >= 0 and outage_s > 0, got "
                             f"{outage_after_s!r} and {outage_s!r}")
        if shutter_every_s is not None and not shutter_every_s > 0:
            raise ValueError(f"shutter_every_s must be > 0 or null, got {shutter_every_s!r}")
        if not 1 <= int(shutter_counts) <= 65535:
            raise ValueError(f"shutter_counts must be 1-65535, got {shutter_counts!r}")
        if not 0 <= shutter_pattern_counts < 65535:
            raise ValueError("shutter_pattern_counts must be >= 0 counts, got "
                             f"{shutter_pattern_counts!r}")
        self.side = side
        self._outage = (outage_after_s, outage_s)
        self._shutter_period = (None if shutter_every_s is None
                                else max(1, round(shutter_every_s * fps)))
        self._shutter_counts = int(shutter_counts)
        self._pattern_sd = float(shutter_pattern_counts)
        self._pattern: tuple[int, np.ndarray] | None = None  # (interval, its pattern)
        self._seed = seed
        self._source_spec = source
        self.timing = TimingModel(
            TimingParams(
                fps=fps,
                latency_s=latency_s,
                jitter_s=jitter_s,
                clock_offset_s=clock_offset_s,
                drift_ppm=drift_ppm,
                drop_rate=drop_rate,
                phase_s=phase_s,
                seed=seed,
            )
        )
        self.image_jitter_px = float(image_jitter_px)
        self.device_clock = device_clock
        self.realtime = realtime
        self.epoch_ns = epoch_ns if epoch_ns is not None else (_PROCESS_EPOCH_NS if realtime else 0)
        self.max_frames = max_frames
        self.source: FrameSource | None = None
        self._k = 0
        self._delivered = 0
        self._rng = np.random.default_rng(seed + 7919)

    def _open(self) -> None:
        after, length = self._outage
        now = time.monotonic_ns()
        if after is not None and self.realtime:
            t0 = _FIRST_OPEN_NS.setdefault(self.label, now) + int(after * 1e9)
            _OUTAGE_NS.setdefault(self.label, (t0, t0 + int(length * 1e9)))
        window = _OUTAGE_NS.get(self.label) if self.realtime else None
        if window is not None and window[0] <= now < window[1]:
            raise CameraDisconnected(f"{self.label}: not found (simulated outage)")
        self.source = load_source(self._source_spec)
        interval = self.source.frame_interval_s
        if interval is not None and abs(interval * self.timing.p.fps - 1.0) > 1e-3:
            # The renderer moved the plume by one frame interval per frame: playing it at
            # another rate changes every velocity the pipeline will measure.
            log.warning(
                "%s: frames were rendered %.4f s apart but are played at %.3f Hz; "
                "velocities will scale by %.3f",
                self.label, interval, self.timing.p.fps, interval * self.timing.p.fps,
            )  # fmt: skip

    def _start(self) -> None:
        self._delivered = 0
        if self.realtime:
            self._k = self.timing.first_frame_after(time.monotonic_ns() - self.epoch_ns)
        else:
            self._k = 0

    def _next_event(self) -> tuple[int, int, int, int]:
        """(k, device_ns, arrival_ns relative to the epoch, frames lost before it)."""
        lost = 0
        while True:
            ev = self.timing.block(self._k // _BLOCK)
            i = self._k - ev.k0
            if not ev.dropped[i]:
                return self._k, int(ev.device_ns[i]), int(ev.arrival_ns[i]), lost
            lost += 1
            self._k += 1

    def _grab(self, timeout: float) -> Capture:
        if self.max_frames is not None and self._delivered >= self.max_frames:
            raise EndOfStream(f"{self.label}: delivered max_frames={self.max_frames}")
        k, device_ns, arrival_rel, lost = self._next_event()
        arrival = self.epoch_ns + arrival_rel
        if self.realtime:
            window = _OUTAGE_NS.get(self.label)
            if window is not None and window[0] <= arrival < window[1] + 1:
                # The outage begins before this frame: wait for it like for a frame.
                self._sleep_until(window[0], timeout)
                if time.monotonic_ns() < window[1]:
                    raise CameraDisconnected(f"{self.label}: connection lost (simulated "
                                             "outage)")
            self._sleep_until(arrival, timeout)
            host_ns = time.monotonic_ns()
        else:
            host_ns = arrival
        self._k = k + 1
        self._delivered += 1
        assert self.source is not None
        image = self.source.stereo(k)[0 if self.side == "left" else 1]
        if self.image_jitter_px > 0:
            image = self._shift(image)
        if self._shutter_period is not None:
            image = self._stepped(image, k // self._shutter_period)
        return Capture(
            image=image,
            pixel_format="Mono16",
            host_ns=host_ns,
            device_ts_ns=device_ns if self.device_clock else None,
            device_frame_id=k,
            lost=lost,
            temperatures={"sensor": 35.0},
        )

    def _sleep_until(self, t_ns: int, timeout: float) -> None:
        """Sleep until monotonic ``t_ns``; CameraTimeout when that is beyond ``timeout``."""
        wait_ns = t_ns - time.monotonic_ns()
        if wait_ns > timeout * 1e9:
            time.sleep(timeout)
            raise CameraTimeout(f"{self.label}: no frame within {timeout} s")
        if wait_ns > 0:
            time.sleep(wait_ns / 1e9)

    def _shift(self, image: np.ndarray) -> np.ndarray:
        dx, dy = self._rng.normal(0.0, self.image_jitter_px, 2)
        m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]], dtype=np.float64)
        h, w = image.shape
        return cv2.warpAffine(
            image, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )

    def _stepped(self, image: np.ndarray, interval: int) -> np.ndarray:
        """``image`` as the shutter interval ``interval`` leaves it: the offset step in
        every other interval, the interval's fixed pattern, clipped to the format."""
        offset = np.float64(self._shutter_counts if interval % 2 else 0)
        if self._pattern_sd > 0:
            if self._pattern is None or self._pattern[0] != interval:
                rng = np.random.default_rng([self._seed, 104729, interval])
                self._pattern = (interval, rng.normal(0.0, self._pattern_sd, image.shape))
            offset = offset + self._pattern[1]
        if not np.any(offset):
            return image
        if not np.issubdtype(image.dtype, np.integer):
            return (image + offset).astype(image.dtype)
        info = np.iinfo(image.dtype)
        return np.clip(np.rint(image + offset), info.min, info.max).astype(image.dtype)

    def _close(self) -> None:
        self.source = None
