"""``ogiflow bench``: speed of the whole scene-flow chain at 320x240 or 640x480.

See :mod:`appliance.evaluation.benchmark` for what is measured and on which input.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
from typing import Any

from appliance import cli


def register(root: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand."""
    p = root.add_parser(
        "bench",
        help="time every stage of the scene-flow chain and pairs/s with 1..N workers",
        description=(
            "Runs the scene-flow chain (compute_scene_flow, the daemon's code, default "
            "parameters or --config's) at 320x240 (or --size 640x480) on "
            "raw 16-bit stereo frames of a moving gas plume and reports: the median wall time "
            "of each stage and of the whole chain, warm (consecutive triples, started from "
            "the previous one as in the daemon), warm again with the active region off (the "
            "solvers on the whole frame; with the mean share of the frame the active region "
            "covered and the warm triples that solved the whole frame anyway) and cold (each "
            "triple on its own), after a "
            "warm-up (one OpenCV and one numba thread), the median CPU time of a call, OpenCV "
            "Farneback on the same differential images with each stage's ratio to it (the "
            "ratio stays comparable on a loaded machine), a roofline floor (bytes streamed "
            "per triple over the copy bandwidth measured in the same run), and stereo pairs "
            "per second with 1..N spawned worker processes taking every N-th triple as the "
            "daemon's workers do, back to back for --seconds. "
            "The machine load is printed with the numbers: on a shared machine wall times "
            "grow with the load, CPU times and ratios much less."
        ),
        epilog="example: ogiflow bench --json bench.json; "
               "ogiflow bench --config benchmarks/configs/coarse-warm-pyramid.yaml",
    )
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"stages_ms": {...}, "chain_ms": ..., "pairs_per_s": '
                        '{"1": ..., "2": ...}, "no_active_region": {"stages_ms": ..., '
                        '"chain_ms": ...}, "active_region": {...}} plus reference and load '
                        'fields to OUT')
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
    p.add_argument("--size", default="320x240", metavar="WxH",
                   help="image size: 320x240 (default) or 640x480 (same field of view, "
                        "twice the camera constant)")
    p.add_argument("--frames", type=int, default=16, metavar="N",
                   help="length of the input sequence, cycled through (default 16); the "
                        "pairs/s run on at least 62 frames (cold starts as in the daemon)")
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="where generated input is cached (default ~/.cache/ogiflow/bench)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="time the chain with this configuration file's "
                        "processing.parameters (as `ogiflow run --config FILE` runs it) "
                        "instead of the defaults; the warm column turns its active region "
                        "on, the 'no region' column off")
    p.set_defaults(func=run)


def _size(text: str) -> tuple[int, int]:
    """``WxH`` -> (W, H), one of the bench's sizes; ValueError otherwise (exit 2)."""
    from appliance.evaluation.bench_input import SIZES

    known = ", ".join(f"{w}x{h}" for w, h in SIZES)
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size expects WxH ({known}), got {text!r}") from None
    if (w, h) not in SIZES:
        raise ValueError(f"--size {text}: unsupported; choose from {known}")
    return w, h


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
    _size(args.size)


