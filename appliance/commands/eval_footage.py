"""``ogiflow eval footage``: pre-processing, flow and gas segmentation on real OGI frames.

Every subfolder of ``--data`` holding images named ``*frame<N>.<ext>`` (JPEG, PNG, TIFF; 8 or
16 bit, one camera) is one set. Frames are ordered by N; only triples of consecutive frame
numbers (N, N+1, N+2) are processed, so sets whose frames are not all consecutive are split
into their consecutive runs (e.g. the ``nonleak`` set of ``data/ogi``: 0-18, 1536-1539,
3019-3023). For each triple: differential images (Eq. 2) with jitter removal and Sobolev
denoising (:func:`processing.preprocess.preprocess_camera`, identity characteristic curve:
the footage is uncalibrated counts), Brox flow between the two differential images (Eq. 5)
and the level-set segmentation (Eq. 9). Reported per frame: the segmented gas fraction
(gas pixels / all pixels) of I_diff(t0 = N), the gas/background activity ratio, the
registration shifts and the median flow magnitude.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import time
from pathlib import Path

import numpy as np

from appliance.cli import CommandError, command_group

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
FRAME_NUMBER = re.compile(r"frame(\d+)\.[A-Za-z]+$")


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
            "1.0; 5 counts is about the 99.9 %% quantile of |I(t) - I(t+1)| on data/ogi"
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
        default="leak",
        help="set for the figure: the first set whose name contains this text",
    )
    p.add_argument(
        "--figure-frame",
        type=int,
        help="frame number N for the figure (default: the set's most confident segmentation)",
    )
    p.add_argument("--json", type=Path, help="write per-frame and per-set results as JSON")
    p.set_defaults(func=run)


def find_sets(data: Path) -> dict[str, list[tuple[int, Path]]]:
    """Image sets under ``data``: {subfolder name: [(frame number, path), ...] sorted}."""
    if not data.is_dir():
        raise ValueError(f"--data {data} is not a directory")
    sets: dict[str, list[tuple[int, Path]]] = {}
    for sub in sorted(p for p in data.iterdir() if p.is_dir()):
        frames = []
        for f in sub.iterdir():
            m = FRAME_NUMBER.search(f.name)
            if m and f.suffix.lower() in IMAGE_SUFFIXES:
                frames.append((int(m.group(1)), f))
        if frames:
            sets[sub.name] = sorted(frames)
    if not sets:
        raise ValueError(f"no image sets (subfolders with *frame<N>.jpg/png/tif) in {data}")
    return sets


def consecutive_runs(numbers: list[int]) -> list[tuple[int, int]]:
    """Maximal runs of consecutive integers in a sorted list, as (first, last)."""
    runs: list[tuple[int, int]] = []
    for n in numbers:
        if runs and n == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], n)
        else:
            runs.append((n, n))
    return runs


def read_frame(path: Path) -> np.ndarray:
    """One frame as a 2-D array of counts (colour images are converted to grey)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot read image {path}")
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel image, got shape {img.shape}")
    return img


