"""Optical-flow accuracy and speed on Middlebury-layout data (``ogiflow eval flow``).

Every subfolder of the dataset holding ``frame10.png``, ``frame11.png`` and ``flow10.flo``
is one sequence. For each, our Brox flow (paper Eq. 5) and, in the same run, OpenCV
Farneback and DIS (medium preset) are scored by the average endpoint error over pixels
with known ground truth, and timed (median of ``repeats`` runs after one warm-up).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from processing.flow.brox import brox_optical_flow
from processing.flow.opencv import dis_flow, farneback_flow
from processing.metrics.flo import known_mask, read_flo
from processing.metrics.flow import average_endpoint_error

#: The alpha x beta grid of the paper's Table 1.
TABLE1_ALPHAS = (0.5, 0.1, 0.05, 0.01)
TABLE1_BETAS = (1.0, 0.5, 0.01)
#: Paper Table 1, Brox, (Dimetrodon, Hydrangea, Urban2) AEE in px, for reference prints.
TABLE1_PAPER = {
    (0.5, 1.0): (0.7, 0.7, 7.0), (0.5, 0.5): (0.8, 1.3, 7.3), (0.5, 0.01): (0.9, 1.6, 7.5),
    (0.1, 1.0): (0.4, 0.5, 1.4), (0.1, 0.5): (0.4, 0.5, 1.1), (0.1, 0.01): (0.4, 0.5, 1.1),
    (0.05, 1.0): (0.3, 0.5, 1.2), (0.05, 0.5): (0.3, 0.5, 1.1), (0.05, 0.01): (0.4, 0.5, 1.1),
    (0.01, 1.0): (0.4, 0.8, 1.5), (0.01, 0.5): (0.4, 0.7, 1.2), (0.01, 0.01): (0.4, 0.5, 1.1),
}

FlowFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


#: Per sequence, per method: {"aee": px, "ms": median ms}.
FlowResults = dict[str, dict[str, dict[str, float]]]


def find_sequences(dataset: Path) -> list[Path]:
    """Subfolders of ``dataset`` in Middlebury layout, sorted by name.

    Raises
    ------
    ValueError
        The folder does not exist, or holds no complete sequence.
    """
    if not dataset.is_dir():
        raise ValueError(f"dataset folder {dataset} does not exist")
    needed = ("frame10.png", "frame11.png", "flow10.flo")
    seqs = [d for d in sorted(dataset.iterdir()) if d.is_dir()]
    complete = [d for d in seqs if all((d / n).is_file() for n in needed)]
    if not complete:
        raise ValueError(
            f"{dataset} holds no sequence folder with {', '.join(needed)}"
        )
    return complete


def read_grey01(path: Path) -> np.ndarray:
    """Read an 8- or 16-bit image as grey float32 scaled to [0, 1]."""
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float32) / np.float32(scale)


def time_method(
    fn: FlowFn, i0: np.ndarray, i1: np.ndarray, repeats: int
) -> tuple[np.ndarray, float]:
    """Run ``fn`` once to warm up, then ``repeats`` times; return (flow, median ms)."""
    flow = fn(i0, i1)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        flow = fn(i0, i1)
        times.append((time.perf_counter() - t) * 1e3)
    return flow, statistics.median(times)


def flow_methods(alpha: float, beta: float, grid: bool = False) -> dict[str, FlowFn]:
    """Our Brox flow with (alpha, beta), OpenCV Farneback and DIS medium; with ``grid`` also
    Brox at every (alpha, beta) of the paper's Table 1."""

    def brox(a: float, b: float) -> FlowFn:
        return lambda i0, i1: brox_optical_flow(i0, i1, alpha=a, beta=b)

    methods: dict[str, FlowFn] = {
        f"brox(alpha={alpha:g},beta={beta:g})": brox(alpha, beta),
        "farneback": farneback_flow,
        "dis_medium": dis_flow,
    }
    if grid:
        for a in TABLE1_ALPHAS:
            for b in TABLE1_BETAS:
                methods.setdefault(f"brox(alpha={a:g},beta={b:g})", brox(a, b))
    return methods


def evaluate_flow(dataset: Path, methods: dict[str, FlowFn], repeats: int,
                  on_result: Callable[[str, str, dict[str, float]], None] | None = None
                  ) -> FlowResults:
    """AEE (px) and median runtime (ms) of every method on every sequence of ``dataset``.

    All methods run on one thread (OpenCV is set to one thread here): the runtime column
    compares like with like. ``on_result(sequence, method, scores)`` is called after each.

    Raises
    ------
    ValueError
        ``repeats`` < 1, no sequence, or frames and ground truth of a sequence differ in size.
    """

    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    cv2.setNumThreads(1)
    results: FlowResults = {}
    for seq in find_sequences(dataset):
        i0 = read_grey01(seq / "frame10.png")
        i1 = read_grey01(seq / "frame11.png")
        gt = read_flo(seq / "flow10.flo")
        if gt.shape[:2] != i0.shape or i1.shape != i0.shape:
            raise ValueError(
                f"{seq}: frames {i0.shape}/{i1.shape} and ground truth {gt.shape[:2]} differ"
            )
        mask = known_mask(gt)
        results[seq.name] = {}
        for name, fn in methods.items():
            flow, ms = time_method(fn, i0, i1, repeats)
            scores = {"aee": average_endpoint_error(flow, gt, mask), "ms": ms}
            results[seq.name][name] = scores
            if on_result is not None:
                on_result(seq.name, name, scores)
    return results


def format_table(results: FlowResults) -> str:
    """Methods as rows, sequences as columns: 'AEE px / ms'."""
    seqs = list(results)
    methods = list(next(iter(results.values())))
    head = f"{'method':28s}" + "".join(f"{s:>24s}" for s in seqs)
    lines = [head, "-" * len(head)]
    for m in methods:
        cells = "".join(
            f"{results[s][m]['aee']:>10.3f} px {results[s][m]['ms']:>7.1f} ms" for s in seqs
        )
        lines.append(f"{m:28s}{cells}")
    return "\n".join(lines)


def format_grid(results: FlowResults) -> str:
    """Paper Table 1 layout: rows alpha, columns beta, cells = AEE per sequence (ours | paper)."""
    seqs = list(results)
    lines = [f"Brox AEE in px, ({', '.join(seqs)}); paper Table 1 in brackets"]
    betas = "".join(f"{'beta=' + format(b, 'g'):>38s}" for b in TABLE1_BETAS)
    lines.append(f"{'alpha':>6s}{betas}")
    for a in TABLE1_ALPHAS:
        row = f"{a:>6g}"
        for b in TABLE1_BETAS:
            name = f"brox(alpha={a:g},beta={b:g})"
            ours = ", ".join(f"{results[s][name]['aee']:.2f}" for s in seqs)
            paper = TABLE1_PAPER.get((a, b))
            ref = f" [{', '.join(f'{x:.1f}' for x in paper)}]" if paper and len(seqs) == 3 else ""
            row += f"{'(' + ours + ')' + ref:>38s}"
        lines.append(row)
    return "\n".join(lines)
