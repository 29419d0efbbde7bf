"""One pyramid level of the flow solver (Eq. 5) against OpenCV's VariationalRefinement.

Run: ``.venv/bin/python -m benchmarks.bench_flow_level [--runs N]``

A warm triple's flow solves each pyramid level with 2 lagged fixed-point iterations of
8 red-black SOR sweeps from the previous triple's flow. OpenCV's ``VariationalRefinement``
(the last stage of its DIS flow, C++ with SIMD) minimises the same kind of energy
(Charbonnier data terms on brightness and gradient constancy, Charbonnier smoothness,
lagged fixed point, red-black SOR) on one level from a given flow. Both run here with that
schedule on the same differential-image-like pair (OpenCV's as 8-bit images, which it
requires), one thread, at the full 320x240 frame and at 208x160 (the bench's typical
active-region box). The chain's level includes what it does around the solve (warping,
the 5-tap derivatives, input checks); OpenCV's computes its own derivatives too. The ratio
says how much of the solvers' time is implementation rather than the number of passes
(docs/performance.md, "What stands between the warm chain and 2.5x Farneback").
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from benchmarks.common import differential_like_pair, median_ms, single_thread
from processing.flow.brox import brox_optical_flow

#: The warm schedule of a level: lagged fixed-point iterations x SOR sweeps.
N_INNER, N_SOR = 2, 8
SIZES = ((240, 320), (160, 208))


def main(argv: list[str] | None = None) -> int:
    """Print both solvers' median level time per size and their ratio; exit status 0."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=30)
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    single_thread()
    refine = cv2.VariationalRefinement.create()
    refine.setFixedPointIterations(N_INNER)
    refine.setSorIterations(N_SOR)
    print(f"one level, {N_INNER} lagged iterations x {N_SOR} SOR sweeps from zero flow, "
          f"median of {args.runs} runs x 3 rounds after warm-up, one thread")
    for shape in SIZES:
        f0, f1 = differential_like_pair(shape)
        g0, g1 = (np.clip(np.rint(f * 255.0), 0, 255).astype(np.uint8) for f in (f0, f1))
        start = np.zeros((*shape, 2), np.float32)

        def ours(f0: np.ndarray = f0, f1: np.ndarray = f1, start: np.ndarray = start) -> None:
            brox_optical_flow(f0, f1, initial_flow=start, n_levels=1, n_inner=N_INNER,
                              n_sor=N_SOR)

        def opencv(g0: np.ndarray = g0, g1: np.ndarray = g1,
                   start: np.ndarray = start) -> None:
            refine.calc(g0, g1, start.copy())

        # Interleaved rounds, so that a load spike hits both.
        chain, other = [], []
        for _ in range(3):
            chain.append(median_ms(ours, runs=args.runs))
            other.append(median_ms(opencv, runs=args.runs))
        a, b = sorted(chain)[1], sorted(other)[1]
        print(f"  {shape[1]}x{shape[0]}: the chain's level {a:6.2f} ms, OpenCV "
              f"VariationalRefinement {b:6.2f} ms, ratio {a / b:4.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
