"""Replay a folder of images (PNG, TIFF, JPEG) as a camera at a given frame rate.

Files are taken in name order. 16-bit images (PNG/TIFF) keep their counts (``Mono16``),
8-bit ones give ``Mono8``; colour images are converted to grey. Unreadable files and files
whose size or depth differs from the first image are skipped and counted
(``stats.skipped``) with a warning naming the file.

Frame rate: the ``fps`` option, else the folder's own: ``frame_interval_s`` of a
``labels.json`` in it (GasVid footage: 1 frame per second), else 30 frames per second.

Timestamps: frame ``i`` is stamped ``host_ns = t_start + i * period`` where ``t_start`` is
the monotonic time of ``start()``; ``device_ts_ns = i * period`` is its time in the
sequence. With ``pace=True`` ``grab`` waits until that time (recorded pace); with
``pace=False`` frames come as fast as they can be read, stamped on the same nominal
timeline, so a left and a right folder replayed fast still pair frame by frame.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import cv2
import numpy as np

from drivers.camera.base import Camera, CameraError, CameraTimeout, Capture, EndOfStream

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def list_images(folder: Path, pattern: str = "*") -> list[Path]:
    """Image files in ``folder`` matching ``pattern``, sorted by name."""
    return sorted(
        p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
    )


def read_mono(path: Path) -> np.ndarray | None:
    """Read an image as (H, W) uint8 or uint16 (colour converted to grey); None if unreadable."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        return None
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype not in (np.uint8, np.uint16):
        return None
    return image


#: The folder file that may say the footage's frame interval (``frame_interval_s``, s).
LABELS_FILE = "labels.json"


def folder_frame_rate_hz(folder: str | Path) -> float | None:
    """The frame rate a folder's ``labels.json`` gives (1 / ``frame_interval_s``), Hz;
    None without one (or without a positive interval in it)."""
    path = Path(folder) / LABELS_FILE
    try:
        interval = json.loads(path.read_text(encoding="utf-8")).get("frame_interval_s")
    except (OSError, ValueError, AttributeError):
        return None
    if isinstance(interval, (int, float)) and not isinstance(interval, bool) and interval > 0:
        return 1.0 / float(interval)
    return None


class FolderReplayCamera(Camera):
    """Images of a folder delivered as frames.

    Parameters
    ----------
    path : str or Path
        The folder.
    fps : float or None
        Frame rate of the sequence; None: the folder's own (module docstring).
    pattern : str
        Glob pattern within the folder (e.g. ``"left_*.png"``).
    pace : bool
        Wait for each frame's time (True) or deliver as fast as possible (False).
    loop : bool
        Start again after the last image instead of raising EndOfStream.
    label : str or None
        Name for messages (default: the folder name).
    """

    backend = "replay_folder"

    def __init__(
        self,
        path: str | Path,
        fps: float | None = None,
        *,
        pattern: str = "*",
        pace: bool = True,
        loop: bool = False,
        label: str | None = None,
    ) -> None:
        self.path = Path(path)
        super().__init__(label=label or self.path.name)
        if fps is None:
            fps = folder_frame_rate_hz(self.path) or 30.0
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.period_ns = round(1e9 / fps)
        self.pattern = pattern
        self.pace = pace
        self.loop = loop
        self._files: list[Path] = []
        self._i = 0
        self._n = 0
        self._t0 = 0
        self._shape: tuple[int, int] | None = None
        self._dtype: np.dtype | None = None

    def _open(self) -> None:
        if not self.path.is_dir():
            raise CameraError(f"{self.label}: {self.path} is not a folder")
        self._files = list_images(self.path, self.pattern)
        if not self._files:
            raise CameraError(
                f"{self.label}: no {'/'.join(IMAGE_SUFFIXES)} files matching "
                f"{self.pattern!r} in {self.path}"
            )
        self._shape = None

    def _start(self) -> None:
        self._i = 0
        self._n = 0
        self._t0 = time.monotonic_ns()

    def _grab(self, timeout: float) -> Capture:
        while True:
            if self._i >= len(self._files):
                if not self.loop:
                    raise EndOfStream(f"{self.label}: last of {len(self._files)} images delivered")
                self._i = 0
            path = self._files[self._i]
            image = read_mono(path)
            self._i += 1
            if image is None:
                self._skip(path, "unreadable or not 8/16-bit")
                continue
            if self._shape is None:
                self._shape, self._dtype = image.shape, image.dtype
            elif image.shape != self._shape or image.dtype != self._dtype:
                self._skip(
                    path, f"{image.shape} {image.dtype}, expected {self._shape} {self._dtype}"
                )
                continue
            break
        due = self._t0 + self._n * self.period_ns
        if self.pace:
            wait = (due - time.monotonic_ns()) / 1e9
            if wait > timeout:
                self._i -= 1  # deliver this image on the next call
                time.sleep(timeout)
                raise CameraTimeout(f"{self.label}: next frame due in {wait:.3f} s")
            if wait > 0:
                time.sleep(wait)
        device_ts = self._n * self.period_ns
        self._n += 1
        return Capture(
            image=image,
            pixel_format="Mono16" if image.dtype == np.uint16 else "Mono8",
            host_ns=due,
            device_ts_ns=device_ts,
            device_frame_id=self._n - 1,
        )

    def _skip(self, path: Path, why: str) -> None:
        self.stats.skipped += 1
        log.warning("%s: skipped %s: %s", self.label, path.name, why)

    def _close(self) -> None:
        self._files = []
