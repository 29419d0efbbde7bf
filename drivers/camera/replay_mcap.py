"""Replay one camera side from an MCAP recording written by the appliance.

Frames keep everything that was recorded: ``host_ns`` (the original monotonic arrival),
``seq``, ``device_ts_ns``, ``device_frame_id``, ``lost`` and temperatures, so offline
reprocessing pairs and times them exactly as the appliance did. ``pace=True`` plays them
with their recorded spacing (relative to ``start()``), ``pace=False`` as fast as they are
read. The file is read with the non-seeking reader: recordings cut by a crash replay up to
their last complete chunk (``truncated`` tells).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

from drivers.camera.base import Camera, CameraError, CameraTimeout, Capture, EndOfStream, Frame
from drivers.camera.mcap_format import SIDES, FrameLogReader


class McapReplayCamera(Camera):
    """One side (``left``/``right``) of an MCAP recording as a camera.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    side : {"left", "right"}
        Which camera's frames to deliver.
    pace : bool
        Recorded pace (True) or as fast as possible (False).
    loop : bool
        Start over at the end (timestamps repeat as recorded) instead of EndOfStream.
    label : str or None
        Name for messages (default ``side``).
    """

    backend = "replay_mcap"

    def __init__(
        self,
        path: str | Path,
        side: str = "left",
        *,
        pace: bool = True,
        loop: bool = False,
        label: str | None = None,
    ) -> None:
        super().__init__(label=label or side)
        if side not in SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        self.path = Path(path)
        self.side = side
        self.pace = pace
        self.loop = loop
        self.truncated = False
        self._reader: FrameLogReader | None = None
        self._it: Iterator[tuple[str, Frame]] | None = None
        self._pending: Frame | None = None
        self._first_host: int | None = None
        self._t0 = 0

    def _open(self) -> None:
        if not self.path.is_file():
            raise CameraError(f"{self.label}: no recording {self.path}")
        self._rewind()

    def _rewind(self) -> None:
        self._reader = FrameLogReader(self.path, sides=(self.side,))
        self._it = iter(self._reader)

    def _start(self) -> None:
        self._first_host = None
        self._t0 = time.monotonic_ns()

    def _next(self) -> Frame:
        if self._pending is not None:
            frame, self._pending = self._pending, None
            return frame
        assert self._it is not None and self._reader is not None
        for _side, frame in self._it:
            return frame
        self.truncated = self.truncated or self._reader.truncated
        self.stats.skipped = self._reader.skipped
        if not self.loop:
            raise EndOfStream(f"{self.label}: end of {self.path}")
        self._rewind()
        self._first_host = None
        self._t0 = time.monotonic_ns()
        for _side, frame in self._it:
            return frame
        raise EndOfStream(f"{self.label}: no {self.side} frames in {self.path}")

    def _grab(self, timeout: float) -> Capture:
        frame = self._next()
        if self._first_host is None:
            self._first_host = frame.host_ns
        if self.pace:
            wait = (self._t0 + (frame.host_ns - self._first_host) - time.monotonic_ns()) / 1e9
            if wait > timeout:
                self._pending = frame
                time.sleep(timeout)
                raise CameraTimeout(f"{self.label}: next frame due in {wait:.3f} s")
            if wait > 0:
                time.sleep(wait)
        return Capture(
            image=frame.image,
            pixel_format=frame.pixel_format,
            host_ns=frame.host_ns,
            device_ts_ns=frame.device_ts_ns,
            device_frame_id=frame.device_frame_id,
            lost=frame.lost,
            temperatures=frame.temperatures,
            seq=frame.seq,
        )

    def _close(self) -> None:
        self._it = None
        self._reader = None
