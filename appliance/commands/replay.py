"""``ogiflow replay``: run the scene-flow pipeline again over a recording.

Reads the raw frames of FILE.mcap (every frame of both cameras, with their original
timestamps), stamps and pairs them exactly as the live appliance does, runs the same
chain (:func:`processing.chain.compute_scene_flow`) on EVERY consecutive triple - nothing
is skipped offline - and writes a new MCAP file with the pairs, the per-frame summaries,
the wind (copied, and rotated into the camera frame at every pair) and the result fields.

The geometry and the chain parameters recorded in the file are used unless overridden:
``--param alpha=0.1`` (repeatable; any field of processing.chain.ChainParameters, value in
YAML syntax) changes a parameter, ``--calibration FILE`` the geometry. By default it runs
at the recorded pace (for watching with ``--live``); ``--fast`` runs as fast as possible.
A recording cut by a crash is processed up to the cut. Ctrl-C stops it and still leaves a
valid output file with every triple processed so far.

``--segment-s S`` cuts the recording into S-second segments that each start cold (no warm
start across a border), exactly as ``ogiflow reprocess --segment-s S`` does on many cores
or a cluster: the two then write the same results.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from appliance.cli import EXIT_INTERRUPTED
from appliance.config import live_overrides, load_config


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("replay", help="reprocess a recording (same pipeline), write a new MCAP",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="recording to reprocess")
    p.add_argument("--out", type=Path, default=None,
                   help="output file (default: FILE-replay.mcap beside the input)")
    p.add_argument("--fast", action="store_true", help="as fast as possible (default: paced)")
    p.add_argument("--param", metavar="KEY=VALUE", action="append", default=[],
                   help="override one chain parameter (repeatable), e.g. --param alpha=0.1")
    p.add_argument("--calibration", type=Path, default=None,
                   help="stereo calibration file to use instead of the recorded geometry")
    p.add_argument("--fields-every", type=int, default=1, metavar="N",
                   help="record the full fields of every N-th result (default 1: all)")
    p.add_argument("--live", metavar="MODE", nargs="+", default=["off"],
                   help="also show it live: serve | connect URL | save FILE | off (default)")
    p.add_argument("--segment-s", type=float, default=None, metavar="S",
                   help="cut into S-second segments that each start cold, as reprocess does "
                        "(default: one segment)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.reprocess.segments import cut_segments, process_into, replay_parameters
    from appliance.reprocess.sink import McapSink
    from appliance.reprocess.source import (
        PairStream,
        Recording,
        load_geometry,
        parse_override,
        read_wind,
    )
    from appliance.runtime.workers import single_threaded

    src: Path = args.file
    rec = Recording.open(src)
    out = args.out or src.with_name(src.stem + "-replay.mcap")
    if out.exists() and not args.force:
        raise ValueError(f"{out} exists; use --force to overwrite")
    if args.fields_every < 1:
        raise ValueError(f"--fields-every must be >= 1, got {args.fields_every}")
    geometry = load_geometry(rec.meta, args.calibration)
    overrides = {k: yaml.safe_load(v) for k, v in map(parse_override, args.param)}
    wind = read_wind(rec.path)
    params = replay_parameters(rec, overrides, wind)
    segments = [cut_segments([], None)[0]]
    if args.segment_s is not None:
        segments = cut_segments([p.time_ns for _i, p in PairStream(rec)], args.segment_s)
    single_threaded()  # bit-identical to reprocess, whose tasks run one thread each

    sink = McapSink(out, rec.output_metadata(params, args.segment_s))
    live = None
    if args.live != ["off"]:
        # Only with a live view (rerun costs ~1-2 s to import).
        from appliance.live.view import LiveView

        live = LiveView(load_config(None, live_overrides(args.live)).live).start()

    def progress(r: Any) -> None:
        nonlocal done
        done = r.triples
        if sys.stderr.isatty():
            sys.stderr.write(f"\rreplay: {r.triples + r.failed} triples, {r.triples} processed")
            sys.stderr.flush()
        elif (r.triples + r.failed) % 100 == 0:
            print(f"replay: {r.triples} triples processed", file=sys.stderr)

    report = None
    done = 0
    try:
        report, _ = process_into(sink, rec, geometry, params, _open_ended(segments),
                                 fields_every=args.fields_every, copy_wind=True,
                                 live=live, pace=not args.fast, on_triple=progress,
                                 wind=wind)
    except KeyboardInterrupt:
        pass
    finally:
        if sys.stderr.isatty():
            sys.stderr.write("\n")
        if live is not None:
            live.close()
        sink.close()  # also on Ctrl-C: a valid file with everything processed so far
    if report is None:
        print(f"interrupted: {done} triples processed so far are in {out}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    for line in report.errors:
        print(line, file=sys.stderr)
    print(f"replayed {src}: {report.pairs} pairs (unpaired frames left "
          f"{report.unpaired['left']}, right {report.unpaired['right']}), {report.triples} "
          f"triples processed, {report.failed} failed, {len(segments)} segment(s) -> {out}")
    if report.truncated:
        print(f"warning: {src} ends early (cut by a crash?); processed everything up to the cut",
              file=sys.stderr)
    return 0


def _open_ended(segments: list[Any]) -> list[Any]:
    """The last segment runs to the end of the file, whatever its planned end."""
    return [*segments[:-1], replace(segments[-1], stop=2**62)]
