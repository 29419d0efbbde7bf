"""Pre-processing, flow and gas segmentation on real OGI frames (``ogiflow eval footage``).

Every folder under the data folder (at any depth, named by its path relative to it) holding
images named ``*frame<N>.<ext>`` (JPEG, PNG, TIFF; 8 or 16 bit, one camera) is one set.
Frames are ordered by N; only triples of consecutive frame numbers (N, N+1, N+2) are
processed, so sets whose frames are not all consecutive are split into their consecutive
runs (e.g. the clips of ``data/ogi/gasvid``: 20-79, 600-659).
For each triple: differential images (Eq. 2) with jitter removal and Sobolev denoising
(:func:`processing.preprocess.differential.preprocess_camera`, identity characteristic curve: the
footage is uncalibrated counts), Brox flow between the two differential images (Eq. 5)
and the level-set segmentation (Eq. 9). Reported per frame: the segmented gas fraction
(gas pixels / all pixels) of I_diff(t0 = N), the gas/background activity ratio, the
registration shifts and the median flow magnitude.
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from appliance.live.colour import flow_bgr
from appliance.paths import walk
from appliance.runtime.single_camera import MonoTriple, mono_triple

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
FRAME_NUMBER = re.compile(r"frame(\d+)\.[A-Za-z]+$")


@dataclass(frozen=True)
class FootageSettings:
    """Settings of one evaluation.

    Attributes
    ----------
    scale
        Normalisation scale: the intensity difference in the frames' counts mapped to 1.0.
    denoise_lambda
        Sobolev prior weight in px^2 (0 disables denoising).
    register
        Remove camera jitter by registration.
    min_activity_ratio
        Gas accepted only if its activity exceeds the background's by this factor.
    """

    scale: float = 5.0
    denoise_lambda: float = 10.0
    register: bool = True
    min_activity_ratio: float = 1.5

    def __post_init__(self) -> None:
        if not np.isfinite(self.scale) or self.scale <= 0:
            raise ValueError(f"--scale must be a positive number, got {self.scale}")
        if not np.isfinite(self.denoise_lambda) or self.denoise_lambda < 0:
            raise ValueError(f"--denoise-lambda must be >= 0, got {self.denoise_lambda}")


@dataclass
class FigureFrame:
    """What the figure of one frame shows: raw frame, I_diff (in [0, 1]), flow, gas mask."""

    set_name: str
    frame: int
    raw: np.ndarray
    diff: np.ndarray
    flow: np.ndarray
    mask: np.ndarray


@dataclass
class FootageReport:
    """Result of :func:`evaluate_footage`.

    Attributes
    ----------
    sets
        Per set name: ``runs``, ``gas_fraction_per_run``, ``triples_used``,
        ``frames_in_set``, ``gas_fraction`` (mean/min/max or None), ``frames_with_gas`` and
        ``frames`` (one dict per processed triple), JSON-ready.
    stage_ms
        Median ms per triple of ``preprocess``, ``flow``, ``segmentation`` (None: no triple).
    figure
        The chosen figure frame, or None when none was asked for or found.
    """

    sets: dict[str, dict[str, Any]] = field(default_factory=dict)
    stage_ms: dict[str, float | None] = field(default_factory=dict)
    figure: FigureFrame | None = None


def find_sets(data: Path) -> dict[str, list[tuple[int, Path]]]:
    """Image sets under ``data``: {folder path relative to ``data``: [(frame number, path),
    ...] sorted}, for every folder below ``data`` that holds frames (``data/ogi`` holds
    ``gasvid/1237``, ...)."""
    if not data.is_dir():
        raise ValueError(f"--data {data} is not a directory")
    sets: dict[str, list[tuple[int, Path]]] = {}
    for sub in sorted(p for p in walk(data) if p.is_dir()):
        frames = []
        for f in sub.iterdir():
            m = FRAME_NUMBER.search(f.name)
            if m and f.suffix.lower() in IMAGE_SUFFIXES:
                frames.append((int(m.group(1)), f))
        if frames:
            sets[sub.relative_to(data).as_posix()] = sorted(frames)
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
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot read image {path}")
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel image, got shape {img.shape}")
    return img


def make_figure(fig: FigureFrame, title: str) -> np.ndarray:
    """Four panels side by side: raw frame, I_diff, colour-coded flow, mask on I_diff.

    Returns an (24 + 22 + H, 4 (W + 2), 3) uint8 BGR image.
    """
    def grey(img: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)

    raw8 = fig.raw.astype(np.float32)
    lo, hi = float(raw8.min()), float(raw8.max())
    raw8 = ((raw8 - lo) / max(hi - lo, 1e-6) * 255).astype(np.uint8)
    diff8 = (np.clip(fig.diff, 0.0, 1.0) * 255).astype(np.uint8)
    mag = np.hypot(fig.flow[..., 0], fig.flow[..., 1])
    max_mag = float(np.percentile(mag, 99)) or 1.0
    overlay = grey(diff8)
    tint = overlay.copy()
    tint[fig.mask] = (0, 0, 255)
    overlay = cv2.addWeighted(overlay, 0.6, tint, 0.4, 0)
    contours, _ = cv2.findContours(fig.mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(overlay, contours, -1, (0, 255, 255), 1)
    panels = [
        (grey(raw8), "raw frame"),
        (grey(diff8), "I_diff (0.5 = no change)"),
        (flow_bgr(fig.flow, max_mag), f"flow, |w| <= {max_mag:.2f} px"),
        (overlay, f"gas mask {100.0 * fig.mask.mean():.1f} %"),
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


def iter_mono_triples(name: str, frames: list[tuple[int, Path]], settings: FootageSettings
                      ) -> Iterator[MonoTriple]:
    """Pre-processing, flow and segmentation of every consecutive triple of one set.

    Raises
    ------
    ValueError
        An unreadable image, or frames of one triple that differ in size.
    """
    paths = dict(frames)
    shift01 = None
    prev_n = None
    cache: dict[int, np.ndarray] = {}
    for first, last in consecutive_runs([n for n, _ in frames]):
        for n in range(first, last - 1):
            imgs = []
            for k in (n, n + 1, n + 2):
                if k not in cache:
                    cache[k] = read_frame(paths[k])
                imgs.append(cache[k])
            cache.pop(n - 1, None)
            try:
                tr = mono_triple(n, imgs, scale=settings.scale, register=settings.register,
                                 denoise_lambda=settings.denoise_lambda,
                                 shift01=shift01 if prev_n == n - 1 else None,
                                 segmentation_options={
                                     "min_activity_ratio": settings.min_activity_ratio})
            except ValueError as exc:
                raise ValueError(f"{name}: {exc}") from None
            shift01, prev_n = tr.shifts[1], n
            yield tr


def evaluate_footage(data: Path, settings: FootageSettings, *, figure_set: str | None = None,
                     figure_frame: int | None = None) -> FootageReport:
    """Run the chain's first stages on every consecutive triple of every set under ``data``.

    Parameters
    ----------
    data
        Folder of image sets (see the module docstring).
    settings
        Pre-processing and segmentation settings.
    figure_set
        Pick the figure frame from the first set whose name contains this text (None: no
        figure).
    figure_frame
        Frame number N for the figure; None: the set's most confident segmentation (the
        largest gas/background activity ratio among frames with gas).

    Raises
    ------
    ValueError
        No sets, no set matching ``figure_set``, an unreadable image, or frames of one
        triple that differ in size.
    """
    sets = find_sets(data)
    if figure_set is not None:
        match = next((name for name in sets if figure_set in name), None)
        if match is None:
            raise ValueError(f"--figure: no set under {data} has {figure_set!r} in its name")
        figure_set = match
    timings: dict[str, list[float]] = {"preprocess": [], "flow": [], "segmentation": []}
    report = FootageReport()
    best_key = -np.inf
    for name, frames in sets.items():
        numbers = [n for n, _ in frames]
        runs = consecutive_runs(numbers)
        per_frame = []
        for tr in iter_mono_triples(name, frames, settings):
            for stage, ms in tr.timings_ms.items():
                timings[stage].append(ms)
            mag = np.sqrt(tr.flow[..., 0] ** 2 + tr.flow[..., 1] ** 2)
            per_frame.append({
                "frame": tr.frame,
                "gas_fraction": float(tr.mask.mean()),
                "gas_pixels": int(tr.mask.sum()),
                "activity_ratio": float(tr.activity_ratio),
                "shift01_px": [round(v, 4) for v in tr.shifts[0]],
                "shift12_px": [round(v, 4) for v in tr.shifts[1]],
                "flow_median_px": float(np.median(mag)),
            })
            if name == figure_set and figure_frame in (None, tr.frame):
                key = tr.activity_ratio if tr.mask.any() else -1.0
                if key > best_key:
                    best_key = key
                    report.figure = FigureFrame(name, tr.frame, tr.raw, tr.diff, tr.flow,
                                                tr.mask)
        fractions = [e["gas_fraction"] for e in per_frame]
        report.sets[name] = {
            "runs": [list(r) for r in runs],
            "gas_fraction_per_run": {
                f"{a}-{b}": _stats([e["gas_fraction"] for e in per_frame
                                    if a <= e["frame"] <= b])
                for a, b in runs
            },
            "triples_used": len(per_frame),
            "frames_in_set": len(numbers),
            "gas_fraction": _stats(fractions),
            "frames_with_gas": sum(1 for f in fractions if f > 0),
            "frames": per_frame,
        }
    report.stage_ms = {k: (statistics.median(v) if v else None) for k, v in timings.items()}
    return report
