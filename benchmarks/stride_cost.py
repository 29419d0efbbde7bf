"""CPU time of a warm triple when a worker takes every triple or every other one.

Run from the repository root (nothing else running: the numbers are CPU times of one core):

    PYTHONPATH=. python benchmarks/stride_cost.py [--stride 1 2] [--triples N] [--config FILE]
        [--source {field,blob}]

With two workers each takes every other triple, starts warm from its own triple two frames
back (the flow's whole pyramid, ``far_warm_flow_options``) and finds this triple's D(t0)
only if the other worker has published it. This runs one chain state in one process on the
bench input of ``ogiflow bench`` (the ``field`` plume at 320x240, 62 frames, cached), taking
every ``stride``-th triple with no image sharing (the case where the other worker was not
yet done), and prints the median and mean process CPU time per warm triple for each stride:
the difference is what a triple of a two-worker daemon costs more than a consecutive one
(docs/performance.md, "What stands between the warm chain and 2.5x Farneback").
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from appliance.evaluation.bench_input import BenchFrames, geometry, iter_triples, load_frames
from appliance.evaluation.benchmark import THROUGHPUT_MIN_FRAMES, single_thread
from appliance.evaluation.sceneflow_setup import load_processing
from appliance.memory import keep_freed_memory
from processing.chain import ChainParameters, ChainState, compute_scene_flow

#: Triples run before the timed ones (compilation, the first cold start).
WARMUP = 10


def warm_cpu_ms(frames: BenchFrames, params: ChainParameters, stride: int, triples: int
                ) -> list[float]:
    """Process CPU time in ms of each warm triple after :data:`WARMUP`, the chain taking
    every ``stride``-th of ``triples`` consecutive triples through one state."""
    if stride < 1 or triples < stride:
        raise ValueError(f"need stride >= 1 and triples >= stride, got {stride}, {triples}")
    geo = geometry(frames.image_size)
    state = ChainState(stride=stride)
    source = iter_triples(frames)
    out: list[float] = []
    for i in range(WARMUP + triples // stride):
        c0 = time.process_time()
        result = compute_scene_flow(*next(source), geo, params, state)
        cpu = time.process_time() - c0
        for _ in range(stride - 1):
            next(source)
        if i >= WARMUP and result.warm:
            out.append(1e3 * cpu)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stride", type=int, nargs="+", default=[1, 2],
                    help="take every N-th triple; one run per value (default 1 2)")
    ap.add_argument("--triples", type=int, default=300,
                    help="consecutive triples each run walks through (default 300)")
    ap.add_argument("--config", type=Path, default=None,
                    help="a configuration file whose processing.parameters to run")
    ap.add_argument("--source", choices=("field", "blob"), default="field")
    args = ap.parse_args(argv)
    single_thread()
    keep_freed_memory()
    params = load_processing(args.config).chain_parameters({})
    frames = load_frames(args.source, THROUGHPUT_MIN_FRAMES)
    for stride in args.stride:
        cpu = warm_cpu_ms(frames, params, stride, args.triples)
        if not cpu:
            print(f"stride {stride}: no warm triple timed")
            continue
        print(f"stride {stride}: warm triple CPU median {np.median(cpu):.2f} ms, "
              f"mean {np.mean(cpu):.2f} ms over {len(cpu)} triples")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
