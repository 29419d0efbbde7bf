"""Speed of pre-processing and gas segmentation at 320x240 (one core).

Run: ``.venv/bin/python -m benchmarks.bench_preprocess [--runs N] [--json OUT]``

Input: three frames of a static textured background with sub-pixel jitter and a moving,
textured gas blob plus sensor noise (counts-like, ~12 bit). Stages timed (median of
``--runs`` after one warm-up, interleaved over rounds so load spikes hit all of them):

- ``estimate_shift``: one registration (phase correlation + robust Gauss-Newton);
- ``warp``: one bicubic sub-pixel translation;
- ``denoise``: one Sobolev DCT denoising;
- ``preprocess_camera``: one camera's whole triple (2 registrations, 2 warps, 2 differences,
  2 denoisings, 2 normalisations); with the previous triple's shift reused (as the daemon
  would) it does one registration less, reported as ``preprocess_camera_cached``;
- ``segment_gas``: the level set (Eq. 9) on I_diff and a flow field;
- ``farneback``: OpenCV Farneback flow on the same pair, as a yardstick measured in the same
  run (the ratio column divides by it).
Targets: the whole chain <= 100 ms per stereo pair, of which pre-processing of two
cameras and segmentation should take a small part (a few ms each).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from processing.preprocess.denoise import sobolev_denoise
from processing.preprocess.differential import preprocess_camera
from processing.preprocess.registration import estimate_shift
from processing.preprocess.translation import warp_translation
from processing.segmentation.segment import segment_gas


def _frames(h: int = 240, w: int = 320) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    background = cv2.GaussianBlur(rng.uniform(0, 400, (h, w)).astype(np.float32), (0, 0), 3)
    background += np.linspace(2000, 2600, h, dtype=np.float32)[:, None]
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    texture = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 2)
    frames = []
    for t, jitter in enumerate([(0.0, 0.0), (0.3, -0.2), (-0.25, 0.35)]):
        cx, cy = 150 + 2 * t, 110 - t
        gas = 40 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 35.0**2))
        gas *= 1 + 0.5 * np.roll(texture, (-t, 2 * t), axis=(0, 1))
        frame = warp_translation(background + gas, jitter)
        frames.append((frame + rng.normal(0, 2, (h, w))).astype(np.float32))
    return frames


def _median_ms(fn: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="timed runs per stage and round")
    parser.add_argument("--json", type=Path, help="also write the medians as JSON here")
    args = parser.parse_args()
    cv2.setNumThreads(1)

    frames = _frames()
    pre = preprocess_camera(frames, scale=40.0, denoise_lambda=10.0)
    u8 = [(np.clip(d, 0, 1) * 255).astype(np.uint8) for d in (pre.diff0, pre.diff1)]
    flow = cv2.calcOpticalFlowFarneback(u8[0], u8[1], None, 0.5, 3, 15, 3, 5, 1.2, 0)
    stages: dict[str, Callable[[], object]] = {
        "estimate_shift": lambda: estimate_shift(frames[0], frames[1]),
        "warp": lambda: warp_translation(frames[1], (0.3, -0.2)),
        "denoise": lambda: sobolev_denoise(pre.raw0, 10.0),
        "preprocess_camera": lambda: preprocess_camera(frames, scale=40.0, denoise_lambda=10.0),
        "preprocess_camera_cached": lambda: preprocess_camera(
            frames, scale=40.0, denoise_lambda=10.0, shift01=pre.shifts[0]
        ),
        "segment_gas": lambda: segment_gas(pre.diff0, flow),
        "farneback": lambda: cv2.calcOpticalFlowFarneback(
            u8[0], u8[1], None, 0.5, 3, 15, 3, 5, 1.2, 0
        ),
    }
    for fn in stages.values():  # warm-up (numba compilation, FFT plans)
        fn()
    rounds = 3
    results: dict[str, list[float]] = {k: [] for k in stages}
    for _ in range(rounds):
        for name, fn in stages.items():
            results[name].append(_median_ms(fn, args.runs))
    medians = {k: statistics.median(v) for k, v in results.items()}
    ref = medians["farneback"]
    print(f"320x240, one thread, median of {args.runs} runs x {rounds} rounds")
    print(f"{'stage':<26} {'ms':>8} {'/ farneback':>12}")
    for name, ms in medians.items():
        print(f"{name:<26} {ms:>8.2f} {ms / ref:>12.2f}")
    seg = segment_gas(pre.diff0, flow)
    print(f"(segmented gas fraction of the benchmark frame: {100 * seg.mask.mean():.1f} %)")
    if args.json is not None:
        args.json.write_text(json.dumps({"stages_ms": medians}, indent=2) + "\n")


if __name__ == "__main__":
    main()
