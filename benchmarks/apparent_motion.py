"""Which image motion do the differential images carry: the chain's flow or the truth's?

Run from the repository root on one scene of a robustness matrix:

    PYTHONPATH=. python benchmarks/apparent_motion.py --matrix benchmarks/matrices/wide.yaml \\
        --seed 37 [--condition ideal] [--part holdout]

The reference of a synthetic scene is the concentration-weighted, path-averaged velocity
of the gas (``processing.synthetic.reference``); its image motion is the (u, v) that Eq. 4
turns into it. When the chain's flow falls short of that motion, either the solver misses
the images' motion or the images move otherwise than the reference says. The data decide:
for every triple the second differential image is warped back by the chain's flow scaled by
s = 0.85 ... 1.35 and by the reference's flow, and the mean absolute difference to the first
on the pixels that are both segmented and gas is printed. A solver that falls short has its
smallest difference at s > 1, near the reference's ratio; images that move slower than the
reference have it near s = 1 while the reference's own flow explains them worse.
"""

from __future__ import annotations

import cv2
import numpy as np

from benchmarks.common import matrix_scene, scene_arguments, scene_triples
from processing.synthetic.reference import eq4_reference

SCALES = tuple(np.round(np.arange(0.85, 1.351, 0.05), 2))


def warp_residual(d0: np.ndarray, d1: np.ndarray, flow: np.ndarray, mask: np.ndarray) -> float:
    """Mean |d1(x + w(x)) - d0(x)| over ``mask``: how well the flow w explains d0 -> d1.

    Parameters
    ----------
    d0, d1 : ndarray, shape (H, W)
        Two differential images (any unit; the result is in it).
    flow : ndarray, shape (H, W, 2)
        w = (u, v) in px per frame, NaN allowed (read as 0).
    mask : ndarray, shape (H, W), bool
        Pixels to average over (at least one).
    """
    h, w = d0.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    f = np.nan_to_num(np.asarray(flow, dtype=np.float32))
    back = cv2.remap(np.asarray(d1, np.float32), xx + f[..., 0], yy + f[..., 1],
                     cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return float(np.mean(np.abs(back - np.asarray(d0, np.float32))[mask]))


def best_scale(d0: np.ndarray, d1: np.ndarray, flow: np.ndarray, mask: np.ndarray,
               scales: tuple[float, ...] = SCALES) -> tuple[float, list[float]]:
    """The factor s of ``scales`` whose flow s w explains d0 -> d1 best (:func:`warp_residual`),
    and the residual of every factor."""
    res = [warp_residual(d0, d1, s * np.nan_to_num(flow), mask) for s in scales]
    return float(scales[int(np.argmin(res))]), res


def along_ratio(flow: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """sum(w . w_ref) / sum(|w_ref|^2) over ``mask``: the flow's length along the reference
    flow, as a share of it (1 = as fast), both (H, W, 2) px per frame."""
    w, r = flow[mask].astype(np.float64), reference[mask].astype(np.float64)
    return float(np.sum(w * r) / np.sum(r * r))


def main(argv: list[str] | None = None) -> int:
    ap = scene_arguments(__doc__ or "")
    scene, cond, frames, geometry, params = matrix_scene(ap, ap.parse_args(argv))
    s_px, b_m = geometry.camera_constant, geometry.baseline
    print(f"{scene.name} {cond.name}: per triple, on segmented gas pixels")
    print("triple  flow/reference  best s  residual(s=1)  residual(reference)")
    rows = []
    for i, f0, f1, res in scene_triples(frames, geometry, params):
        dt = f1.t_s - f0.t_s
        r0, r1 = (eq4_reference(f.gt_position, f.gt_velocity, s_px, b_m, dt)
                  for f in (f0, f1))
        ref = np.stack([0.5 * (r0.u + r1.u), 0.5 * (r0.v + r1.v)], axis=-1)
        mask = res.gas_mask & res.valid & f0.gt_mask & np.all(np.isfinite(ref), axis=-1)
        if not mask.any():
            print(f"{i:6d}  no gas")
            continue
        d0, d1 = res.diff_left
        s, scan = best_scale(d0, d1, res.flow, mask)
        row = (along_ratio(res.flow, ref, mask), s, scan[SCALES.index(1.0)],
               warp_residual(d0, d1, ref, mask))
        rows.append(row)
        print(f"{i:6d}  {row[0]:14.2f}  {row[1]:6.2f}  {row[2]:13.4f}  {row[3]:19.4f}")
    if rows:
        med = np.median(np.array(rows), axis=0)
        print(f"median  {med[0]:14.2f}  {med[1]:6.2f}  {med[2]:13.4f}  {med[3]:19.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
