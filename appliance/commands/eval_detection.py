"""``ogiflow eval detection``: leak events over recorded image sets (appliance.evaluation)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from appliance import cli
from appliance.runtime.event_config import EventConfig

_HELP = """\
Run the chain and the daemon's leak-event logic over every image set under --data: folders
of consecutive single-camera frames named *frame<N>.jpg/png/tif (like data/ogi) and
sequences written by `ogiflow simulate`. Reports per set the frames, the frames with gas
(at least --min-gas-pixels segmented) and the events (first and last frame, why it ended,
source, confidence). Frame times of folders are N / --fps; a folder with a labels.json
(data/ogi/gasvid) takes its frame interval from there and is scored per release class:
windows alarmed, false events and why they started, time to the first alarm, source error
against the labelled box, apparent size and its rank correlation with the rate.
"""


def register(root: argparse._SubParsersAction) -> None:
    group = cli.command_group(root, "eval", "evaluate the method on reference data")
    p = group.add_parser("detection", help="leak events over recorded image sets",
                         description=_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, type=Path, metavar="DIR",
                   help="folder of image sets (or one simulated sequence)")
    p.add_argument("--json", type=Path, default=None, metavar="OUT",
                   help="write {set: {frames, gas_frames, events, per_frame[, labelled]}} to OUT")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of folder sets (30)")
    d = EventConfig()
    for name, typ in (("min_gas_pixels", int), ("min_coherence", float),
                      ("max_source_shift_px", float), ("min_duration_s", float),
                      ("start_window_s", float), ("start_fraction", float),
                      ("end_window_s", float), ("end_fraction", float)):
        p.add_argument("--" + name.replace("_", "-"), type=typ, default=getattr(d, name),
                       help=f"event logic (default {getattr(d, name)})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation.detection import DetectionSettings, evaluate_detection
    from appliance.evaluation.labelled import format_labelled

    if not args.fps > 0:
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    events = EventConfig(**{f.name: getattr(args, f.name) for f in dataclasses.fields(
        EventConfig) if hasattr(args, f.name)})
    report = evaluate_detection(args.data, DetectionSettings(fps=args.fps, events=events))
    print(f"{'set':<24} {'frames':>6} {'gas frames':>10}  events (first-last frame, end)")
    for name, r in report.items():
        evs = ", ".join(f"{e['start_frame']}-{e['end_frame']} ({e['end_reason']})"
                        for e in r["events"]) or "none"
        print(f"{name:<24} {r['frames']:>6} {r['gas_frames']:>10}  {evs}")
    for name, r in report.items():
        if "labelled" in r:
            print("\n".join(format_labelled(name, r["labelled"])))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1, allow_nan=False) + "\n")
        print(f"json: {args.json}")
    return cli.EXIT_OK
