"""How well the differential optical depth tells a warm object's edges from moving gas.

A warm object moving inside the gas's own depth band is the one disturbance the depth gate
cannot remove (docs/evaluation-sceneflow.md). Its uniform face changes nothing; its edges
change a pixel from background to object radiance within one frame, which gas of any
plausible optical depth cannot: with the gas radiance L_g known (its temperature, about the
ambient air's), the differential optical depth (:func:`processing.preprocess.differential
.differential_image`) D = (I(t) - I(t+1)) / (I_mid - L_g) of gas is the change of its
optical depth over its transmittance, that of an object's edge (L_bg - L_obj) /
((L_bg + L_obj) / 2 - L_g), independent of the gas in front of it.

For each development scene of a matrix, both the ``moving object`` and the ``ideal``
condition are rendered (the same gas); their difference locates the object, and where its
footprint (more than 30 % of its largest radiance excess) changes between two frames is its
moving edge. The |D| of those pixels is compared with the |D| of the moving gas (the ideal
frames' gas pixels, column > 50 ppm m, away from the object, |D| > 0.005), with the gas
temperature of the simulation (285 K)::

    python benchmarks/object_optical_depth.py benchmarks/matrices/wide.yaml

prints per scene the quantiles of |D| and, per threshold, the share of object-edge pixels
and of moving-gas pixels above it: the measured basis of the chain's opaque-edge gate
(:mod:`processing.preprocess.opaque_gate`, `opaque_gate_gas_k`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from appliance.evaluation.matrix_file import load_matrix
from appliance.evaluation.robustness import Matrix, Scene, scene_frames
from processing.calibration.radiometric import gas_radiance_and_floor
from processing.preprocess.differential import differential_image, radiometric_correction

#: Gas temperature of the simulated scenes, K (``processing.synthetic.imaging.Radiometry``).
GAS_K = 285.0
#: A pixel belongs to the object's footprint above this share of its largest excess.
FOOTPRINT_SHARE = 0.3
THRESHOLDS = (0.1, 0.2, 0.3, 0.5)
QUANTILES = (0.1, 0.5, 0.9, 0.99)


def pair_depths(with_object: tuple[np.ndarray, np.ndarray], clean: tuple[np.ndarray, np.ndarray],
                gas: np.ndarray, gas_radiance: float, min_contrast: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """|D| of the object's moving edge and of the moving gas between two frames.

    Parameters
    ----------
    with_object, clean : (ndarray, ndarray), shape (H, W), float32
        Radiance at t and t+1 with the object and without it (the same gas).
    gas : ndarray, shape (H, W), bool
        Where the gas is at t (the truth's mask, thin columns left out).
    gas_radiance, min_contrast : float
        L_g and the contrast floor of :func:`differential_image`, radiance units.

    Returns
    -------
    ndarray, ndarray, 1-D float32
        |D| where the object's footprint changed between the two frames, and where gas
        away from the object moved (|D| > 0.005).
    """
    excess = [np.abs(a - b) for a, b in zip(with_object, clean, strict=True)]
    on = [e > FOOTPRINT_SHARE * e.max() if e.max() > 0 else np.zeros(e.shape, bool)
          for e in excess]
    d_obj = np.abs(differential_image(*with_object, gas_radiance, min_contrast))
    d_gas = np.abs(differential_image(*clean, gas_radiance, min_contrast))
    away = (excess[0] == 0) & (excess[1] == 0)
    return d_obj[on[0] ^ on[1]], d_gas[gas & away & (d_gas > 0.005)]


def edge_and_gas_depths(matrix: Matrix, scene: Scene, cache: Path
                        ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pair_depths` over every frame pair of one scene, pooled."""
    conds = {c.name: c for c in matrix.conditions}
    with_object, geo, _ = scene_frames(matrix, scene, conds["moving object"], cache)
    ideal, _, _ = scene_frames(matrix, scene, conds["ideal"], cache)
    curve = geo.curve_left
    if curve is None:
        raise ValueError("the matrix's frames carry no radiometric curve")
    # the chain's contrast floor: 1 K at the gas temperature
    lg, per_k = gas_radiance_and_floor(GAS_K, curve.band_m, 1.0)
    edges, gas = [], []
    for k in range(len(ideal) - 1):
        obj = (radiometric_correction(with_object[k].left, curve),
               radiometric_correction(with_object[k + 1].left, curve))
        clean = (radiometric_correction(ideal[k].left, curve),
                 radiometric_correction(ideal[k + 1].left, curve))
        mask = ideal[k].gt_mask.astype(bool) & (ideal[k].column_density_ppm_m > 50)
        e, g = pair_depths(obj, clean, mask, lg, per_k)
        edges.append(e)
        gas.append(g)
    return np.concatenate(edges), np.concatenate(gas)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("matrix", type=Path, help="matrix file (its dev part is read)")
    parser.add_argument("--cache-dir", type=Path,
                        default=Path.home() / ".cache" / "ogiflow" / "robustness")
    args = parser.parse_args(argv)
    matrix = load_matrix(args.matrix, "dev")
    header = " ".join(f"q{round(100 * q)}" for q in QUANTILES)
    print(f"{'scene':<38}{'pixels':>8}  |D| {header}   share above " +
          " ".join(f"{t:g}" for t in THRESHOLDS))
    pooled: dict[str, list[np.ndarray]] = {"object edge": [], "moving gas": []}
    for scene in matrix.scenes:
        edges, gas = edge_and_gas_depths(matrix, scene, args.cache_dir)
        for label, values in (("object edge", edges), ("moving gas", gas)):
            pooled[label].append(values)
            _row(f"{scene.name} {label}", values)
    for label, parts in pooled.items():
        _row(f"all scenes, {label}", np.concatenate(parts))
    return 0


def _row(name: str, values: np.ndarray) -> None:
    if values.size == 0:
        print(f"{name:<38}{0:>8}")
        return
    qs = " ".join(f"{v:.3f}" for v in np.quantile(values, QUANTILES))
    shares = " ".join(f"{np.mean(values > t):.3f}" for t in THRESHOLDS)
    print(f"{name:<38}{values.size:>8}  {qs}   {shares}")


if __name__ == "__main__":
    sys.exit(main())