def run(args: argparse.Namespace) -> int:
    """Measure and print (and optionally write) the chain's speed."""
    _check_args(args)
    # Imported when the command runs: the CLI imports every command module for its parser.
    from dataclasses import replace

    from appliance.evaluation import benchmark as bm
    from appliance.evaluation.sceneflow_setup import load_processing

    # The configuration is checked before anything is rendered or timed (exit 2).
    params = load_processing(args.config).chain_parameters({})
    load_start = bm.load_average()
    frames = bm.load_frames(args.source, n_frames=args.frames, cache_dir=args.cache_dir,
                            image_size=_size(args.size))
    try:
        # The warm columns with the active region on (the default), the 'no region' ones
        # with it off, whatever the configuration says: both are always shown.
        st = bm.measure_stages(frames, replace(params, active_region=True), runs=args.runs,
                               warmup=args.warmup)
        long = frames if len(frames.times_s) >= bm.THROUGHPUT_MIN_FRAMES else bm.load_frames(
            args.source, n_frames=bm.THROUGHPUT_MIN_FRAMES, cache_dir=args.cache_dir,
            image_size=_size(args.size))
        through = [bm.measure_throughput(long, n, seconds=args.seconds, warmup=args.warmup,
                                         params=params)
                   for n in range(1, args.workers_max + 1)]
    except RuntimeError as exc:
        raise cli.CommandError(str(exc)) from exc
    load_end = bm.load_average()

    warm, cold, fl = st.warm, st.cold, st.floor
    full = st.times("warm_full")
    ratios, cold_ratios, full_ratios = st.ratios("warm"), st.ratios("cold"), st.ratios("warm_full")
    w, h = frames.image_size
    print(f"parameters: {args.config or 'the defaults'}")
    print(f"input: {args.source}, {len(frames.times_s)} frames {w}x{h} uint16 cycled; "
          f"{warm.runs} timed chain calls each warm, warm without the active region and "
          f"cold after {args.warmup} warm-up; 1 thread per process")
    print("warm = consecutive triple started from the previous one (as in the daemon), with "
          "processing.parameters.active_region on (the default); no region = the same with "
          "it off (solvers on the whole frame); "
          "cold = a triple on its own (full pyramid, SGM start)")
    print(f"{'stage':<18}{'warm ms':>9}{'x Fbck':>8}{'CPU ms':>8}{'no region':>11}{'x Fbck':>8}"
          f"{'cold ms':>10}{'x Fbck':>8}")
    for name in bm.STAGES:
        print(f"{name:<18}{warm.stages_ms[name]:>9.2f}{ratios[name]:>8.2f}"
              f"{warm.stages_cpu_est_ms[name]:>8.2f}{full.stages_ms[name]:>11.2f}"
              f"{full_ratios[name]:>8.2f}{cold.stages_ms[name]:>10.2f}"
              f"{cold_ratios[name]:>8.2f}")
    print(f"{'chain (total)':<18}{warm.chain_ms:>9.2f}{ratios['chain']:>8.2f}{warm.cpu_ms:>8.2f}"
          f"{full.chain_ms:>11.2f}{full_ratios['chain']:>8.2f}"
          f"{cold.chain_ms:>10.2f}{cold_ratios['chain']:>8.2f}")
    print("CPU ms: process CPU time of a call (measured; per stage estimated from the "
          "call's CPU/wall ratio)")
    box = warm.box_share
    print(f"active region: the warm solvers worked on {100 * warm.solved_share:.1f} % of the "
          f"frame on average; {warm.full_frame_calls} of {warm.runs} warm triples solved the "
          f"whole frame"
          + ("" if box is None else f", the others a box of {100 * box:.1f} % on average"))
    fb_cpu = st.farneback_cpu_ms
    print(f"by CPU time (steadier under load): warm chain {warm.cpu_ms / fb_cpu:.2f}x "
          f"({full.cpu_ms / fb_cpu:.2f}x without the active region), "
          f"cold chain {cold.cpu_ms / fb_cpu:.2f}x Farneback")
    print(f"Farneback reference (OpenCV, same differential images): {st.farneback_ms:.2f} ms "
          f"wall, {st.farneback_cpu_ms:.2f} ms CPU")
    print(f"roofline floor of a warm triple: {fl.bytes_per_triple / 1e6:.0f} MB streamed; at "
          f"{fl.cache_bandwidth_gb_s:.1f} GB/s (cache-resident copy) {fl.cache_floor_ms:.2f} ms, "
          f"at {fl.dram_bandwidth_gb_s:.1f} GB/s (main memory) {fl.dram_floor_ms:.2f} ms; the "
          f"warm chain's CPU time is {warm.cpu_ms / fl.cache_floor_ms:.1f}x / "
          f"{warm.cpu_ms / fl.dram_floor_ms:.1f}x these floors")
    print(f"pairs/s on {len(long.times_s)} frames cycled (cold starts as often as in the "
          f"daemon for any number of workers):")
    for t in through:
        print(f"{t.workers} worker(s): {t.pairs_per_s:.2f} pairs/s "
              f"({t.triples} triples in {t.wall_s:.1f} s; {t.cpu_ms_per_pair:.1f} ms CPU each, "
              f"{t.pairs_per_cpu_s:.2f} pairs per CPU-second; D(t0) found computed: "
              f"{', '.join(f'{100 * f:.0f} %' for f in t.d0_found)})")
    if load_start is not None and load_end is not None:
        print(f"load average (1/5/15 min): start {_fmt_load(load_start)}, "
              f"end {_fmt_load(load_end)} on {_cpu_count()} CPUs")

    if args.json is not None:
        out: dict[str, Any] = {
            "stages_ms": warm.stages_ms,
            "chain_ms": warm.chain_ms,
            "pairs_per_s": {str(t.workers): t.pairs_per_s for t in through},
            "throughput_frames": len(long.times_s),
            "chain_cpu_ms": warm.cpu_ms,
            "stages_cpu_est_ms": warm.stages_cpu_est_ms,
            "cold": {"stages_ms": cold.stages_ms, "chain_ms": cold.chain_ms,
                     "chain_cpu_ms": cold.cpu_ms,
                     "ratio_to_farneback": cold_ratios},
            "active_region": {"solved_share": warm.solved_share, "box_share": box,
                              "full_frame_triples": warm.full_frame_calls,
                              "warm_triples": warm.runs},
            "no_active_region": {"stages_ms": full.stages_ms, "chain_ms": full.chain_ms,
                                 "chain_cpu_ms": full.cpu_ms,
                                 "stages_cpu_est_ms": full.stages_cpu_est_ms,
                                 "ratio_to_farneback": full_ratios},
            "cpu_ms_per_pair": {str(t.workers): t.cpu_ms_per_pair for t in through},
            "pairs_per_cpu_s": {str(t.workers): t.pairs_per_cpu_s for t in through},
            "d0_found": {str(t.workers): list(t.d0_found) for t in through},
            "farneback_ms": st.farneback_ms,
            "farneback_cpu_ms": st.farneback_cpu_ms,
            "ratio_to_farneback": ratios,
            "floor": {"bytes_per_triple": fl.bytes_per_triple,
                      "cache_bandwidth_gb_s": fl.cache_bandwidth_gb_s,
                      "dram_bandwidth_gb_s": fl.dram_bandwidth_gb_s,
                      "cache_floor_ms": fl.cache_floor_ms, "dram_floor_ms": fl.dram_floor_ms},
            "source": args.source,
            "config": None if args.config is None else str(args.config),
            "image_size": [w, h],
            "runs": warm.runs,
            "seconds": args.seconds,
            "load_average": {"start": load_start, "end": load_end, "cpus": _cpu_count()},
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return cli.EXIT_OK


def _fmt_load(load: tuple[float, float, float]) -> str:
    return "/".join(f"{x:.2f}" for x in load)


def _cpu_count() -> int:
    return os.cpu_count() or 1
