"""``ogiflow eval stereo``: disparity accuracy on a rectified pair with ground truth.

The argparse layer and the printed table; the evaluation is
:func:`appliance.evaluation.stereo.evaluate_stereo` (its docstring says what is measured).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from appliance import cli


def register(root: argparse._SubParsersAction) -> None:
    """Add ``eval stereo`` to the ``eval`` group."""
    group = cli.command_group(root, "eval", "evaluate the processing against reference data")
    p = group.add_parser(
        "stereo",
        help="disparity error of our variational solver and StereoSGBM against ground truth",
        description=(
            "Disparity of a rectified grey pair (left, right) by our joint variational "
            "solver (paper Eq. 6 on a static pair, d' = 0) and by OpenCV StereoSGBM, "
            "compared with a ground-truth disparity image: mean absolute error (MAE, px) "
            "and bad-pixel rate (fraction with error > 1 px) over pixels with gt > 0. "
            "SGBM's invalid pixels count as bad; its MAE is over its valid pixels, "
            "reported with their fraction. Disparity convention: x_right = x_left - d."
        ),
        epilog=("example: ogiflow eval stereo --left data/stereo/tsukuba/im3.png "
                "--right data/stereo/tsukuba/im4.png --gt data/stereo/tsukuba/disp3.pgm "
                "--gt-scale 16"),
    )
    p.add_argument("--left", required=True, type=Path, help="left image (any grey/colour)")
    p.add_argument("--right", required=True, type=Path, help="right image, same size")
    p.add_argument("--gt", required=True, type=Path,
                   help="ground-truth disparity image of the left view (0 = unknown)")
    p.add_argument("--gt-scale", required=True, type=float,
                   help="ground-truth pixel value per pixel of disparity (Middlebury "
                        "tsukuba 16, venus 8)")
    p.add_argument("--d0", type=float, default=0.0,
                   help="initial (minimum) disparity of the variational solver, px "
                        "(default 0: coarse-to-fine from zero)")
    p.add_argument("--sgm-init", action="store_true",
                   help="initialise the variational solver from the SGBM estimate "
                        "(holes filled with its median) instead of --d0")
    p.add_argument("--max-disparity", type=int, default=64,
                   help="SGBM search range in px, a multiple of 16 (default 64)")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<method>": {"mae": ..., "bad1": ...}} to this file')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate both methods on the given pair and print a table (and JSON)."""
    if not args.gt_scale > 0:
        raise ValueError(f"--gt-scale must be positive, got {args.gt_scale}")
    if args.max_disparity <= 0 or args.max_disparity % 16:
        raise ValueError(f"--max-disparity must be a positive multiple of 16, "
                         f"got {args.max_disparity}")
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation.stereo import (
        METHOD_SGBM,
        METHOD_VARIATIONAL,
        evaluate_stereo,
        read_grey,
        read_gt,
    )

    left = read_grey(args.left, "left")
    right = read_grey(args.right, "right")
    gt = read_gt(args.gt, args.gt_scale)
    if right.shape != left.shape or gt.shape != left.shape:
        raise ValueError(f"image sizes differ: left {left.shape[::-1]}, right "
                         f"{right.shape[::-1]}, gt {gt.shape[::-1]} (width, height)")
    res = evaluate_stereo(left, right, gt, d0=args.d0, sgm_init=args.sgm_init,
                   max_disparity=args.max_disparity)
    init = "SGBM estimate" if args.sgm_init else f"d0 = {args.d0:g} px"
    print(f"{args.left.name} / {args.right.name}: {left.shape[1]}x{left.shape[0]} px, "
          f"{int((gt > 0).sum())} pixels with ground truth")
    print(f"{'method':<12} {'MAE/px':>8} {'bad>1px':>8} {'valid':>7} {'ms':>8}")
    v = res[METHOD_VARIATIONAL]
    print(f"{METHOD_VARIATIONAL:<12} {v['mae']:8.3f} {v['bad1']:8.1%} {'100%':>7} "
          f"{v['ms']:8.0f}   (Eq. 6, init {init})")
    s = res[METHOD_SGBM]
    print(f"{METHOD_SGBM:<12} {s['mae']:8.3f} {s['bad1']:8.1%} {s['valid']:7.1%} "
          f"{s['ms']:8.0f}   (MAE over valid pixels; invalid count as bad)")
    if args.json is not None:
        args.json.write_text(json.dumps(res, indent=2) + "\n")
    return cli.EXIT_OK
