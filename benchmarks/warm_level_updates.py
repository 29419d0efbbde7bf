"""How far each pyramid level of a warm triple moves the fields: where the iterations go.

Run from the repository root:

    PYTHONPATH=. python benchmarks/warm_level_updates.py [--triples N] [--config FILE]
        [--source {field,blob}]

Runs the chain (default parameters with the solvers on the whole frame, since the active
region's box changes the levels' sizes from triple to triple; or a configuration file's
``processing.parameters``) on the bench input of ``ogiflow bench`` (the ``field`` plume at
320x240, cached) through one chain state, as a worker does, and records for every solver
call of a warm triple the mean absolute change each pyramid level makes to its two unknowns -
(u, v) for the flow (Eq. 5), (d, d') for the disparity (Eq. 6) - in pixels of the finest
level. Prints, per
solver and level, the median over the warm triples of that mean change and its 99th
percentile over the pixels. A level that moves its fields by a few thousandths of a pixel
buys little with its iterations; a coarse level that still moves them by tenths is where
the warm start is not yet close (docs/performance.md, "Fewer passes on a warm start").
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from appliance.evaluation.bench_input import BenchFrames, geometry, iter_triples, load_frames
from appliance.evaluation.sceneflow_setup import load_processing
from processing.chain import ChainParameters, ChainState, SceneFlowResult, compute_scene_flow
from processing.solvers import lagged

#: (solver, level width) -> per warm triple: (mean |dx1|, mean |dx2|, p99 |dx1|), finest px.
Updates = dict[tuple[str, int], list[tuple[float, float, float]]]


def _recording(inner: Callable[..., None], log: list[tuple[str, int, float, float, float]]
               ) -> Callable[..., None]:
    """``lagged_iterations`` that also logs the change it made to both unknowns."""
    def run(terms: Any, x1: np.ndarray, x2: np.ndarray, *args: Any) -> None:
        before1, before2 = x1.copy(), x2.copy()
        inner(terms, x1, x2, *args)
        # in the level's own px; measure() converts them to px of the finest level
        log.append((type(terms).__name__.strip("_").removesuffix("Terms"), x1.shape[1],
                    float(np.mean(np.abs(x1 - before1))), float(np.mean(np.abs(x2 - before2))),
                    float(np.percentile(np.abs(x1 - before1), 99))))
    return run


def measure(frames: BenchFrames, params: ChainParameters, n_triples: int,
            results: list[SceneFlowResult] | None = None) -> Updates:
    """The per-level changes of ``n_triples`` consecutive triples of ``frames`` (cold ones
    left out), keyed by (solver, level width). The chain's results, appended to ``results``
    when given, are those of an unwatched run."""
    geo = geometry(frames.image_size)
    state = ChainState()
    triples = iter_triples(frames)
    log: list[tuple[str, int, float, float, float]] = []
    original = lagged.lagged_iterations
    # Both solvers call the skeleton through this module attribute.
    lagged.lagged_iterations = _recording(original, log)  # type: ignore[assignment]
    updates: Updates = defaultdict(list)
    try:
        for _ in range(n_triples):
            log.clear()
            result = compute_scene_flow(*next(triples), geo, params, state)
            if results is not None:
                results.append(result)
            if not result.warm:
                continue
            finest = max(width for _, width, *_ in log)
            for solver, width, m1, m2, p99 in log:
                scale = finest / width
                updates[(solver, width)].append((m1 * scale, m2 * scale, p99 * scale))
    finally:
        lagged.lagged_iterations = original  # type: ignore[assignment]
    return updates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triples", type=int, default=30, help="consecutive triples (default 30)")
    ap.add_argument("--config", type=Path, help="a configuration file's processing.parameters")
    ap.add_argument("--source", choices=("field", "blob"), default="field",
                    help="the bench's input (default: the field plume)")
    args = ap.parse_args()
    params = (ChainParameters(active_region=False) if args.config is None
              else load_processing(args.config).chain_parameters({}))
    updates = measure(load_frames(args.source), params, args.triples)
    print("median over warm triples; changes in px of the finest level")
    print(f"{'solver':<10} {'level width':>11} {'mean |x1|':>10} {'mean |x2|':>10} "
          f"{'p99 |x1|':>9} {'triples':>8}")
    for (solver, width), rows in sorted(updates.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        a = np.median(np.array(rows), axis=0)
        print(f"{solver:<10} {width:>11} {a[0]:>10.5f} {a[1]:>10.5f} {a[2]:>9.3f} "
              f"{len(rows):>8}")
    print("x1, x2: u, v for the flow; d, d' for the disparity")


if __name__ == "__main__":
    main()
