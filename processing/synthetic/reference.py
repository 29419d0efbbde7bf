"""Reference fields for evaluating scene flow on synthetic sequences (paper Eq. 4, Sec. 5.1).

The synthetic ground truth is 3D (V*, P* per left pixel). An evaluation of the chain also
wants the image quantities Eq. 4 is built from - optical flow ``w_L = (u, v)``, disparity
``d_L`` and disparity change ``d'_L`` - so each stage can be checked on its own, and the 3D
reference that matches a triplet of raw frames.

Conventions are those of :mod:`processing.synthetic.render`: ``d = x_L - x_R = s b / Z > 0``;
flows in px per frame; a point moves by ``V / f`` per frame (``f`` = frame rate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from processing.synthetic.storage import SyntheticFrame


@dataclass
class Eq4Reference:
    """Image-space reference of one frame, float32 (H, W) each, NaN where no gas.

    Attributes
    ----------
    u, v : optical flow w_L of the left camera, px per frame
    d : disparity d_L = s b / Z*, px
    d_prime : disparity change d'_L = s b / (Z* + V*_Z / f) - d, px per frame
    """

    u: np.ndarray
    v: np.ndarray
    d: np.ndarray
    d_prime: np.ndarray


def eq4_reference(
    gt_position: np.ndarray,
    gt_velocity: np.ndarray,
    s_px: float,
    b_m: float,
    frame_interval_s: float,
) -> Eq4Reference:
    """Invert Eq. 4: the (u, v, d, d') that Eq. 4 turns into V* at P* (ideal pinhole).

    Parameters
    ----------
    gt_position, gt_velocity : (H, W, 3) float arrays
        P* in m and V* in m/s (left camera frame), as stored in a frame.
    s_px, b_m : float
        Camera constant s (px) and baseline b (m).
    frame_interval_s : float
        1 / f in s.

    Returns
    -------
    Eq4Reference
        Applying Eq. 4 with f = 1 / frame_interval_s to these fields gives back V* exactly
        (up to float32 rounding), because P* lies on each pixel's ray.
    """
    p = np.asarray(gt_position, dtype=np.float64)
    vel = np.asarray(gt_velocity, dtype=np.float64)
    if p.shape != vel.shape or p.ndim != 3 or p.shape[-1] != 3:
        raise ValueError(f"gt_position {p.shape} and gt_velocity {vel.shape} must be (H, W, 3)")
    if not frame_interval_s > 0:
        raise ValueError(f"frame_interval_s must be > 0, got {frame_interval_s}")
    p1 = p + vel * frame_interval_s
    with np.errstate(invalid="ignore", divide="ignore"):
        u = s_px * (p1[..., 0] / p1[..., 2] - p[..., 0] / p[..., 2])
        v = s_px * (p1[..., 1] / p1[..., 2] - p[..., 1] / p[..., 2])
        d = s_px * b_m / p[..., 2]
        d_prime = s_px * b_m / p1[..., 2] - d
    return Eq4Reference(
        u=u.astype(np.float32), v=v.astype(np.float32),
        d=d.astype(np.float32), d_prime=d_prime.astype(np.float32),
    )


def triplet_reference(
    first: SyntheticFrame, second: SyntheticFrame
) -> tuple[np.ndarray, np.ndarray]:
    """3D reference velocity for the raw triplet (i, i+1, i+2) of Sec. 5.1.

    The two differential images of the triplet come from the motions i -> i+1 and
    i+1 -> i+2, whose ground truths are ``gt_velocity`` of frames i and i+1. Returns their
    mean, float32 (H, W, 3) m/s, and the gas mask of frame i (H, W) bool restricted to pixels
    where both are defined.
    """
    if first.gt_velocity.shape != second.gt_velocity.shape:
        raise ValueError("frames of different sizes")
    if second.index != first.index + 1:
        raise ValueError(f"frames {first.index} and {second.index} are not consecutive")
    v = 0.5 * (first.gt_velocity.astype(np.float64) + second.gt_velocity.astype(np.float64))
    mask = first.gt_mask & np.all(np.isfinite(v), axis=-1)
    return v.astype(np.float32), mask
