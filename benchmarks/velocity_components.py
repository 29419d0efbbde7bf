"""Which component of the gas velocity falls short: the chain's mean V against the reference.

Run from the repository root on one scene of a robustness matrix:

    PYTHONPATH=. python benchmarks/velocity_components.py --matrix benchmarks/matrices/wide.yaml \\
        --seed 47 [--condition "noise 0.03 K"] [--part holdout] [--config FILE]

For every triple, on the pixels that are segmented, valid and gas (the reference's mask):
the measured and the reference mean of V_X, V_Y, V_Z (Eq. 4, m/s, left camera frame), the
mean disparity d and disparity change d' there (px), the normalisation scale the chain used
and its flags. At the end: the means over the triples, each component's share of the
reference (measured / reference; none where the reference has next to nothing of that
component), the scene's RMVE / AEMV as ``ogiflow eval robustness`` computes them (Eq. 10:
the segmented region against the reference's), and the magnitude of Eq. 10's mean as three
factors (:func:`magnitude_factors`): what the segmented pixels that are not the reference's
gas do to it, the velocity on the common pixels, and what the reference's gas left out of
the segmentation would have added. ``--config FILE`` runs the chain as
``ogiflow eval robustness --config FILE`` does (the file's ``processing.parameters`` over the
scene's gas depth band), e.g. with ``disparity_options: {constant_mode: false}`` or a fixed
``diff_scale``; without it, the matrix's field settings.
"""

from __future__ import annotations

import numpy as np

from appliance.evaluation.sceneflow import common_mean_velocities, frame_metrics
from benchmarks.common import matrix_scene, scene_arguments, scene_triples
from processing.metrics import sceneflow as sm
from processing.synthetic.reference import triplet_reference

#: A component of the reference below this share of its speed has no meaningful share.
MIN_COMPONENT_SHARE = 0.05


def component_shares(measured: np.ndarray, reference: np.ndarray,
                     min_share: float = MIN_COMPONENT_SHARE) -> np.ndarray:
    """measured / reference per component, shape (3,); NaN where the reference component is
    below ``min_share`` of the reference speed (an in-plane wind's V_Z: any ratio is noise).
    """
    m = np.asarray(measured, np.float64)
    r = np.asarray(reference, np.float64)
    speed = float(np.linalg.norm(r))
    out = np.full(3, np.nan)
    big = np.abs(r) >= min_share * speed if speed > 0 else np.zeros(3, bool)
    out[big] = m[big] / r[big]
    return out


def magnitude_factors(velocity: np.ndarray, region: np.ndarray, reference: np.ndarray,
                      reference_mask: np.ndarray) -> tuple[float, float, float] | None:
    """|V_avg| / |V*_avg| of Eq. 10 as the product of three factors.

    Parameters
    ----------
    velocity, reference : ndarray, shape (H, W, 3)
        Measured V and reference V*, m/s (the reference may hold NaN off its mask).
    region, reference_mask : ndarray, shape (H, W), bool
        The measured mean's pixels (segmented and valid) and the reference's gas.

    Returns
    -------
    (float, float, float) or None
        ``extra`` = |V_avg(region)| / |V_avg(common)|: the segmented pixels that are not the
        reference's gas; ``velocity`` = |V_avg(common)| / |V*_avg(common)|: the measurement
        where both count gas; ``coverage`` = |V*_avg(common)| / |V*_avg(reference mask)|:
        the reference's gas the segmentation leaves out. Their product is |V_avg| /
        |V*_avg|, i.e. 1 - RMVE / 100 % for a short mean. None without a common pixel.
    """
    measured_common, reference_common, _ = common_mean_velocities(
        velocity, region, region, reference, reference_mask)
    if measured_common is None or reference_common is None:
        return None
    speed = [float(np.linalg.norm(v)) for v in (
        sm.mean_velocity(velocity, region), measured_common, reference_common,
        sm.mean_velocity(reference, reference_mask))]
    return speed[0] / speed[1], speed[1] / speed[2], speed[2] / speed[3]


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join("  n/a" if not np.isfinite(x) else f"{x:5.2f}" for x in v) + ")"


def main(argv: list[str] | None = None) -> int:
    ap = scene_arguments(__doc__ or "")
    args = ap.parse_args(argv)
    scene, cond, frames, geometry, params = matrix_scene(ap, args)
    print(f"{scene.name} {cond.name}: per triple, on the pixels segmented, valid and gas")
    print("triple  pixels  V measured (m/s)        V reference (m/s)       d (px)  d' (px)"
          "  scale      flags")
    measured, truth, rmve, aemv, factors = [], [], [], [], []
    for i, f0, f1, res in scene_triples(frames, geometry, params):
        ref, ref_mask = triplet_reference(f0, f1)
        metrics = frame_metrics(res.velocity, res.valid, res.gas_mask, res.u_sf,
                                res.u_sf_valid, ref, ref_mask)
        if metrics["rmve"] is not None:
            rmve.append(metrics["rmve"])
            aemv.append(metrics["aemv"])
        split = magnitude_factors(res.velocity, res.gas_mask & res.valid, ref, ref_mask)
        if split is not None:
            factors.append(split)
        v, r, both = common_mean_velocities(res.velocity, res.valid, res.gas_mask, ref,
                                            ref_mask)
        if v is None or r is None:
            print(f"{i:6d}  no pixel segmented, valid and gas")
            continue
        measured.append(v)
        truth.append(r)
        print(f"{i:6d}  {int(both.sum()):6d}  {_fmt(v)}  {_fmt(r)}  "
              f"{float(res.disparity[both].mean()):6.2f}  "
              f"{float(res.disparity_change[both].mean()):7.3f}  {res.diff_scale:9.3g}  "
              f"{','.join(res.summary.flags) or '-'}")
    if not measured:
        return 0
    v, r = np.mean(measured, axis=0), np.mean(truth, axis=0)
    print(f"mean    {'':6s}  {_fmt(v)}  {_fmt(r)}")
    print(f"share of the reference (V_X, V_Y, V_Z): {_fmt(component_shares(v, r))}")
    if rmve:
        print(f"scene RMVE {np.mean(rmve):.1f} %, AEMV {np.mean(aemv):.1f} deg "
              f"({len(rmve)} triples; as `ogiflow eval robustness`)")
    if factors:
        extra, vel, cover = np.mean(factors, axis=0)
        print(f"|V_avg| / |V*_avg| as factors (means over the triples): segmented beyond "
              f"the gas {extra:.3f} x velocity on the common pixels {vel:.3f} x the gas "
              f"left out {cover:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
