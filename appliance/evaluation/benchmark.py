"""Speed of the whole scene-flow chain at 320x240 (issue 3 item 10; ``ogiflow bench``).

Measures, in one run on one input:

- the median wall time of each stage of :func:`processing.chain.compute_scene_flow` (its own
  ``timings_ms``) and of the whole call, over consecutive triples with a warm start through a
  :class:`~processing.chain.ChainState` exactly as the daemon's workers run it, after a
  warm-up (numba loads or compiles its kernels on the first call);
- the median process CPU time of one call (load-independent as long as the process is not
  starved of cache and memory bandwidth);
- OpenCV Farneback flow on the same differential images as a reference, and each stage's
  ratio to it: this machine is shared and noisy, ratios are what stays comparable;
- stereo pairs per second with N worker processes (spawned), each pinned to one OpenCV and
  one numba thread, processing triples back to back for a fixed wall time after its own
  warm-up: completed triples / wall time. In streaming every new stereo pair completes one
  triple, so triples/s = pairs/s.

Input: raw 16-bit stereo frames of a moving gas plume, from the synthetic renderer's
``field`` preset (the appliance's simulated cameras: 30 Hz, plume ~5.5 m away, 1.5 m/s
wind, NETD-like noise 0.03 K and 0.1 px camera jitter) on a 6 cm grid so generating stays a
few seconds; frames are cached in the user cache directory keyed by their parameters. The
``blob`` source is an analytic moving textured blob on a warm textured background (no
simulation; used by the tests and when the renderer is not wanted).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import statistics
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Order in which stages are reported (the chain's ``timings_ms`` keys, without "total").
STAGES: tuple[str, ...] = (
    "preprocess", "flow", "disparity_init", "disparity", "velocity_quality", "segmentation",
    "summary",
)
SOURCES: tuple[str, ...] = ("field", "blob")
FRAME_RATE_HZ = 30.0
#: Geometry of the benchmark (the synthetic cameras': 320x240, s = 780 px, b = 0.2 m).
CAMERA_CONSTANT_PX = 780.0
PRINCIPAL_POINT_PX = (159.5, 119.5)
BASELINE_M = 0.2
IMAGE_SIZE = (320, 240)


@dataclass(frozen=True)
class BenchFrames:
    """A short raw stereo sequence to run the chain on.

    Attributes
    ----------
    left, right : ndarray, shape (N, 240, 320), uint16
        Raw counts of the left and right camera.
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
        h, w = IMAGE_SIZE[1], IMAGE_SIZE[0]
        n = len(self.times_s)
        if n < 3:
            raise ValueError(f"need at least 3 frames, got {n}")
        for name, arr in (("left", self.left), ("right", self.right)):
            if arr.shape != (n, h, w):
                raise ValueError(f"{name} frames have shape {arr.shape}, expected {(n, h, w)}")


def geometry() -> Any:
    """The :class:`~processing.chain.StereoGeometry` of the benchmark (rectified cameras)."""
    from processing.chain import StereoGeometry

    return StereoGeometry(camera_constant=CAMERA_CONSTANT_PX, principal_point=PRINCIPAL_POINT_PX,
                          baseline=BASELINE_M, image_size=IMAGE_SIZE)


def single_thread() -> None:
    """Set a process up as the appliance's workers are: OpenCV and numba on one thread (the
    targets are per core) and glibc's allocator tuned (:mod:`appliance.runtime.tuning`)."""
    import cv2

    from appliance.runtime.tuning import keep_freed_memory

    keep_freed_memory()
    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


# ---------------------------------------------------------------------------- input frames


def _field_config(n_frames: int, seed: int) -> Any:
    from processing.synthetic.sequences import RenderOptions, preset_field

    return preset_field(n_frames=n_frames, b_m=BASELINE_M, voxel_m=0.06, seed=seed,
                        options=RenderOptions(noise_netd_k=0.03, jitter_px=0.1))


def field_frames(n_frames: int = 16, seed: int = 7) -> BenchFrames:
    """Render ``n_frames`` raw stereo frames of the synthetic ``field`` preset (6 cm grid).

    Takes a few seconds (spin-up of the fluid, then 2 steps and 2 renders per frame), plus
    the numba compilation of the simulator on a machine that never ran it.
    """
    from processing.synthetic.sequences import generate_sequence

    cfg = _field_config(n_frames, seed)
    cam = cfg.effective_camera()
    if (cam.width, cam.height) != IMAGE_SIZE or cam.s_px != CAMERA_CONSTANT_PX:
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
    import cv2

    tex = cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), sigma)
    return (tex - tex.mean()) / tex.std()


