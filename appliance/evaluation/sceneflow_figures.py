"""Figures of ``ogiflow eval sceneflow``: mean velocity per triple and one triple's fields.

Drawn with OpenCV (no plotting library needed): ``<name>_mean_velocity.png`` plots mean V_X,
V_Y, V_Z and |V| per triple for the reference and every method, ``<name>_fields.png`` shows
V_X, V_Y, V_Z of the middle triple (reference and methods) on one symmetric colour scale
per component.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from appliance.evaluation.sceneflow import METHOD_LABELS, METHODS, Metrics

_COLOURS = {"reference": (0, 0, 0), "proposed": (40, 40, 220), "sgm_brox": (200, 120, 0),
            "sgm_farneback": (0, 160, 0)}


def _line_panel(series: dict[str, list[float | None]], title: str,
                size: tuple[int, int] = (360, 260)) -> np.ndarray:
    """One line plot (OpenCV drawing) of several series over the frame index."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 52, 10, 26, 30
    vals = [v for s in series.values() for v in s if v is not None]
    lo, hi = (min(vals), max(vals)) if vals else (0.0, 1.0)
    if hi - lo < 1e-6:
        lo, hi = lo - 0.5, hi + 0.5
    pad = 0.08 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    n = max(len(s) for s in series.values())

    def xy(i: int, v: float) -> tuple[int, int]:
        x = left + (w - left - right) * (i / max(n - 1, 1))
        y = top + (h - top - bottom) * (hi - v) / (hi - lo)
        return round(x), round(y)

    cv2.rectangle(img, (left, top), (w - right, h - bottom), (160, 160, 160), 1)
    for k in range(5):
        v = lo + (hi - lo) * k / 4
        _, y = xy(0, v)
        cv2.line(img, (left - 4, y), (left, y), (0, 0, 0), 1)
        cv2.putText(img, f"{v:.2f}", (2, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1,
                    cv2.LINE_AA)
    for i in range(n):
        x, _ = xy(i, lo)
        cv2.putText(img, str(i), (x - 3, h - bottom + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    cv2.putText(img, "triple", (w // 2 - 15, h - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                (0, 0, 0), 1, cv2.LINE_AA)
    for name, s in series.items():
        colour = _COLOURS.get(name, (100, 100, 100))
        pts = [xy(i, v) for i, v in enumerate(s) if v is not None]
        for a, b in itertools.pairwise(pts):
            cv2.line(img, a, b, colour, 2 if name == "reference" else 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, colour, -1, cv2.LINE_AA)
    return img


def _legend(width: int) -> np.ndarray:
    img = np.full((24, width, 3), 255, np.uint8)
    x = 10
    for name in ("reference", *METHODS):
        cv2.line(img, (x, 12), (x + 20, 12), _COLOURS[name], 2)
        label = "reference V*" if name == "reference" else METHOD_LABELS[name]
        cv2.putText(img, label, (x + 25, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += 35 + 9 * len(label)
    return img


def mean_velocity_figure(summary: Metrics) -> np.ndarray:
    """BGR image: V_X, V_Y, V_Z and |V| of the mean velocity per triple, all methods."""
    frames = summary["proposed"]["frames"]
    panels = []
    for c, label in enumerate(("mean V_X / m/s", "mean V_Y / m/s", "mean V_Z / m/s",
                               "|mean V| / m/s")):
        series: dict[str, list[float | None]] = {}

        def comp(v: list[float] | None, c: int = c) -> float | None:
            if v is None:
                return None
            return float(np.linalg.norm(v)) if c == 3 else float(v[c])

        series["reference"] = [comp(f["reference_mean_velocity"]) for f in frames]
        for m in METHODS:
            series[m] = [comp(f["mean_velocity"]) for f in summary[m]["frames"]]
        panels.append(_line_panel(series, label))
    top = np.hstack(panels[:2])
    bottom = np.hstack(panels[2:])
    return np.vstack([_legend(top.shape[1]), top, bottom])


def _colour_field(field: np.ndarray, mask: np.ndarray, limit: float) -> np.ndarray:
    scaled = np.clip((field / limit + 1.0) * 127.5, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(scaled, cv2.COLORMAP_JET)
    img[~mask] = (90, 90, 90)
    return img


def fields_figure(fig: dict[str, Any]) -> np.ndarray:
    """BGR image: rows V*, proposed, SGM+Brox, SGM+Fbck; columns V_X, V_Y, V_Z (one triple).

    Each column has one symmetric colour range [-L, L] m/s (L = the reference's 99th
    percentile of |V_c|, printed in the header); grey: outside the region scored.
    """
    ref, ref_mask, gas = fig["reference"], fig["reference_mask"], fig["gas_mask"]
    rows = [("reference V*", ref, ref_mask)]
    for m in METHODS:
        vel, valid = fig["fields"][m]
        rows.append((METHOD_LABELS[m], vel, gas & valid))
    limits = []
    for c in range(3):
        vals = np.abs(ref[..., c][ref_mask])
        limits.append(float(np.percentile(vals, 99)) if vals.size else 1.0)
    limits = [lim if lim > 0 else 1.0 for lim in limits]
    out_rows = []
    h, w = ref.shape[:2]
    header = np.full((22, 120 + 3 * w, 3), 255, np.uint8)
    for c, axis in enumerate("XYZ"):
        cv2.putText(header, f"V_{axis} (+-{limits[c]:.2f} m/s)", (120 + c * w + 5, 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    out_rows.append(header)
    for label, vel, mask in rows:
        lab = np.full((h, 120, 3), 255, np.uint8)
        cv2.putText(lab, label, (4, h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        tiles = [_colour_field(vel[..., c], mask, limits[c]) for c in range(3)]
        out_rows.append(np.hstack([lab, *tiles]))
    return np.vstack(out_rows)


def write_figures(directory: Path, name: str, summary: Metrics,
                  fig: dict[str, Any]) -> list[Path]:
    """Write ``<name>_mean_velocity.png`` and ``<name>_fields.png``; return their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for suffix, img in (("mean_velocity", mean_velocity_figure(summary)),
                        ("fields", fields_figure(fig) if fig else None)):
        if img is None:
            continue
        path = directory / f"{name}_{suffix}.png"
        if not cv2.imwrite(str(path), img):
            raise OSError(f"cannot write figure {path}")
        out.append(path)
    return out
