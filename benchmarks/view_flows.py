"""Do the two cameras' differential images move alike? d' from each view's own flow.

Run from the repository root on one scene of a robustness matrix:

    PYTHONPATH=. python benchmarks/view_flows.py --matrix benchmarks/matrices/wide.yaml \\
        --seed 31 [--condition ideal] [--part holdout] [--config FILE]

The chain measures d' with the joint solver (Eq. 6), given the left view's flow (Eq. 5):
the right view's motion is the left one's less d'. Here each view's differential images
get their own flow, solved cold with the chain's flow solver and parameters, and the
d' they imply, u_L(x) - u_R(x - d(x)) (px per frame, x along the rectified rows), is
printed beside the chain's for every triple, as the mean and median on the pixels that are
segmented, valid and gas. Where the gas moves in the image plane the reference's d' is 0:
an implied d' away from 0 says the two views' images themselves move differently (for
example the wall behind the gas modulating each view's differential image otherwise,
docs/evaluation-sceneflow.md), not the joint solver.
"""

from __future__ import annotations

import cv2
import numpy as np

from appliance.evaluation.sceneflow import common_mean_velocities
from benchmarks.common import matrix_scene, scene_arguments, scene_triples
from processing.flow.brox import brox_optical_flow
from processing.solvers.derivatives import pixel_grid
from processing.synthetic.reference import triplet_reference


def implied_change(u_left: np.ndarray, u_right: np.ndarray, disparity: np.ndarray
                   ) -> np.ndarray:
    """d' implied by the two views' horizontal flows: u_L(x) - u_R(x - d(x)), px per frame.

    Parameters
    ----------
    u_left, u_right : ndarray, shape (H, W)
        Horizontal flow of the left and the right view's differential images, px per
        frame, each on its own view's pixel grid.
    disparity : ndarray, shape (H, W)
        d of the left view's pixels, px (x_R = x_L - d).

    Returns
    -------
    ndarray, shape (H, W), float32
        The right flow sampled (bilinear) at each left pixel's partner, subtracted from the
        left flow; partners outside the right view take its border value.
    """
    xx, yy = pixel_grid(u_left.shape)
    partner = xx - np.asarray(disparity, np.float32)
    u_r = cv2.remap(np.asarray(u_right, np.float32), partner, yy, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return np.asarray(u_left, np.float32) - u_r


def main(argv: list[str] | None = None) -> int:
    ap = scene_arguments(__doc__ or "")
    args = ap.parse_args(argv)
    scene, cond, frames, geometry, params = matrix_scene(ap, args)
    flow_args = {"alpha": params.alpha, "beta": params.beta, **params.flow_options}
    print(f"{scene.name} {cond.name}: per triple, on the pixels segmented, valid and gas")
    print("triple  pixels  chain d'  implied d' mean  median  u_L   u_R(x - d)  (px per frame)")
    for i, f0, f1, res in scene_triples(frames, geometry, params):
        ref, ref_mask = triplet_reference(f0, f1)
        _, _, both = common_mean_velocities(res.velocity, res.valid, res.gas_mask, ref,
                                            ref_mask)
        if not both.any():
            print(f"{i:6d}  no pixel segmented, valid and gas")
            continue
        u_l = brox_optical_flow(*res.diff_left, **flow_args)[..., 0]
        u_r = brox_optical_flow(*res.diff_right, **flow_args)[..., 0]
        implied = implied_change(u_l, u_r, res.disparity)
        print(f"{i:6d}  {int(both.sum()):6d}  {float(res.disparity_change[both].mean()):8.3f}"
              f"  {float(implied[both].mean()):15.3f}  {float(np.median(implied[both])):6.3f}"
              f"  {float(u_l[both].mean()):5.2f}  {float((u_l - implied)[both].mean()):5.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
