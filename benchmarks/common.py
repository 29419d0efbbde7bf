"""Helpers shared by the benchmarks: realistic inputs and robust timing.

Benchmarks are not tests: they print medians after warm-up and ratios against a
reference measured in the same run, because this machine is shared and noisy.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from appliance.evaluation.benchmark import single_thread

__all__ = ["differential_like_pair", "matrix_scene", "median_ms", "scene_arguments",
           "scene_triples", "sequence_arguments", "single_thread"]


def differential_like_pair(
    shape: tuple[int, int] = (240, 320), shift: tuple[float, float] = (1.2, -0.8), seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Two consecutive differential-image-like frames in [0, 1] (H, W) float32.

    Smooth gas-like blobs of both signs around the neutral level 0.5 (paper Eq. 2 images
    after normalisation), moving by ``shift`` px, plus independent sensor noise.
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)

    def blobs(dx: float, dy: float) -> np.ndarray:
        r = np.random.default_rng(seed)
        img = np.zeros(shape, np.float32)
        for _ in range(25):
            cx, cy = r.uniform(0.2 * w, 0.8 * w), r.uniform(0.15 * h, 0.85 * h)
            s = r.uniform(6, 25)
            a = r.uniform(-0.25, 0.25)
            img += a * np.exp(-((xx - cx - dx) ** 2 + (yy - cy - dy) ** 2) / (2 * s * s))
        return img

    noise = lambda: rng.normal(0, 0.01, shape).astype(np.float32)  # noqa: E731
    f0 = np.clip(0.5 + blobs(0, 0) + noise(), 0, 1)
    f1 = np.clip(0.5 + blobs(*shift) + noise(), 0, 1)
    return f0.astype(np.float32), f1.astype(np.float32)


def median_ms(fn: Callable[[], object], *, warmup: int = 3, runs: int = 30) -> float:
    """Median wall time of ``fn`` in ms over ``runs`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def sequence_arguments(doc: str) -> argparse.Namespace:
    """Command line of the emission analyses: sequence folders and ``--triples N``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--triples", type=int, default=None, help="first N triples only")
    return ap.parse_args()


def scene_arguments(doc: str) -> argparse.ArgumentParser:
    """Command line of the analyses of one robustness-matrix scene: ``--matrix``,
    ``--part``, ``--seed``, ``--condition``, the gas ``--cache`` and ``--config`` (add more,
    then parse)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--matrix", type=Path, required=True, help="matrix file (YAML/JSON)")
    ap.add_argument("--part", default="dev", choices=("dev", "holdout"))
    ap.add_argument("--seed", type=int, required=True, help="the scene's seed")
    ap.add_argument("--condition", default="ideal")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache/ogiflow/robustness",
                    help="gas cache of `ogiflow eval robustness`")
    ap.add_argument("--config", type=Path, default=None,
                    help="run the chain with this configuration file's processing.parameters")
    return ap


def matrix_scene(ap: argparse.ArgumentParser, args: argparse.Namespace
                 ) -> tuple[Any, Any, list[Any], Any, Any]:
    """(scene, condition, frames, geometry, chain parameters) the :func:`scene_arguments`
    name, as ``ogiflow eval robustness`` renders and runs them (``ap.error`` when the matrix
    has no such scene or condition); with ``--config FILE`` the parameters are the file's
    ``processing.parameters`` over the scene's gas depth band, as ``ogiflow eval robustness
    --config FILE`` runs them."""
    from appliance.evaluation import robustness
    from appliance.evaluation.matrix_file import load_matrix

    matrix = load_matrix(args.matrix, args.part)
    scene = next((s for s in matrix.scenes if s.seed == args.seed), None)
    cond = next((c for c in matrix.conditions if c.name == args.condition), None)
    if scene is None or cond is None:
        ap.error(f"no scene with seed {args.seed} or no condition {args.condition!r} in "
                 f"{args.matrix} ({args.part})")
    frames, geometry, params = robustness.scene_frames(matrix, scene, cond, args.cache)
    if args.config is not None:
        from appliance.evaluation.sceneflow_setup import load_processing

        params = load_processing(args.config).chain_parameters(
            {"d0": params.d0, "sgm_num_disparities": params.sgm_num_disparities})
    return scene, cond, frames, geometry, params


def scene_triples(frames: list[Any], geometry: Any, params: Any
                  ) -> Iterator[tuple[int, Any, Any, Any]]:
    """The chain over every triple of a scene's frames in one state, as ``ogiflow eval
    robustness --workers 1`` runs it (:func:`appliance.evaluation.sceneflow.chain_triples`):
    per triple its index, its first two frames (what its reference is made of,
    :func:`processing.synthetic.reference.triplet_reference`) and the SceneFlowResult."""
    from appliance.evaluation.sceneflow import chain_triples

    for i, res in chain_triples(frames, geometry, params):
        yield i, frames[i], frames[i + 1], res
