"""Input of ``ogiflow bench``: raw stereo frames of a moving gas plume, cached.

Two sources: ``field``, raw 16-bit stereo frames from the synthetic renderer's ``field``
preset (the appliance's simulated cameras: 30 Hz, plume ~5.5 m away, 1.5 m/s wind, NETD-like
noise 0.03 K and 0.1 px camera jitter) on a 6 cm grid so generating stays a few seconds
(about four times that at 640x480), cached in the user cache directory keyed by their
parameters; ``blob``, an analytic moving textured blob on a warm textured background (no
simulation; used by the tests). Sizes: 320x240 (default) and 640x480, the field preset's
(:data:`~processing.synthetic.presets.FIELD_IMAGE_SIZES`); a 640x480 camera has twice the
camera constant (same field of view), so every disparity and motion in px doubles.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from processing.chain import StereoGeometry
from processing.synthetic.presets import FIELD_IMAGE_SIZES, field_camera
from processing.synthetic.sequences import RenderOptions, generate_sequence, preset_field

SOURCES: tuple[str, ...] = ("field", "blob")
FRAME_RATE_HZ = 30.0
#: Geometry of the benchmark (the synthetic cameras': 320x240, s = 780 px, b = 0.2 m; at
#: 640x480 s = 1560 px).
BASELINE_M = 0.2
IMAGE_SIZE = (320, 240)
#: Image sizes (W, H) the bench runs at.
SIZES: tuple[tuple[int, int], ...] = FIELD_IMAGE_SIZES


@dataclass(frozen=True)
class BenchFrames:
    """A short raw stereo sequence to run the chain on.

    Attributes
    ----------
    left, right : ndarray, shape (N, H, W), uint16
        Raw counts of the left and right camera (a size of :data:`SIZES`).
    times_s : ndarray, shape (N,), float64
        Capture times in s (30 Hz).
    source : str
        "field" or "blob" (see the module docstring).
    """

    left: np.ndarray
    right: np.ndarray
    times_s: np.ndarray
    source: str

    def __post_init__(self) -> None:
        n = len(self.times_s)
        if n < 3:
            raise ValueError(f"need at least 3 frames, got {n}")
        h, w = self.left.shape[1:] if self.left.ndim == 3 else (0, 0)
        if (w, h) not in SIZES:
            raise ValueError(f"frames of shape {self.left.shape}: expected (N, H, W) with "
                             f"(W, H) one of {SIZES}")
        for name, arr in (("left", self.left), ("right", self.right)):
            if arr.shape != (n, h, w):
                raise ValueError(f"{name} frames have shape {arr.shape}, expected {(n, h, w)}")

    @property
    def image_size(self) -> tuple[int, int]:
        """(W, H) of the frames, px."""
        return int(self.left.shape[2]), int(self.left.shape[1])


def geometry(image_size: tuple[int, int] = IMAGE_SIZE) -> Any:
    """The :class:`~processing.chain.StereoGeometry` of the benchmark (rectified cameras) at
    ``image_size`` (W, H): the field preset's camera with the bench's baseline."""

    cam = field_camera(image_size, BASELINE_M)
    return StereoGeometry(camera_constant=cam.s_px, principal_point=(cam.cx, cam.cy),
                          baseline=BASELINE_M, image_size=(cam.width, cam.height))


# ---------------------------------------------------------------------------- input frames


def _field_config(n_frames: int, seed: int, image_size: tuple[int, int] = IMAGE_SIZE) -> Any:

    return preset_field(n_frames=n_frames, b_m=BASELINE_M, voxel_m=0.06, seed=seed,
                        image_size=image_size,
                        options=RenderOptions(noise_netd_k=0.03, jitter_px=0.1))


def field_frames(n_frames: int = 16, seed: int = 7,
                 image_size: tuple[int, int] = IMAGE_SIZE) -> BenchFrames:
    """Render ``n_frames`` raw stereo frames of the synthetic ``field`` preset (6 cm grid)
    at ``image_size`` (W, H).

    Takes a few seconds at 320x240 (spin-up of the fluid, then 2 steps and 2 renders per
    frame; the renders about 4x longer at 640x480), plus the numba compilation of the
    simulator on a machine that never ran it.
    """

    cfg = _field_config(n_frames, seed, image_size)
    cam = cfg.effective_camera()
    geo = geometry(image_size)
    if (cam.width, cam.height) != geo.image_size or cam.s_px != geo.camera_constant:
        raise RuntimeError("the field preset's camera no longer matches the bench geometry")
    frames = list(generate_sequence(cfg))
    return BenchFrames(
        left=np.stack([f.left for f in frames]).astype(np.uint16),
        right=np.stack([f.right for f in frames]).astype(np.uint16),
        times_s=np.array([f.t_s for f in frames], dtype=np.float64),
        source="field",
    )


def _smooth_texture(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Zero-mean, unit-std smooth random texture (float32)."""
    tex = cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), sigma)
    return (tex - tex.mean()) / tex.std()


