"""Cameras through OpenCV ``VideoCapture``: V4L2 devices, video files, RTSP/HTTP streams.

Frames are stamped with ``time.monotonic_ns()`` when ``read()`` returns: OpenCV's
``CAP_PROP_POS_MSEC`` is a position in the stream, not a capture time, so there is no
device timestamp (``device_ts_ns`` None; the clock model smooths arrivals against the
nominal period instead). ``device_frame_id`` is the frame's index in a video file, and None
for live sources (OpenCV does not report the device's frame counter, so drops are unseen).

Colour frames are converted to grey (``Mono8``). A V4L2 camera delivering 16-bit grey
(``Y16``) is read raw (``fourcc="Y16 "``, ``convert_rgb=False``) as ``Mono16``.

Live sources (devices, network streams) that stop delivering are released and re-opened
every ``retry_interval_s`` inside :meth:`grab` (``CameraDisconnected`` meanwhile). Files end
with :class:`EndOfStream` unless ``loop`` is set; ``pace=True`` plays a file at its own
frame rate (or ``fps``), ``pace=False`` as fast as it decodes.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np

from drivers.camera.base import (
    Camera,
    CameraDisconnected,
    CameraError,
    Capture,
    EndOfStream,
)

log = logging.getLogger(__name__)

_APIS = {"any": cv2.CAP_ANY, "v4l2": cv2.CAP_V4L2, "ffmpeg": cv2.CAP_FFMPEG}
_NETWORK = ("rtsp://", "rtsps://", "http://", "https://", "udp://", "tcp://")


def _parse_source(source: int | str) -> tuple[int | str, str]:
    """(what to pass to VideoCapture, kind) with kind in device/file/network."""
    if isinstance(source, int) or (isinstance(source, str) and source.isdigit()):
        return int(source), "device"
    if source.startswith("/dev/video"):
        return source, "device"
    if source.lower().startswith(_NETWORK):
        return source, "network"
    return source, "file"


class OpenCVCamera(Camera):
    """A camera or stream read through OpenCV.

    Parameters
    ----------
    source : int or str
        V4L2 device index (``0``) or path (``/dev/video0``), a video file, or a stream URL
        (``rtsp://...``).
    api : {"any", "v4l2", "ffmpeg"}
        OpenCV back end (``any`` lets OpenCV choose; devices default to V4L2).
    width, height, fps : int, int, float or None
        Requested capture size and rate for devices (None: leave as is). For files,
        ``fps`` overrides the file's rate for pacing.
    fourcc : str or None
        Four-character pixel format to request from a device (``"Y16 "`` for 16-bit grey).
    convert_rgb : bool
        Let OpenCV convert to BGR (True) or hand out raw data (False, for Y16).
    pace : bool
        Play files at their frame rate (True) or as fast as possible (False).
    loop : bool
        Files: start again at the end instead of EndOfStream.
    open_timeout_s, read_timeout_s : float
        Network streams: FFmpeg open and read timeouts.
    retry_interval_s : float
        Live sources: time between re-open attempts after a failure.
    label : str or None
        Name for messages.
    """

    backend = "opencv"

    def __init__(
        self,
        source: int | str,
        *,
        api: str = "any",
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        fourcc: str | None = None,
        convert_rgb: bool = True,
        pace: bool = False,
        loop: bool = False,
        open_timeout_s: float = 5.0,
        read_timeout_s: float = 5.0,
        retry_interval_s: float = 1.0,
        label: str | None = None,
    ) -> None:
        super().__init__(label=label or str(source))
        if api not in _APIS:
            raise ValueError(f"api must be one of {sorted(_APIS)}, got {api!r}")
        if fourcc is not None and len(fourcc) != 4:
            raise ValueError(f"fourcc must be 4 characters, got {fourcc!r}")
        if fps is not None and not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.source, self.kind = _parse_source(source)
        self.api = api
        self.size = (width, height)
        self.fps = fps
        self.fourcc = fourcc
        self.convert_rgb = convert_rgb
        self.pace = pace
        self.loop = loop
        self.open_timeout_s = open_timeout_s
        self.read_timeout_s = read_timeout_s
        self.retry_interval_s = retry_interval_s
        self._cap: cv2.VideoCapture | None = None
        self._index = 0
        self._period_ns = 0
        self._t0 = 0
        self._next_retry = 0.0

    # -- connection ----------------------------------------------------------------------
    def _make_capture(self) -> cv2.VideoCapture:
        api = _APIS[self.api]
        if self.api == "any" and self.kind == "device":
            api = cv2.CAP_V4L2
        params: list[int] = []
        if self.kind == "network":
            params = [
                cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(self.open_timeout_s * 1000),
                cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.read_timeout_s * 1000),
            ]  # fmt: skip
        if self.kind == "file" and not Path(str(self.source)).is_file():
            raise CameraError(f"{self.label}: no such video file {self.source}")
        cap = cv2.VideoCapture(self.source, api, params)
        if not cap.isOpened():
            cap.release()
            raise CameraDisconnected(f"{self.label}: OpenCV cannot open {self.source!r}")
        if self.kind == "device":
            if self.fourcc is not None:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc))
            w, h = self.size
            if w is not None:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, w)
            if h is not None:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
            if self.fps is not None:
                cap.set(cv2.CAP_PROP_FPS, self.fps)
        if not self.convert_rgb:
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        return cap

    def _open(self) -> None:
        self._cap = self._make_capture()
        rate = self.fps or self._cap.get(cv2.CAP_PROP_FPS) or 0.0
        self._period_ns = round(1e9 / rate) if rate > 0 else 0

    def _start(self) -> None:
        self._index = 0
        self._t0 = time.monotonic_ns()

    def _reopen(self) -> bool:
        now = time.monotonic()
        if now < self._next_retry:
            return False
        self._next_retry = now + self.retry_interval_s
        try:
            self._cap = self._make_capture()
        except CameraDisconnected as exc:
            log.debug("%s: reopen failed: %s", self.label, exc)
            return False
        self.stats.reconnects += 1
        log.info("%s: reopened", self.label)
        return True

    # -- frames --------------------------------------------------------------------------
    def _grab(self, timeout: float) -> Capture:
        if self._cap is None and not self._reopen():
            time.sleep(min(timeout, max(0.0, self._next_retry - time.monotonic())))
            raise CameraDisconnected(f"{self.label}: source away, reopening")
        assert self._cap is not None
        if self.pace and self.kind == "file" and self._period_ns:
            wait = (self._t0 + self._index * self._period_ns - time.monotonic_ns()) / 1e9
            if wait > 0:
                time.sleep(min(wait, timeout))
        ok, frame = self._cap.read()
        host_ns = time.monotonic_ns()
        if not ok or frame is None:
            if self.kind == "file":
                if self.loop and self._index > 0:
                    self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                    self._t0 = host_ns - self._index * self._period_ns
                    return self._grab(timeout)
                raise EndOfStream(f"{self.label}: end of {self.source} after {self._index} frames")
            self._cap.release()
            self._cap = None
            self.stats.disconnects += 1
            self._next_retry = time.monotonic() + self.retry_interval_s
            raise CameraDisconnected(f"{self.label}: read from {self.source!r} failed")
        image = self._to_mono(frame)
        index = self._index
        self._index += 1
        return Capture(
            image=image,
            pixel_format="Mono16" if image.dtype == np.uint16 else "Mono8",
            host_ns=host_ns,
            # A file's frame index is exact; a live source's count of delivered frames would
            # hide drops, and the clock model would take it for the device's frame counter.
            device_frame_id=index if self.kind == "file" else None,
        )

    def _to_mono(self, frame: np.ndarray) -> np.ndarray:
        if frame.ndim == 3 and frame.shape[2] == 3:
            return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        if frame.ndim == 3 and frame.shape[2] == 1:
            return frame[:, :, 0]
        if frame.ndim == 2 and frame.dtype in (np.uint8, np.uint16):
            if frame.dtype == np.uint8 and self.fourcc == "Y16 " and self._cap is not None:
                # raw Y16 arrives as bytes: view as little-endian uint16
                w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
                h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
                if frame.size == w * h * 2:
                    return frame.reshape(-1).view("<u2").reshape(h, w).astype(np.uint16)
            return frame
        raise CameraError(f"{self.label}: unsupported frame {frame.shape} {frame.dtype}")

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
