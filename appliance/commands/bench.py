"""``ogiflow bench``: speed of the whole scene-flow chain at 320x240 (issue 3 item 10).

See :mod:`appliance.evaluation.benchmark` for what is measured and on which input.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from appliance import cli


def register(root: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand."""
    p = root.add_parser(
        "bench",
        help="time every stage of the scene-flow chain and pairs/s with 1..N workers",
        description=(
            "Runs the scene-flow chain (compute_scene_flow, the daemon's code) at 320x240 on "
            "raw 16-bit stereo frames of a moving gas plume and reports: the median wall time "
            "of each stage and of the whole chain over consecutive triples after a warm-up "
            "(one OpenCV and one numba thread), the median CPU time of a call, OpenCV "
            "Farneback on the same differential images with each stage's ratio to it (the "
            "ratio stays comparable on a loaded machine), and stereo pairs per second with "
            "1..N spawned worker processes each running triples back to back for --seconds. "
            "The machine load is printed with the numbers: on a shared machine wall times "
            "grow with the load, CPU times and ratios much less."
        ),
        epilog="example: ogiflow bench --json bench.json",
    )
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"stages_ms": {...}, "chain_ms": ..., "pairs_per_s": '
                        '{"1": ..., "2": ...}} plus reference and load fields to OUT')
    p.add_argument("--seconds", type=float, default=10.0, metavar="S",
                   help="wall time of each throughput measurement, s (default 10)")
    p.add_argument("--runs", type=int, default=30, metavar="N",
                   help="chain calls timed for the stage medians (default 30)")
    p.add_argument("--warmup", type=int, default=3, metavar="N",
                   help="untimed chain calls first, in every process (default 3)")
    p.add_argument("--workers-max", type=int, default=2, metavar="N",
                   help="measure pairs/s with 1..N worker processes (default 2)")
    p.add_argument("--source", choices=("field", "blob"), default="field",
                   help="input: 'field' = synthetic gas plume from the renderer's field preset "
                        "(default; generated once, then cached), 'blob' = analytic moving "
                        "textured blob (no simulation)")
    p.add_argument("--frames", type=int, default=16, metavar="N",
                   help="length of the input sequence, cycled through (default 16)")
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="where generated input is cached (default ~/.cache/ogiflow/bench)")
    p.set_defaults(func=run)


def _check_args(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise ValueError(f"--seconds must be a positive number, got {args.seconds}")
    if args.runs < 1:
        raise ValueError(f"--runs must be >= 1, got {args.runs}")
    if args.warmup < 1:
        raise ValueError(f"--warmup must be >= 1 (the first call compiles), got {args.warmup}")
    if args.workers_max < 1:
        raise ValueError(f"--workers-max must be >= 1, got {args.workers_max}")
    if args.frames < 4:
        raise ValueError(f"--frames must be >= 4, got {args.frames}")


def run(args: argparse.Namespace) -> int:
    """Measure and print (and optionally write) the chain's speed."""
    _check_args(args)
    from appliance.evaluation import benchmark as bm

    load_start = bm.load_average()
    frames = bm.load_frames(args.source, n_frames=args.frames, cache_dir=args.cache_dir)
    try:
        st = bm.measure_stages(frames, runs=args.runs, warmup=args.warmup)
        through = [bm.measure_throughput(frames, n, seconds=args.seconds, warmup=args.warmup)
                   for n in range(1, args.workers_max + 1)]
    except RuntimeError as exc:
        raise cli.CommandError(str(exc)) from exc
    load_end = bm.load_average()

    ratios = st.ratios()
    print(f"input: {args.source}, {len(frames.times_s)} frames 320x240 uint16 cycled; "
          f"{st.runs} timed chain calls after {args.warmup} warm-up; 1 thread per process")
    print(f"{'stage':<16}{'median ms':>10}{'x Farneback':>13}{'CPU ms (est.)':>15}")
    for name, ms in st.stages_ms.items():
        print(f"{name:<16}{ms:>10.2f}{ratios[name]:>13.2f}{st.stages_cpu_est_ms[name]:>15.2f}")
    print(f"{'chain (total)':<16}{st.chain_ms:>10.2f}{ratios['chain']:>13.2f}"
          f"{st.chain_cpu_ms:>15.2f}")
    print("CPU ms: process CPU time of a call (measured; per stage estimated from the "
          "call's CPU/wall ratio)")
    print(f"Farneback reference (OpenCV, same differential images): {st.farneback_ms:.2f} ms "
          f"wall, {st.farneback_cpu_ms:.2f} ms CPU")
    for t in through:
        print(f"{t.workers} worker(s): {t.pairs_per_s:.2f} pairs/s "
              f"({t.triples} triples in {t.wall_s:.1f} s; {t.cpu_ms_per_pair:.1f} ms CPU each, "
              f"{t.pairs_per_cpu_s:.2f} pairs per CPU-second)")
    if load_start is not None and load_end is not None:
        print(f"load average (1/5/15 min): start {_fmt_load(load_start)}, "
              f"end {_fmt_load(load_end)} on {_cpu_count()} CPUs")

    if args.json is not None:
        out: dict[str, Any] = {
            "stages_ms": st.stages_ms,
            "chain_ms": st.chain_ms,
            "pairs_per_s": {str(t.workers): t.pairs_per_s for t in through},
            "chain_cpu_ms": st.chain_cpu_ms,
            "stages_cpu_est_ms": st.stages_cpu_est_ms,
            "cpu_ms_per_pair": {str(t.workers): t.cpu_ms_per_pair for t in through},
            "pairs_per_cpu_s": {str(t.workers): t.pairs_per_cpu_s for t in through},
            "farneback_ms": st.farneback_ms,
            "farneback_cpu_ms": st.farneback_cpu_ms,
            "ratio_to_farneback": ratios,
            "source": args.source,
            "runs": st.runs,
            "seconds": args.seconds,
            "load_average": {"start": load_start, "end": load_end, "cpus": _cpu_count()},
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return cli.EXIT_OK


def _fmt_load(load: tuple[float, float, float]) -> str:
    return "/".join(f"{x:.2f}" for x in load)


def _cpu_count() -> int:
    import os

    return os.cpu_count() or 1
