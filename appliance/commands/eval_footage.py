"""``ogiflow eval footage``: pre-processing, flow and gas segmentation on real OGI frames.

The argparse layer and the printed report; the evaluation is
:func:`appliance.evaluation.footage.evaluate_footage`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from appliance.cli import CommandError, command_group

if TYPE_CHECKING:  # the core imports OpenCV: loaded when the command runs, not at CLI start
    from appliance.evaluation.footage import FootageReport, FootageSettings


def register(root: argparse._SubParsersAction) -> None:
    group = command_group(root, "eval", "evaluate the methods against reference data")
    p = group.add_parser(
        "footage",
        help="gas fraction per frame on real OGI frames (pre-processing, flow, segmentation)",
        description=(
            "Run pre-processing (registration, differential images, Sobolev denoising), Brox "
            "flow and the level-set gas segmentation on every consecutive frame triple of "
            "each image set under --data (one subfolder per set, files named *frame<N>.jpg/"
            "png/tif) and report the segmented gas fraction per frame and per set."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--data", type=Path, default=Path("data/ogi"), help="folder of image sets")
    p.add_argument(
        "--scale",
        type=float,
        default=5.0,
        help=(
            "normalisation scale: the intensity difference (in the frames' counts) mapped to "
            "1.0; 5 counts was about the 99.9 %% quantile of |I(t) - I(t+1)| on 30 frames of "
            "GF320 footage without a visible leak"
        ),
    )
    p.add_argument(
        "--denoise-lambda",
        type=float,
        default=10.0,
        help="Sobolev prior weight in px^2 (0 disables denoising)",
    )
    p.add_argument("--no-register", action="store_true", help="skip the jitter registration")
    p.add_argument(
        "--min-activity-ratio",
        type=float,
        default=1.5,
        help="gas accepted only if its activity exceeds the background's by this factor",
    )
    p.add_argument("--figure", type=Path, help="write a PNG of one leak frame here")
    p.add_argument(
        "--figure-set",
        default="",
        help="set for the figure: the first set whose name contains this text (default: the "
        "first set)",
    )
    p.add_argument(
        "--figure-frame",
        type=int,
        help="frame number N for the figure (default: the set's most confident segmentation)",
    )
    p.add_argument("--json", type=Path, help="write per-frame and per-set results as JSON")
    p.set_defaults(func=run)


def _print_report(report: FootageReport, settings: FootageSettings) -> None:
    print(
        f"settings: scale {settings.scale:g} counts, denoise lambda "
        f"{settings.denoise_lambda:g} px^2, registration {'on' if settings.register else 'off'}, "
        f"min activity ratio {settings.min_activity_ratio:g}"
    )
    for name, rep in report.sets.items():
        runs_txt = ", ".join(f"{a}-{b}" for a, b in rep["runs"])
        print(f"\n{name}: consecutive runs {runs_txt}; {rep['triples_used']} triples")
        print(f"  {'frame':>6} {'gas %':>7} {'ratio':>6} {'|w| med':>8} {'shift t1 (px)':>16}")
        for e in rep["frames"]:
            sx, sy = e["shift01_px"]
            print(
                f"  {e['frame']:>6} {100 * e['gas_fraction']:>7.2f} {e['activity_ratio']:>6.2f} "
                f"{e['flow_median_px']:>8.2f} {sx:>+7.3f},{sy:>+7.3f}"
            )
        s = rep["gas_fraction"]
        if s["mean"] is None:
            print("  no consecutive triple in this set")
            continue
        print(
            f"  gas fraction: mean {100 * s['mean']:.2f} %, min {100 * s['min']:.2f} %, "
            f"max {100 * s['max']:.2f} %; frames with gas {rep['frames_with_gas']}"
            f"/{rep['triples_used']}"
        )
        if len(rep["runs"]) > 1:
            for run_name, rs in rep["gas_fraction_per_run"].items():
                if rs["mean"] is not None:
                    print(f"    run {run_name}: mean {100 * rs['mean']:.2f} %, "
                          f"min {100 * rs['min']:.2f} %, max {100 * rs['max']:.2f} %")
    print(
        "\nmedian ms per triple: "
        + ", ".join(f"{k} {v:.1f}" for k, v in report.stage_ms.items() if v is not None)
    )


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    import cv2

    from appliance.evaluation.footage import FootageSettings, evaluate_footage, make_figure

    settings = FootageSettings(scale=args.scale, denoise_lambda=args.denoise_lambda,
                               register=not args.no_register,
                               min_activity_ratio=args.min_activity_ratio)
    report = evaluate_footage(args.data, settings,
                              figure_set=args.figure_set if args.figure is not None else None,
                              figure_frame=args.figure_frame)
    _print_report(report, settings)
    if args.figure is not None:
        fig = report.figure
        if fig is None:
            raise CommandError(f"no frame of a set matching {args.figure_set!r} to draw "
                               f"(frame {args.figure_frame})")
        title = (f"{fig.set_name} frame {fig.frame}: pre-processing, Brox flow (Eq. 5), "
                 f"gas mask (Eq. 9)")
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.figure), make_figure(fig, title)):
            raise CommandError(f"could not write {args.figure}")
        print(f"figure: {args.figure} ({fig.set_name} frame {fig.frame})")
    if args.json is not None:
        out = {
            "settings": {
                "scale_counts": settings.scale,
                "denoise_lambda": settings.denoise_lambda,
                "register": settings.register,
                "min_activity_ratio": settings.min_activity_ratio,
            },
            "stage_ms": report.stage_ms,
            "sets": report.sets,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2, allow_nan=False) + "\n")
        print(f"json: {args.json}")
    return 0