def blob_frames(n_frames: int = 16, seed: int = 0) -> BenchFrames:
    """Analytic stereo sequence: a textured absorbing blob drifting over a warm background.

    Background: a static smooth texture (~14000 counts +- 300) at 20 m, disparity
    s b / Z = 7.8 px. Gas: a Gaussian envelope (sigma 35 px) with its own texture, 5.5 m
    away (disparity 28.4 px), moving (+4, -2) px per frame and absorbing up to ~600 counts.
    Noise: Gaussian, 15 counts (NETD-like). Counts as uint16.
    """
    import cv2

    w, h = IMAGE_SIZE
    rng = np.random.default_rng(seed)
    pad = 64
    big = (h + 2 * pad, w + 2 * pad)
    bg_tex = 14000.0 + 300.0 * _smooth_texture(rng, big, 6.0)
    gas_tex = 1.0 + 0.5 * _smooth_texture(rng, big, 3.0)
    d_bg = CAMERA_CONSTANT_PX * BASELINE_M / 20.0
    d_gas = CAMERA_CONSTANT_PX * BASELINE_M / 5.5
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)

    def sample(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
        # value at (x + dx, y + dy) of the padded image, bilinear
        return cv2.remap(img.astype(np.float32), xx + pad + dx, yy + pad + dy, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)

    left, right = [], []
    for k in range(n_frames):
        gx, gy = 100.0 + 4.0 * k, 140.0 - 2.0 * k  # blob centre, px
        for view, out in ((0.0, left), (1.0, right)):
            # x_R = x_L - d: the right image at x shows what the left shows at x + d
            bg = sample(bg_tex, view * d_bg, 0.0)
            gx_v = gx - view * d_gas
            env = np.exp(-((xx - gx_v) ** 2 + (yy - gy) ** 2) / (2 * 35.0**2))
            tex = sample(gas_tex, view * d_gas - 4.0 * k, 2.0 * k)
            img = bg - 600.0 * env * tex + rng.normal(0.0, 15.0, (h, w))
            out.append(np.clip(np.rint(img), 0, 65535).astype(np.uint16))
    return BenchFrames(left=np.stack(left), right=np.stack(right),
                       times_s=np.arange(n_frames) / FRAME_RATE_HZ, source="blob")


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/ogiflow/bench`` (``~/.cache/ogiflow/bench``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ogiflow" / "bench"


def _cache_key(source: str, n_frames: int, seed: int) -> str:
    spec: dict[str, Any] = {"source": source, "n_frames": n_frames, "seed": seed, "v": 1}
    if source == "field":
        cfg = _field_config(n_frames, seed)
        spec["config"] = {k: repr(v) for k, v in asdict(cfg).items()}
    text = json.dumps(spec, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_frames(source: str = "field", n_frames: int = 16, seed: int = 7,
                cache_dir: Path | None = None) -> BenchFrames:
    """The bench input, from the cache when present, else generated and cached.

    The cache file name holds a hash of the source, the frame count, the seed and (for
    ``field``) the whole sequence configuration, so a changed preset is regenerated.
    A corrupt cache file is regenerated and overwritten; an unwritable cache directory only
    costs the cache (a warning on stderr).
    """
    if source not in SOURCES:
        raise ValueError(f"unknown bench source {source!r}; choose from {', '.join(SOURCES)}")
    if n_frames < 4:
        raise ValueError(f"need at least 4 frames, got {n_frames}")
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    path = cache_dir / f"{source}-{_cache_key(source, n_frames, seed)}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return BenchFrames(left=z["left"], right=z["right"], times_s=z["times_s"],
                                   source=source)
        except (OSError, ValueError, KeyError):
            pass  # corrupt or from an older layout: regenerate below
    frames = field_frames(n_frames, seed) if source == "field" else blob_frames(n_frames, seed)
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


# ---------------------------------------------------------------------------- measurements


@dataclass(frozen=True)
class StageTimes:
    """Medians over ``runs`` chain calls (ms) and the Farneback reference.

    ``*_cpu_ms`` are process CPU times; the stage times are wall times (the chain's own
    ``timings_ms``). ``stages_cpu_est_ms`` estimates each stage's CPU time: its wall time in
    a call scaled by that call's CPU / wall ratio (assumes the load was even over the call).
    """

    stages_ms: dict[str, float]
    stages_cpu_est_ms: dict[str, float]
    chain_ms: float
    chain_cpu_ms: float
    farneback_ms: float
    farneback_cpu_ms: float
    runs: int

    def ratios(self) -> dict[str, float]:
        """Each stage's and the chain's median over Farneback's median."""
        out = {k: v / self.farneback_ms for k, v in self.stages_ms.items()}
        out["chain"] = self.chain_ms / self.farneback_ms
        return out


def measure_stages(frames: BenchFrames, *, runs: int = 30, warmup: int = 3) -> StageTimes:
    """Median per-stage and whole-chain times in this process, pinned to one thread."""
    from processing.chain import ChainParameters, ChainState, compute_scene_flow
    from processing.opencv_flow import farneback_flow

    if runs < 1 or warmup < 1:
        raise ValueError(f"runs and warmup must be >= 1, got {runs} and {warmup}")
    single_thread()
    geo, params, state = geometry(), ChainParameters(), ChainState()
    triples = iter_triples(frames)
    result = None
    for _ in range(warmup):
        result = compute_scene_flow(*next(triples), geo, params, state)
    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    per_stage_cpu: dict[str, list[float]] = {s: [] for s in STAGES}
    total, cpu = [], []
    for _ in range(runs):
        c0 = time.process_time()
        result = compute_scene_flow(*next(triples), geo, params, state)
        cpu.append((time.process_time() - c0) * 1e3)
        total.append(result.timings_ms["total"])
        cpu_share = cpu[-1] / total[-1]
        for s in STAGES:
            per_stage[s].append(result.timings_ms[s])
            per_stage_cpu[s].append(result.timings_ms[s] * cpu_share)
    assert result is not None
    d0, d1 = result.diff_left

    fb, fb_cpu = [], []
    for i in range(warmup + runs):
        t0, c0 = time.perf_counter(), time.process_time()
        farneback_flow(d0, d1)
        if i >= warmup:
            fb.append((time.perf_counter() - t0) * 1e3)
            fb_cpu.append((time.process_time() - c0) * 1e3)
    return StageTimes(
        stages_ms={s: statistics.median(v) for s, v in per_stage.items()},
        stages_cpu_est_ms={s: statistics.median(v) for s, v in per_stage_cpu.items()},
        chain_ms=statistics.median(total),
        chain_cpu_ms=statistics.median(cpu),
        farneback_ms=statistics.median(fb),
        farneback_cpu_ms=statistics.median(fb_cpu),
        runs=runs,
    )


@dataclass(frozen=True)
class Throughput:
    """Result of one throughput measurement with ``workers`` processes."""

    workers: int
    triples: int
    wall_s: float
    cpu_s: float

    @property
    def pairs_per_s(self) -> float:
        """Completed triples (= new stereo pairs in streaming) per second of wall time."""
        return self.triples / self.wall_s

    @property
    def cpu_ms_per_pair(self) -> float:
        """Process CPU time per triple, summed over the workers."""
        return 1e3 * self.cpu_s / self.triples

    @property
    def pairs_per_cpu_s(self) -> float:
        """Triples per second of CPU time: the pairs/s of one worker on an idle core."""
        return self.triples / self.cpu_s


def _worker(frames: BenchFrames, seconds: float, warmup: int, offset: int,
            barrier: Any, results: Any) -> None:
    """One throughput worker (spawned): warm up, wait for the others, run ``seconds``."""
    os.environ["NUMBA_NUM_THREADS"] = "1"  # before numba is first imported in this process
    os.environ["OMP_NUM_THREADS"] = "1"
    single_thread()
    from processing.chain import ChainParameters, ChainState, compute_scene_flow

    geo, params, state = geometry(), ChainParameters(), ChainState()
    triples = iter_triples(frames)
    for _ in range(offset):  # workers start at different frames, like a real split stream
        next(triples)
    for _ in range(warmup):
        compute_scene_flow(*next(triples), geo, params, state)
    barrier.wait()
    t0, c0 = time.perf_counter(), time.process_time()
    deadline = t0 + seconds
    done = 0
    now = t0
    while now < deadline:
        compute_scene_flow(*next(triples), geo, params, state)
        done += 1
        now = time.perf_counter()
    results.put((done, now - t0, time.process_time() - c0))


def measure_throughput(frames: BenchFrames, workers: int, *, seconds: float = 10.0,
                       warmup: int = 3) -> Throughput:
    """Pairs/s with ``workers`` spawned processes running the chain back to back.

    All workers start together after their own warm-up (a barrier); the wall time is the
    longest of theirs (each stops after the first triple completed past ``seconds``).
    """
    import multiprocessing as mp
    import queue

    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(workers)
    results = ctx.Queue()
    stride = max(1, (len(frames.times_s) - 2) // workers)
    procs = [ctx.Process(target=_worker, args=(frames, seconds, warmup, i * stride, barrier,
                                               results), daemon=True)
             for i in range(workers)]
    for p in procs:
        p.start()
    out = []
    try:
        # generous: spawn + imports + warm-up + the run itself
        limit = time.monotonic() + seconds + 300.0
        while len(out) < workers:
            try:
                out.append(results.get(timeout=1.0))
            except queue.Empty:
                if time.monotonic() > limit or any(
                        p.exitcode not in (None, 0) for p in procs):
                    codes = [p.exitcode for p in procs]
                    raise RuntimeError(f"a bench worker failed (exit codes {codes})") from None
    finally:
        for p in procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join()
    return Throughput(workers=workers, triples=sum(r[0] for r in out),
                      wall_s=max(r[1] for r in out), cpu_s=sum(r[2] for r in out))


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 min load averages (None where the platform has none)."""
    try:
        return os.getloadavg()
    except OSError:
        return None
