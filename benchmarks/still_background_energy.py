"""What the temporal data terms see on a still, noisy background.

Run from the repository root on one scene of a robustness matrix:

    PYTHONPATH=. python benchmarks/still_background_energy.py \\
        --matrix benchmarks/matrices/wide.yaml --seed 47 --condition "noise 0.03 K"

The chain's two differential images of a camera, D(t0) = I(t0) - I(t1) and D(t1) = I(t1) -
I(t2), share the frame I(t1) with opposite signs, so on a still background their noise is
anti-correlated. The temporal terms compare one with the other shifted: the flow's
brightness constancy (Eq. 5, left camera, shifted by the flow) and E3 of Eq. 6 (right
camera, shifted horizontally by the flow and d'). On still pixels the true shift is 0, yet
the mean squared difference D(t1)(x + s) - D(t0)(x) is largest there: the shared frame
counts twice at s = 0 and is spread apart by any shift. For every triple this prints that
mean over the still pixels (no reference gas within ``--margin`` px in either view, not
blanked, away from the borders) for horizontal shifts s of the left and the right camera's
images, relative to its value at s = 0, and the chain's mean |u|, |v| and |d'| on the same
pixels; the medians over the triples at the end.
"""

from __future__ import annotations

import cv2
import numpy as np

from benchmarks.common import matrix_scene, scene_arguments, scene_triples
from processing.synthetic.reference import triplet_reference

SHIFTS_PX = (-1.0, -0.5, -0.25, 0.0, 0.25, 0.5, 1.0)
BORDER_PX = 16


def shifted_energy(d0: np.ndarray, d1: np.ndarray, mask: np.ndarray,
                   shifts: tuple[float, ...] = SHIFTS_PX) -> np.ndarray:
    """Mean of (d1(x + s, y) - d0(x, y))^2 over ``mask`` for each horizontal shift s.

    Parameters
    ----------
    d0, d1 : ndarray, shape (H, W)
        Two differential images of one camera.
    mask : ndarray, shape (H, W), bool
        The pixels to average over (at least one).
    shifts : tuple of float
        Horizontal shifts in px (cubic interpolation).

    Returns
    -------
    ndarray, shape (len(shifts),)
        The mean squared difference per shift, in the images' units squared.
    """
    h, w = d0.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    a0 = np.asarray(d0, np.float32)
    a1 = np.asarray(d1, np.float32)
    out = []
    for s in shifts:
        moved = cv2.remap(a1, xx + np.float32(s), yy, cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REPLICATE)
        out.append(float(np.mean(((moved - a0) ** 2)[mask])))
    return np.asarray(out)


def still_pixels(gas: np.ndarray, blanked: np.ndarray, margin_px: int) -> np.ndarray:
    """Pixels with no gas within ``margin_px``, not blanked, :data:`BORDER_PX` from the
    borders; shape (H, W), bool."""
    k = 2 * margin_px + 1
    near_gas = cv2.dilate(gas.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    keep = ~near_gas & ~blanked
    keep[:BORDER_PX] = keep[-BORDER_PX:] = False
    keep[:, :BORDER_PX] = keep[:, -BORDER_PX:] = False
    return keep


def seen_right(gas: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """The left view's ``gas`` (H, W) bool moved to where the right view sees it: left by
    the median disparity (px) on it; nothing where it has no finite disparity."""
    d = disparity[gas & np.isfinite(disparity)]
    out = np.zeros_like(gas)
    if d.size == 0:
        return out
    shift = round(float(np.median(d)))
    if 0 < shift < gas.shape[1]:
        out[:, :-shift] = gas[:, shift:]
    else:
        out[:] = gas
    return out


def main(argv: list[str] | None = None) -> int:
    ap = scene_arguments(__doc__ or "")
    ap.add_argument("--margin", type=int, default=10,
                    help="px kept clear of the reference's gas (default 10)")
    args = ap.parse_args(argv)
    scene, cond, frames, geometry, params = matrix_scene(ap, args)
    print(f"{scene.name} {cond.name}: still pixels; energy at shift s relative to s = 0")
    print("triple  pixels  left (flow): " + " ".join(f"{s:5.2f}" for s in SHIFTS_PX)
          + "  |  right (E3): " + " ".join(f"{s:5.2f}" for s in SHIFTS_PX)
          + "  |  |u|, |v|, |d'| px")
    rows = []
    for i, f0, f1, res in scene_triples(frames, geometry, params):
        _ref, ref_mask = triplet_reference(f0, f1)
        # A blanked pixel holds exactly 0 in both of the left view's differential images.
        blanked = (res.diff_left[0] == 0) & (res.diff_left[1] == 0)
        keep = still_pixels(ref_mask, blanked, args.margin)
        # The right view sees the gas d px further left (x_R = x - d).
        keep_right = still_pixels(ref_mask | seen_right(ref_mask, res.disparity), blanked,
                                  args.margin)
        if not keep.any() or not keep_right.any():
            print(f"{i:6d}  no still pixel")
            continue
        left = shifted_energy(res.diff_left[0], res.diff_left[1], keep)
        right = shifted_energy(res.diff_right[0], res.diff_right[1], keep_right)
        zero = SHIFTS_PX.index(0.0)
        rel_l = left / left[zero] if left[zero] > 0 else np.full_like(left, np.nan)
        rel_r = right / right[zero] if right[zero] > 0 else np.full_like(right, np.nan)
        motion = np.array([np.nanmean(np.abs(res.flow[..., 0][keep])),
                           np.nanmean(np.abs(res.flow[..., 1][keep])),
                           np.nanmean(np.abs(res.disparity_change[keep]))])
        rows.append(np.concatenate([rel_l, rel_r, motion]))
        print(f"{i:6d}  {int(keep.sum()):6d}  {_row(rows[-1])}")
    if rows:
        print(f"median          {_row(np.nanmedian(np.array(rows), axis=0))}")
    return 0


def _row(values: np.ndarray) -> str:
    """A printed row: the left and the right camera's relative energies, then |u|, |v|, |d'|."""
    n = len(SHIFTS_PX)
    left = " ".join(f"{x:5.2f}" for x in values[:n])
    right = " ".join(f"{x:5.2f}" for x in values[n:2 * n])
    return f"{left}  |  {right}  |  {values[-3]:.3f}, {values[-2]:.3f}, {values[-1]:.3f}"


if __name__ == "__main__":
    raise SystemExit(main())