def blob_frames(n_frames: int = 16, seed: int = 0,
                image_size: tuple[int, int] = IMAGE_SIZE) -> BenchFrames:
    """Analytic stereo sequence: a textured absorbing blob drifting over a warm background.

    At 320x240 (everything in px scales with the width ``k = W / 320``): background a
    static smooth texture (~14000 counts +- 300) at 20 m, disparity s b / Z = 7.8 px. Gas: a
    Gaussian envelope (sigma 35 px) with its own texture, 5.5 m away (disparity 28.4 px),
    moving (+4, -2) px per frame and absorbing up to ~600 counts. Noise: Gaussian, 15
    counts (NETD-like). Counts as uint16.
    """
    geo = geometry(image_size)
    w, h = geo.image_size
    k_px = w / IMAGE_SIZE[0]
    rng = np.random.default_rng(seed)
    pad = round(64 * k_px)
    big = (h + 2 * pad, w + 2 * pad)
    bg_tex = 14000.0 + 300.0 * _smooth_texture(rng, big, 6.0 * k_px)
    gas_tex = 1.0 + 0.5 * _smooth_texture(rng, big, 3.0 * k_px)
    d_bg = geo.camera_constant * BASELINE_M / 20.0
    d_gas = geo.camera_constant * BASELINE_M / 5.5
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)

    def sample(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
        # value at (x + dx, y + dy) of the padded image, bilinear
        return cv2.remap(img.astype(np.float32), xx + pad + dx, yy + pad + dy, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)

    left, right = [], []
    for k in range(n_frames):
        gx, gy = k_px * (100.0 + 4.0 * k), k_px * (140.0 - 2.0 * k)  # blob centre, px
        for view, out in ((0.0, left), (1.0, right)):
            # x_R = x_L - d: the right image at x shows what the left shows at x + d
            bg = sample(bg_tex, view * d_bg, 0.0)
            gx_v = gx - view * d_gas
            env = np.exp(-((xx - gx_v) ** 2 + (yy - gy) ** 2) / (2 * (35.0 * k_px) ** 2))
            tex = sample(gas_tex, view * d_gas - 4.0 * k_px * k, 2.0 * k_px * k)
            img = bg - 600.0 * env * tex + rng.normal(0.0, 15.0, (h, w))
            out.append(np.clip(np.rint(img), 0, 65535).astype(np.uint16))
    return BenchFrames(left=np.stack(left), right=np.stack(right),
                       times_s=np.arange(n_frames) / FRAME_RATE_HZ, source="blob")


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/ogiflow/bench`` (``~/.cache/ogiflow/bench``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ogiflow" / "bench"


def _cache_key(source: str, n_frames: int, seed: int,
               image_size: tuple[int, int] = IMAGE_SIZE) -> str:
    spec: dict[str, Any] = {"source": source, "n_frames": n_frames, "seed": seed, "v": 1}
    if tuple(image_size) != IMAGE_SIZE:  # 320x240 keeps the keys it had: caches stay valid
        spec["size"] = list(image_size)
    if source == "field":
        cfg = _field_config(n_frames, seed, image_size)
        spec["config"] = {k: repr(v) for k, v in asdict(cfg).items()}
    text = json.dumps(spec, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_frames(source: str = "field", n_frames: int = 16, seed: int = 7,
                cache_dir: Path | None = None,
                image_size: tuple[int, int] = IMAGE_SIZE) -> BenchFrames:
    """The bench input at ``image_size`` (W, H), from the cache when present, else generated
    and cached.

    The cache file name holds a hash of the source, the frame count, the seed, the size and
    (for ``field``) the whole sequence configuration, so a changed preset is regenerated.
    A corrupt cache file is regenerated and overwritten; an unwritable cache directory only
    costs the cache (a warning on stderr).
    """
    if source not in SOURCES:
        raise ValueError(f"unknown bench source {source!r}; choose from {', '.join(SOURCES)}")
    if n_frames < 4:
        raise ValueError(f"need at least 4 frames, got {n_frames}")
    image_size = (int(image_size[0]), int(image_size[1]))
    if image_size not in SIZES:
        raise ValueError(f"unknown bench size {image_size[0]}x{image_size[1]}; choose from "
                         + ", ".join(f"{w}x{h}" for w, h in SIZES))
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    path = cache_dir / f"{source}-{_cache_key(source, n_frames, seed, image_size)}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return BenchFrames(left=z["left"], right=z["right"], times_s=z["times_s"],
                                   source=source)
        except (OSError, ValueError, KeyError):
            pass  # corrupt or from an older layout: regenerate below
    make = field_frames if source == "field" else blob_frames
    frames = make(n_frames, seed, image_size)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        np.savez(tmp, left=frames.left, right=frames.right, times_s=frames.times_s)
        os.replace(tmp, path)
    except OSError as exc:  # a read-only home (e.g. under systemd) only costs the cache
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        print(f"ogiflow bench: input not cached ({exc})", file=sys.stderr)
    return frames


def iter_triples(frames: BenchFrames) -> Iterator[tuple[list[np.ndarray], list[np.ndarray],
                                                       tuple[float, float, float]]]:
    """Endless consecutive triples (k, k+1, k+2), cycling through the sequence.

    Times keep increasing across a wrap, with a one-frame gap there, so the chain sees the
    wrap as a dropped frame (cold start), as it would in the field, not as a continuation.
    """
    n = len(frames.times_s)
    period = (n + 1) / FRAME_RATE_HZ
    lap = 0
    while True:
        for k in range(n - 2):
            t = tuple(float(frames.times_s[k + i] + lap * period) for i in range(3))
            yield (
                [frames.left[k + i] for i in range(3)],
                [frames.right[k + i] for i in range(3)],
                (t[0], t[1], t[2]),
            )
        lap += 1
