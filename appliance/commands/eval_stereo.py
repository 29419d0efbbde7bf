"""``ogiflow eval stereo``: disparity accuracy on a rectified pair with ground truth.

Runs our variational disparity (the joint solver of Eq. 6 on a static pair: the same
images at t0 and t1 and zero flow, so d' = 0) and OpenCV StereoSGBM in the same run and
reports the mean absolute error and the bad-pixel rate (error > 1 px) over the pixels
with known ground truth (gt > 0).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from appliance import cli

METHOD_VARIATIONAL = "variational"
METHOD_SGBM = "sgbm"


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


def _read_grey(path: Path, what: str):
    import cv2
    import numpy as np

    if not path.is_file():
        raise ValueError(f"{what} image not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError(f"cannot read {what} image {path} (unknown or corrupt format)")
    if img.dtype != np.uint8:
        raise ValueError(f"{what} image {path} must be 8-bit, got {img.dtype}")
    return img.astype(np.float32) / 255.0


def _read_gt(path: Path, scale: float):
    import cv2
    import numpy as np

    if not path.is_file():
        raise ValueError(f"ground-truth image not found: {path}")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ValueError(f"cannot read ground-truth image {path} (unknown or corrupt format)")
    if raw.ndim != 2:
        raise ValueError(f"ground-truth image {path} must be single-channel, got {raw.shape}")
    return raw.astype(np.float32) / np.float32(scale)


def evaluate(
    left, right, gt, *, d0: float = 0.0, sgm_init: bool = False, max_disparity: int = 64
) -> dict[str, dict[str, float]]:
    """Scores of both methods on one pair (arrays already loaded; see the module doc).

    Returns
    -------
    dict
        {"variational": {"mae", "bad1", "ms"}, "sgbm": {"mae", "bad1", "valid", "ms"}}
        with mae in px, bad1 and valid as fractions of the known ground-truth pixels.
    """
    import numpy as np

    from processing.baselines import sgbm_disparity, sgbm_initial_disparity
    from processing.disparity import joint_disparity

    known = gt > 0
    if not known.any():
        raise ValueError("the ground truth has no known pixel (all values are 0)")
    t = time.perf_counter()
    d_sgbm, valid = sgbm_disparity(left, right, num_disparities=max_disparity)
    ms_sgbm = (time.perf_counter() - t) * 1e3
    init = None
    if sgm_init:
        init = sgbm_initial_disparity(left, right, num_disparities=max_disparity, fallback=d0)
    zero = np.zeros((*left.shape, 2), np.float32)
    # Warm-up on a tiny pair: the first call loads the compiled numba code from its cache,
    # which must not count as run time.
    tiny = np.zeros((16, 16), np.float32)
    joint_disparity(tiny, tiny, tiny, tiny, np.zeros((16, 16, 2), np.float32))
    t = time.perf_counter()
    d_var, _ = joint_disparity(left, right, left, right, zero, d0=d0, initial_disparity=init)
    ms_var = (time.perf_counter() - t) * 1e3

    err_var = np.abs(d_var - gt)[known]
    err_sgbm = np.abs(d_sgbm - gt)[known]
    valid_k = valid[known]
    bad_sgbm = (~valid_k) | (err_sgbm > 1.0)
    return {
        METHOD_VARIATIONAL: {"mae": float(err_var.mean()), "bad1": float(np.mean(err_var > 1.0)),
                             "ms": ms_var},
        METHOD_SGBM: {
            "mae": float(err_sgbm[valid_k].mean()) if valid_k.any() else float("nan"),
            "bad1": float(bad_sgbm.mean()),
            "valid": float(valid_k.mean()),
            "ms": ms_sgbm,
        },
    }


def run(args: argparse.Namespace) -> int:
    """Evaluate both methods on the given pair and print a table (and JSON)."""
    if not args.gt_scale > 0:
        raise ValueError(f"--gt-scale must be positive, got {args.gt_scale}")
    if args.max_disparity <= 0 or args.max_disparity % 16:
        raise ValueError(f"--max-disparity must be a positive multiple of 16, "
                         f"got {args.max_disparity}")
    left = _read_grey(args.left, "left")
    right = _read_grey(args.right, "right")
    gt = _read_gt(args.gt, args.gt_scale)
    if right.shape != left.shape or gt.shape != left.shape:
        raise ValueError(f"image sizes differ: left {left.shape[::-1]}, right "
                         f"{right.shape[::-1]}, gt {gt.shape[::-1]} (width, height)")
    res = evaluate(left, right, gt, d0=args.d0, sgm_init=args.sgm_init,
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
