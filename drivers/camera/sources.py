"""Pre-rendered stereo frame sources for the simulated camera.

A source holds ``n_frames`` left/right image pairs in memory, rendered or loaded once, and
hands out pair ``index % n_frames``. Both cameras of a simulated stereo pair share one
source object (:func:`load_source` caches by path), so frame ``k`` of the left camera and
frame ``k`` of the right camera show the same instant.

Two concrete sources:

- :class:`SyntheticDirSource` reads the synthetic-data renderer's output directory
  (``meta.json`` with ``"format": "ogiflow-synthetic/1"`` and ``frame_00000.npz`` ... each
  holding ``left`` and ``right`` (H, W) uint16 counts). It is read with numpy directly so
  the drivers do not depend on the renderer's code.
- :class:`TexturePatternSource` makes deterministic textured frames with numpy/OpenCV (a
  smooth random background, a drifting bright blob, the right view shifted by a fixed
  disparity). It is the test source for the camera, clock and pairing code.
"""

from __future__ import annotations

import json
import threading
import zipfile
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from drivers.camera.base import CameraError

SYNTHETIC_FORMAT_PREFIX = "ogiflow-synthetic/"


@runtime_checkable
class FrameSource(Protocol):
    """Stereo frames by index, already in memory."""

    n_frames: int
    shape: tuple[int, int]  # (H, W)
    frame_interval_s: float | None  # the interval the frames were rendered for, if any

    def stereo(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right (H, W) uint16 images of frame ``index % n_frames`` (read-only)."""
        ...


class _ArraySource:
    """Shared storage: (N, 2, H, W) uint16, read-only."""

    def __init__(self, frames: np.ndarray, frame_interval_s: float | None) -> None:
        if frames.ndim != 4 or frames.shape[1] != 2 or frames.dtype != np.uint16:
            raise ValueError(
                f"frames must be (N, 2, H, W) uint16, got {frames.shape} {frames.dtype}"
            )
        if frames.shape[0] < 1:
            raise ValueError("a frame source needs at least one frame")
        frames.flags.writeable = False
        self._frames = frames
        self.n_frames = int(frames.shape[0])
        self.shape = (int(frames.shape[2]), int(frames.shape[3]))
        self.frame_interval_s = frame_interval_s

    def stereo(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        pair = self._frames[index % self.n_frames]
        return pair[0], pair[1]


class SyntheticDirSource(_ArraySource):
    """Frames written by the synthetic stereo renderer (format ``ogiflow-synthetic/1``).

    Parameters
    ----------
    path : str or Path
        The renderer's output directory.

    Raises
    ------
    CameraError
        Missing or malformed ``meta.json``, a missing frame file, or a frame whose arrays
        are not (H, W) uint16 of the size in ``meta.json``; the message names the file.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        meta_path = self.path / "meta.json"
        try:
            meta = json.loads(meta_path.read_text())
        except FileNotFoundError:
            raise CameraError(f"{meta_path}: not found (not a synthetic frame directory)") from None
        except json.JSONDecodeError as exc:
            raise CameraError(f"{meta_path}: not valid JSON ({exc})") from None
        fmt = str(meta.get("format", ""))
        if not fmt.startswith(SYNTHETIC_FORMAT_PREFIX):
            raise CameraError(f"{meta_path}: format {fmt!r} is not {SYNTHETIC_FORMAT_PREFIX}N")
        try:
            n = int(meta["n_frames"])
            width = int(meta["camera"]["width"])
            height = int(meta["camera"]["height"])
        except (KeyError, TypeError, ValueError) as exc:
            raise CameraError(
                f"{meta_path}: missing or bad n_frames/camera.width/height ({exc})"
            ) from None
        interval = meta.get("frame_interval_s")
        if n < 1:
            raise CameraError(f"{meta_path}: n_frames must be >= 1, got {n}")
        frames = np.empty((n, 2, height, width), dtype=np.uint16)
        for i in range(n):
            f = self.path / f"frame_{i:05d}.npz"
            try:
                with np.load(f, allow_pickle=False) as z:
                    for j, key in enumerate(("left", "right")):
                        arr = z[key]
                        if arr.shape != (height, width) or arr.dtype != np.uint16:
                            raise CameraError(
                                f"{f}: {key} is {arr.shape} {arr.dtype}, expected "
                                f"({height}, {width}) uint16 as in meta.json"
                            )
                        frames[i, j] = arr
            except FileNotFoundError:
                raise CameraError(f"{f}: missing (meta.json says {n} frames)") from None
            except KeyError as exc:
                raise CameraError(f"{f}: no array {exc}") from None
            except (zipfile.BadZipFile, OSError, ValueError) as exc:
                raise CameraError(f"{f}: unreadable ({exc})") from None
        super().__init__(frames, None if interval is None else float(interval))


class TexturePatternSource(_ArraySource):
    """Deterministic textured stereo frames for tests and the simulated default.

    Parameters
    ----------
    n_frames : int
        Number of distinct frames (looped by the camera).
    shape : (int, int)
        (H, W) of each image.
    disparity_px : int
        The right view is the left view shifted left by this many pixels.
    seed : int
        Seed of the background texture.
    """

    def __init__(
        self,
        n_frames: int = 30,
        shape: tuple[int, int] = (240, 320),
        disparity_px: int = 8,
        seed: int = 0,
    ) -> None:
        h, w = shape
        if n_frames < 1 or h < 8 or w < 8 + disparity_px:
            raise ValueError(f"bad pattern size: n_frames={n_frames}, shape={shape}")
        rng = np.random.default_rng(seed)
        wide = w + disparity_px
        noise = rng.standard_normal((h, wide)).astype(np.float32)
        background = cv2.GaussianBlur(noise, (0, 0), 3.0)
        background *= 400.0 / max(float(background.std()), 1e-6)
        yy, xx = np.mgrid[0:h, 0:wide].astype(np.float32)
        frames = np.empty((n_frames, 2, h, w), dtype=np.uint16)
        for k in range(n_frames):
            # A bright blob drifting right across the view, like a warm plume in counts.
            cx = wide * (0.2 + 0.6 * k / max(n_frames, 1))
            cy = h * 0.5
            blob = 1500.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2.0 * (h / 8) ** 2))
            scene = np.clip(8000.0 + background + blob, 0, 65535).astype(np.uint16)
            frames[k, 0] = scene[:, disparity_px:]
            frames[k, 1] = scene[:, :w]
        super().__init__(frames, None)


_cache: dict[str, FrameSource] = {}
_cache_lock = threading.Lock()


def load_source(spec: str | Path | FrameSource) -> FrameSource:
    """Return a shared frame source: ``"pattern"``, a synthetic frame directory, or a source.

    The same spec returns the same object, so a left and a right simulated camera created
    separately from the config share one copy of the frames in memory.
    """
    if isinstance(spec, FrameSource):
        return spec
    key = "pattern" if str(spec) == "pattern" else str(Path(spec).resolve())
    with _cache_lock:
        if key not in _cache:
            _cache[key] = TexturePatternSource() if key == "pattern" else SyntheticDirSource(key)
        return _cache[key]