def flow_to_bgr(flow: np.ndarray, max_magnitude: float) -> np.ndarray:
    """Colour-code a flow field: hue = direction, brightness = magnitude / max_magnitude."""
    import cv2

    mag, ang = cv2.cartToPolar(flow[..., 0], flow[..., 1], angleInDegrees=True)
    hsv = np.zeros((*flow.shape[:2], 3), np.uint8)
    hsv[..., 0] = (ang / 2.0).astype(np.uint8)  # OpenCV hue is 0..179
    hsv[..., 1] = 255
    hsv[..., 2] = np.clip(mag / max(max_magnitude, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)


def make_figure(
    raw: np.ndarray, diff: np.ndarray, flow: np.ndarray, mask: np.ndarray, title: str
) -> np.ndarray:
    """Four panels side by side: raw frame, I_diff, colour-coded flow, mask on I_diff."""
    import cv2

    def grey(img: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)

    raw8 = raw.astype(np.float32)
    lo, hi = float(raw8.min()), float(raw8.max())
    raw8 = ((raw8 - lo) / max(hi - lo, 1e-6) * 255).astype(np.uint8)
    diff8 = (np.clip(diff, 0.0, 1.0) * 255).astype(np.uint8)
    mag = np.sqrt(flow[..., 0] ** 2 + flow[..., 1] ** 2)
    max_mag = float(np.percentile(mag, 99)) or 1.0
    flow_bgr = flow_to_bgr(flow, max_mag)
    overlay = grey(diff8)
    tint = overlay.copy()
    tint[mask] = (0, 0, 255)
    overlay = cv2.addWeighted(overlay, 0.6, tint, 0.4, 0)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(overlay, contours, -1, (0, 255, 255), 1)
    panels = [
        (grey(raw8), "raw frame"),
        (grey(diff8), "I_diff (0.5 = no change)"),
        (flow_bgr, f"flow, |w| <= {max_mag:.2f} px"),
        (overlay, f"gas mask {100.0 * mask.mean():.1f} %"),
    ]
    labelled = []
    for img, label in panels:
        canvas = cv2.copyMakeBorder(img, 22, 0, 0, 2, cv2.BORDER_CONSTANT, value=(0, 0, 0))
        cv2.putText(canvas, label, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        labelled.append(canvas)
    row = np.hstack(labelled)
    header = np.zeros((24, row.shape[1], 3), np.uint8)
    cv2.putText(header, title, (4, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    return np.vstack([header, row])


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"mean": None, "min": None, "max": None}
    return {"mean": float(np.mean(values)), "min": float(min(values)), "max": float(max(values))}


def run(args: argparse.Namespace) -> int:
    import cv2

    from processing.optical_flow import brox_optical_flow
    from processing.preprocess import preprocess_camera
    from processing.segmentation import segment_gas

    if not np.isfinite(args.scale) or args.scale <= 0:
        raise ValueError(f"--scale must be a positive number, got {args.scale}")
    if not np.isfinite(args.denoise_lambda) or args.denoise_lambda < 0:
        raise ValueError(f"--denoise-lambda must be >= 0, got {args.denoise_lambda}")
    sets = find_sets(args.data)
    figure_set = next((name for name in sets if args.figure_set in name), None)
    if args.figure is not None and figure_set is None:
        raise ValueError(f"--figure: no set under {args.data} has {args.figure_set!r} in its name")

    timings: dict[str, list[float]] = {"preprocess": [], "flow": [], "segmentation": []}
    report: dict[str, object] = {}
    figure_candidates: list[tuple[float, int, tuple]] = []
    for name, frames in sets.items():
        numbers = [n for n, _ in frames]
        paths = dict(frames)
        runs = consecutive_runs(numbers)
        per_frame = []
        shift01 = None
        prev_n = None
        cache: dict[int, np.ndarray] = {}
        for first, last in runs:
            for n in range(first, last - 1):
                imgs = []
                for k in (n, n + 1, n + 2):
                    if k not in cache:
                        cache[k] = read_frame(paths[k])
                    imgs.append(cache[k])
                cache.pop(n - 1, None)
                if imgs[0].shape != imgs[1].shape or imgs[0].shape != imgs[2].shape:
                    raise ValueError(f"{name}: frames {n}..{n + 2} differ in size")
                t0 = time.perf_counter()
                pre = preprocess_camera(
                    imgs,
                    scale=args.scale,
                    register=not args.no_register,
                    denoise_lambda=args.denoise_lambda,
                    shift01=shift01 if prev_n == n - 1 else None,
                )
                t1 = time.perf_counter()
                flow = brox_optical_flow(pre.diff0, pre.diff1)
                t2 = time.perf_counter()
                seg = segment_gas(pre.diff0, flow, min_activity_ratio=args.min_activity_ratio)
                t3 = time.perf_counter()
                timings["preprocess"].append((t1 - t0) * 1e3)
                timings["flow"].append((t2 - t1) * 1e3)
                timings["segmentation"].append((t3 - t2) * 1e3)
                shift01, prev_n = pre.shifts[1], n
                mag = np.sqrt(flow[..., 0] ** 2 + flow[..., 1] ** 2)
                entry = {
                    "frame": n,
                    "gas_fraction": float(seg.mask.mean()),
                    "gas_pixels": int(seg.mask.sum()),
                    "activity_ratio": float(seg.activity_ratio),
                    "shift01_px": [round(v, 4) for v in pre.shifts[0]],
                    "shift12_px": [round(v, 4) for v in pre.shifts[1]],
                    "flow_median_px": float(np.median(mag)),
                }
                per_frame.append(entry)
                if name == figure_set and (args.figure_frame in (None, n)):
                    key = seg.activity_ratio if seg.mask.any() else -1.0
                    figure_candidates.append((key, n, (imgs[0], pre.diff0, flow, seg.mask)))
                    figure_candidates = [max(figure_candidates, key=lambda c: c[0])]
        fractions = [e["gas_fraction"] for e in per_frame]
        per_run = {
            f"{a}-{b}": _stats([e["gas_fraction"] for e in per_frame if a <= e["frame"] <= b])
            for a, b in runs
        }
        report[name] = {
            "runs": [list(r) for r in runs],
            "gas_fraction_per_run": per_run,
            "triples_used": len(per_frame),
            "frames_in_set": len(numbers),
            "gas_fraction": _stats(fractions),
            "frames_with_gas": sum(1 for f in fractions if f > 0),
            "frames": per_frame,
        }

    print(
        f"settings: scale {args.scale:g} counts, denoise lambda {args.denoise_lambda:g} px^2, "
        f"registration {'off' if args.no_register else 'on'}, "
        f"min activity ratio {args.min_activity_ratio:g}"
    )
    for name, rep in report.items():
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
        else:
            print(
                f"  gas fraction: mean {100 * s['mean']:.2f} %, min {100 * s['min']:.2f} %, "
                f"max {100 * s['max']:.2f} %; frames with gas {rep['frames_with_gas']}"
                f"/{rep['triples_used']}"
            )
            if len(rep["runs"]) > 1:
                for run_name, rs in rep["gas_fraction_per_run"].items():
                    if rs["mean"] is not None:
                        print(
                            f"    run {run_name}: mean {100 * rs['mean']:.2f} %, "
                            f"min {100 * rs['min']:.2f} %, max {100 * rs['max']:.2f} %"
                        )
    stage_ms = {k: (statistics.median(v) if v else None) for k, v in timings.items()}
    print(
        "\nmedian ms per triple: "
        + ", ".join(f"{k} {v:.1f}" for k, v in stage_ms.items() if v is not None)
    )

    if args.figure is not None:
        if not figure_candidates:
            raise CommandError(
                f"no frame of set {figure_set!r} to draw (frame {args.figure_frame})"
            )
        _, n, (raw, diff, flow, mask) = figure_candidates[0]
        title = f"{figure_set} frame {n}: pre-processing, Brox flow (Eq. 5), gas mask (Eq. 9)"
        fig = make_figure(raw, diff, flow, mask, title)
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.figure), fig):
            raise CommandError(f"could not write {args.figure}")
        print(f"figure: {args.figure} ({figure_set} frame {n})")
    if args.json is not None:
        out = {
            "settings": {
                "scale_counts": args.scale,
                "denoise_lambda": args.denoise_lambda,
                "register": not args.no_register,
                "min_activity_ratio": args.min_activity_ratio,
            },
            "stage_ms": stage_ms,
            "sets": report,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2, allow_nan=False) + "\n")
        print(f"json: {args.json}")
    return 0
