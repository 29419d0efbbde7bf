"""How much a labelled GasVid video's plume contrast varies within a class and between classes.

Reads one labelled set (``frameNNNN.jpg`` and ``labels.json``, as ``ogiflow eval detection``
does) and prints, per release class from class 1 on, from the frames alone (no chain):

- the temporal contrast within ``--radius`` px of the labelled source box centre (sum of
  |frame - previous frame| in counts), as the median of each ``--window`` s window of the
  class's settled part: lowest, highest, their ratio, and the class median;
- the plume's direction seen from the source, per window: the angle (deg, counter-clockwise
  from the image's +x, so 90 = straight up) of the centroid of the pixels' temporal standard
  deviation in excess of the no-release part's;
- the rate step to the class before (x).

A wind change shows as a turn of the plume's direction; the contrast then changes at a
constant rate by more than adjacent classes differ (docs/real-footage.md). On the clip the
project ships (class 3 only), or on a whole labelled video from wherever it is stored::

    python benchmarks/gasvid_contrast.py data/ogi/gasvid/1238
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from appliance.evaluation.footage import find_sets, read_frame
from appliance.evaluation.labelled import SETTLE_S, load_labels


def load_video(folder: Path) -> tuple[dict[int, np.ndarray], dict]:
    """Frames by number (second at 1 frame/s; 2-D uint8 counts) and the labels.

    Raises
    ------
    ValueError
        No ``labels.json`` or no frames.
    """
    labels = load_labels(folder)
    if labels is None:
        raise ValueError(f"{folder}: no labels.json")
    frames = find_sets(folder.parent).get(folder.name)
    if not frames:
        raise ValueError(f"{folder}: no frameNNNN images")
    return {n: read_frame(p) for n, p in frames}, labels


def plume_angle_deg(stack: np.ndarray, background_std: np.ndarray,
                    centre: tuple[float, float], radius: float) -> float:
    """Direction of the plume from the source (deg, counter-clockwise from +x, image y down).

    Parameters
    ----------
    stack : ndarray, shape (T, H, W)
        The window's frames, counts.
    background_std : ndarray, shape (H, W)
        Per-pixel temporal standard deviation without a release, counts.
    centre : (float, float)
        Source (x, y), px.
    radius : float
        Only pixels this close to the source count, px.
    """
    # 2 counts above the background's flicker: JPEG noise and cloud texture stay out.
    excess = np.clip(stack.std(0) - background_std - 2.0, 0.0, None)
    yy, xx = np.mgrid[:excess.shape[0], :excess.shape[1]]
    weight = excess * (np.hypot(xx - centre[0], yy - centre[1]) < radius)
    total = weight.sum()
    if total <= 0:
        return float("nan")
    dx = (weight * xx).sum() / total - centre[0]
    dy = (weight * yy).sum() / total - centre[1]
    return float(np.degrees(np.arctan2(-dy, dx)))


def _stack(frames: dict[int, np.ndarray], first: int, stop: int) -> np.ndarray:
    """The frames numbered ``first`` to ``stop - 1`` that exist, (T, H, W) float32."""
    present = [frames[n] for n in range(first, stop) if n in frames]
    return np.stack(present).astype(np.float32) if present else np.empty((0, 0, 0), np.float32)


def window_contrast(frames: dict[int, np.ndarray], first: int, stop: int,
                    near: np.ndarray) -> float | None:
    """Median over the window of the temporal contrast near the source: the sum over
    ``near`` of |frame n - frame n-1| (counts), for every n in the window whose frame and
    predecessor exist; None when fewer than half of them do."""
    sums = [float(np.abs(frames[n].astype(np.float32) - frames[n - 1])[near].sum())
            for n in range(first, stop) if n in frames and n - 1 in frames]
    return float(np.median(sums)) if 2 * len(sums) >= stop - first else None


def class_rows(frames: dict[int, np.ndarray], labels: dict, radius: float,
               window_s: float) -> list[str]:
    """One printed line per release class from class 1 on (module docstring)."""
    dt = float(labels["frame_interval_s"])
    x, y, w, h = labels["source_box_xywh"]
    centre = (x + w / 2.0, y + h / 2.0)
    shape = next(iter(frames.values())).shape
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    near = np.hypot(xx - centre[0], yy - centre[1]) < radius
    classes = sorted(labels["classes"], key=lambda c: c["start_s"])
    quiet = _stack(frames, 0, int(next(c for c in classes if c["class"] == 0)["end_s"] / dt))
    if len(quiet) < 2:
        raise ValueError("no frames without a visible release (class 0) to take the "
                         "background's flicker from")
    background_std = quiet.std(0)
    step = max(2, round(window_s / dt))
    rows, previous_rate = [], None
    for c in classes:
        if c["class"] < 1:
            continue
        ratio = "" if previous_rate is None else f"x{c['rate_g_h'] / previous_rate:.2f}"
        previous_rate = c["rate_g_h"]
        a, b = int((c["start_s"] + SETTLE_S) / dt), int(c["end_s"] / dt)
        medians, angles = [], []
        for s in range(a, b - step + 1, step):
            m = window_contrast(frames, s, s + step, near)
            if m is not None:
                medians.append(m)
                angles.append(plume_angle_deg(_stack(frames, s, s + step), background_std,
                                              centre, radius))
        if not medians:
            continue
        lo, hi = min(medians) / 1e3, max(medians) / 1e3
        rows.append(
            f"class {c['class']} {c['rate_g_h']:7.1f} g/h {ratio:>6}  contrast (10^3 counts) "
            f"{lo:6.1f} - {hi:6.1f} (x{hi / lo:.1f}), median {np.median(medians) / 1e3:6.1f}"
            "  per window " + " ".join(f"{m / 1e3:4.0f}" for m in medians)
            + "  plume direction (deg) " + " ".join(f"{ang:4.0f}" for ang in angles))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("video", type=Path, help="a labelled set: frameNNNN.jpg and labels.json")
    p.add_argument("--radius", type=float, default=100.0, help="px around the source (100)")
    p.add_argument("--window", type=float, default=30.0, help="window length, s (30)")
    args = p.parse_args(argv)
    try:
        frames, labels = load_video(args.video.resolve())
        rows = class_rows(frames, labels, args.radius, args.window)
    except ValueError as exc:
        print(f"gasvid_contrast: {exc}", file=sys.stderr)
        return 2
    print(f"{args.video}: {labels.get('video', '')}, {labels.get('distance_m', '?')} m, "
          f"{len(frames)} frames; within {args.radius:.0f} px of the source, "
          f"{args.window:.0f}-s windows")
    for row in rows:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
