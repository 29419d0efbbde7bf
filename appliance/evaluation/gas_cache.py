"""The gas of a simulated scene (fluid + ray marching), computed once and cached on disk.

``ogiflow eval robustness`` renders every condition of a scene from the same gas frames
(:func:`gas_frames`); camera effects are applied afterwards, so they are not part of the
cache key.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

from appliance.evaluation.sceneflow import Log
from processing.synthetic.cameras import GasFrame
from processing.synthetic.config import SequenceConfig
from processing.synthetic.render import GroundTruth
from processing.synthetic.sequences import SyntheticStereoScene

#: Bump when the simulation or the cache layout changes (invalidates cached gas frames).
CACHE_VERSION = 1


def _cache_key(config: SequenceConfig) -> str:
    meta = config.meta()
    for k in ("options", "background", "radiometry", "counts_model"):
        meta.pop(k, None)
    meta["version"] = CACHE_VERSION
    text = json.dumps(meta, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _save_gas(path: Path, gas: GasFrame) -> None:
    gt = gas.truth
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, index=gas.index, t_s=gas.t_s,
                        column_left=gas.column_left.astype(np.float32),
                        column_right=gas.column_right.astype(np.float32),
                        velocity=gt.velocity, position=gt.position, mask=gt.mask,
                        column=gt.column_density_ppm_m)
    tmp.replace(path)


def _as_stored(gas: GasFrame) -> GasFrame:
    """``gas`` with its columns rounded as the cache stores them (float32), so that the run
    that simulates a scene reads the same numbers as every later run from the cache
    (measured: up to 0.2 deg of a scene's AEMV apart before)."""
    return dataclasses.replace(
        gas, column_left=gas.column_left.astype(np.float32).astype(np.float64),
        column_right=gas.column_right.astype(np.float32).astype(np.float64))


def _load_gas(path: Path) -> GasFrame:
    with np.load(path) as z:
        truth = GroundTruth(velocity=z["velocity"], position=z["position"], mask=z["mask"],
                            column_density_ppm_m=z["column"])
        return GasFrame(index=int(z["index"]), t_s=float(z["t_s"]),
                        column_left=z["column_left"].astype(np.float64),
                        column_right=z["column_right"].astype(np.float64), truth=truth)


def gas_frames(config: SequenceConfig, cache_dir: Path | None,
               log: Log | None = None) -> list[GasFrame]:
    """The gas of every frame of ``config`` (fluid + ray marching), cached per scene.

    Camera effects are not part of the key: every condition of a scene shares one
    simulation.
    """
    folder = None if cache_dir is None else cache_dir / f"gas-{_cache_key(config)}"
    paths = [] if folder is None else [folder / f"gas_{i:04d}.npz"
                                       for i in range(config.n_frames)]
    if paths and all(p.is_file() for p in paths):
        return [_load_gas(p) for p in paths]
    if log is not None:
        log(f"  simulating {config.n_frames} frames of the gas (cached afterwards)")
    scene = SyntheticStereoScene(config)
    frames = [_as_stored(scene.next_gas()) for _ in range(config.n_frames)]
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
        for p, g in zip(paths, frames, strict=True):
            _save_gas(p, g)
    return frames
