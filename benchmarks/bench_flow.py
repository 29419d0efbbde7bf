"""Brox optical flow speed at 320x240 on differential-image-like input.

Run: ``.venv/bin/python -m benchmarks.bench_flow [--runs N]``

Prints the median ms per frame pair of our flow (default parameters) and, measured in
the same run, OpenCV Farneback and DIS medium (all on one thread), with the ratios.
Target: median <= 30 ms on one core of the reference machine.
"""

from __future__ import annotations

import argparse
import json

from benchmarks.common import differential_like_pair, median_ms, single_thread
from processing.flow.brox import brox_optical_flow
from processing.flow.opencv import dis_flow, farneback_flow


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--json", help="also write the numbers as JSON to this file")
    args = parser.parse_args()
    single_thread()
    f0, f1 = differential_like_pair()
    # Interleave the methods over several rounds so that load spikes hit all of them.
    rounds = 3
    totals: dict[str, list[float]] = {"brox": [], "farneback": [], "dis_medium": []}
    for _ in range(rounds):
        totals["brox"].append(median_ms(lambda: brox_optical_flow(f0, f1), runs=args.runs))
        totals["farneback"].append(median_ms(lambda: farneback_flow(f0, f1), runs=args.runs))
        totals["dis_medium"].append(median_ms(lambda: dis_flow(f0, f1), runs=args.runs))
    ms = {k: sorted(v)[len(v) // 2] for k, v in totals.items()}
    print(f"320x240, {args.runs} runs x {rounds} rounds after warm-up, one thread")
    for name, value in ms.items():
        print(
            f"  {name:11s} {value:7.1f} ms/frame"
            f"   ratio to Farneback {value / ms['farneback']:5.2f}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"ms": ms, "ratio_to_farneback": ms["brox"] / ms["farneback"]}, f, indent=2)


if __name__ == "__main__":
    main()
