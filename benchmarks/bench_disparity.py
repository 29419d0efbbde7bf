"""Speed of the joint disparity solver (paper Eq. 6) at 320x240 on one core.

Input resembles stereo differential gas images: smooth multi-scale blobs inside a
plume-shaped region on a flat background, camera noise, a right view displaced by a
smoothly varying disparity (about 20 px) and a second time step moved by about 2 px.
Prints the median of many runs after warm-up for the joint solver, and for reference, in
the same run, our Brox flow (Eq. 5) and OpenCV Farneback at the same size, with ratios:
on a shared machine absolute times vary, the ratios much less.

Run from the repository root:  python benchmarks/bench_disparity.py [--runs N] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cv2
import numpy as np

from processing.flow.brox import brox_optical_flow
from processing.metrics.baselines import farneback_flow
from processing.stereo.joint import joint_disparity

H, W = 240, 320


def _scene(seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    big_h, big_w = H + 40, W + 80
    tex = np.zeros((big_h, big_w), np.float32)
    for sigma in (2.0, 4.0, 8.0):
        layer = cv2.GaussianBlur(rng.standard_normal((big_h, big_w)).astype(np.float32),
                                 (0, 0), sigma)
        tex += layer / layer.std()
    yy, xx = np.mgrid[0:big_h, 0:big_w].astype(np.float32)
    plume = np.exp(-(((xx - big_w * 0.45) / 70.0) ** 2 + ((yy - big_h * 0.6) / 60.0) ** 2))
    base = 0.5 + 0.12 * tex * plume
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    disp = 20.0 + 3.0 * np.sin(xs / 60.0) * np.cos(ys / 50.0)

    def view(dx: np.ndarray | float, dy: float) -> np.ndarray:
        img = cv2.remap(base, xs + 40 + dx, ys + 20 + dy, cv2.INTER_CUBIC)
        img = img + rng.normal(0.0, 0.005, img.shape).astype(np.float32)
        return np.clip(img, 0.0, 1.0).astype(np.float32)

    # Left at t0 / t1 (moved by (1.5, -2) px), right displaced by the disparity (x_R = x - d).
    return view(0.0, 0.0), view(disp, 0.0), view(-1.5, 2.0), view(disp + 0.3 - 1.5, 2.0)


def _median_ms(fn, runs: int) -> tuple[float, float]:
    """Median wall-clock and median CPU time (ms) of ``fn`` after warm-up.

    The CPU time (``time.thread_time``) leaves out the time this thread waited for a core,
    so on a busy machine it is the closer estimate of the one-core cost.
    """
    for _ in range(3):
        fn()
    wall, cpu = [], []
    for _ in range(runs):
        t, c = time.perf_counter(), time.thread_time()
        fn()
        cpu.append((time.thread_time() - c) * 1e3)
        wall.append((time.perf_counter() - t) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=30, help="timed runs per method")
    parser.add_argument("--json", type=Path, help="write the medians to this file")
    args = parser.parse_args()
    # One core: numba code here is single-threaded; OpenCV is told to be. (No CPU pinning:
    # on a shared machine pinning everyone to the same core would distort the numbers.)
    cv2.setNumThreads(1)
    il0, ir0, il1, ir1 = _scene()
    flow = brox_optical_flow(il0, il1)
    runs = {
        "joint_disparity": _median_ms(
            lambda: joint_disparity(il0, ir0, il1, ir1, flow, d0=15.0), args.runs),
        "brox_flow": _median_ms(lambda: brox_optical_flow(il0, il1), args.runs),
        "farneback": _median_ms(lambda: farneback_flow(il0, il1), args.runs),
    }
    res: dict[str, float] = {}
    for name, (wall, cpu) in runs.items():
        res[f"{name}_ms"] = wall
        res[f"{name}_cpu_ms"] = cpu
    res["ratio_to_brox"] = res["joint_disparity_ms"] / res["brox_flow_ms"]
    res["ratio_to_farneback"] = res["joint_disparity_ms"] / res["farneback_ms"]
    d, dp = joint_disparity(il0, ir0, il1, ir1, flow, d0=15.0)
    print(f"320x240, one core, median of {args.runs} runs after warm-up "
          f"(wall-clock / CPU time of this thread)")
    print(f"  joint d/d' (Eq. 6):  {res['joint_disparity_ms']:7.1f} / "
          f"{res['joint_disparity_cpu_ms']:7.1f} ms  (target <= 45 ms)")
    print(f"  Brox flow (Eq. 5):   {res['brox_flow_ms']:7.1f} / {res['brox_flow_cpu_ms']:7.1f} ms"
          f"  (joint/Brox = {res['ratio_to_brox']:.2f})")
    print(f"  Farneback:           {res['farneback_ms']:7.1f} / {res['farneback_cpu_ms']:7.1f} ms"
          f"  (joint/Farneback = {res['ratio_to_farneback']:.2f})")
    print(f"  sanity: median d = {np.median(d[20:-20, 60:-20]):.2f} px (about 20), "
          f"median d' = {np.median(dp[20:-20, 60:-20]):.2f} px (about 0.3)")
    if args.json:
        args.json.write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
