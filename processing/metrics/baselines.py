"""Decoupled scene-flow baselines of the paper's Sec. 5.1 (its ref. [20], Schuster et al.).

Disparity is computed by semi-global matching (OpenCV StereoSGBM, Hirschmueller) at t0 and
at t1 independently; the optical flow separately (our Brox flow, or OpenCV Farneback); and
the disparity change is read along the flow:

    d'(x) = d_t1(x + w(x)) - d_t0(x)

with bilinear sampling of d_t1. The result has the same meaning as the joint estimate of
:func:`processing.stereo.joint.joint_disparity` (same sign convention: ``x_R = x_L - d``, which
is also StereoSGBM's), so both go through Eq. 4 alike. SGBM leaves holes (occlusions,
failed uniqueness or left-right checks, untextured areas): they are returned as invalid,
never as numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from processing.flow.brox import brox_optical_flow
from processing.flow.opencv import farneback_flow
from processing.solvers import derivatives
from processing.stereo.sgm import sgbm_disparity
from processing.validation import as_float_image, check_same_shape


@dataclass(frozen=True)
class BaselineSceneFlow:
    """Result of a decoupled baseline, left view, all arrays (H, W[, 2]).

    Attributes
    ----------
    flow : ndarray, shape (H, W, 2), float32
        Left optical flow (u, v) in px from t0 to t1.
    d : ndarray, shape (H, W), float32
        Disparity at t0 in px (``x_R = x_L - d``); 0 where invalid.
    d_change : ndarray, shape (H, W), float32
        Disparity change d' in px along the flow; 0 where invalid.
    valid : ndarray, shape (H, W), bool
        True where d and d' are both defined (SGBM valid at x at t0 and at all four
        bilinear neighbours of x + w at t1, x + w inside the image).
    """

    flow: np.ndarray
    d: np.ndarray
    d_change: np.ndarray
    valid: np.ndarray


def change_along_flow(
    d_t0: np.ndarray,
    valid_t0: np.ndarray,
    d_t1: np.ndarray,
    valid_t1: np.ndarray,
    flow: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Disparity change d'(x) = d_t1(x + w(x)) - d_t0(x) by bilinear sampling.

    Parameters
    ----------
    d_t0, d_t1 : ndarray, shape (H, W), float32
        Disparities at t0 and t1 in px.
    valid_t0, valid_t1 : ndarray, shape (H, W), bool
        Their validity masks.
    flow : ndarray, shape (H, W, 2), float32
        Left optical flow (u, v) from t0 to t1 in px.

    Returns
    -------
    d_change : ndarray, shape (H, W), float32
        d' in px; 0 where invalid.
    valid : ndarray, shape (H, W), bool
        True where d_t0 is valid at x, x + w lies inside the image and all four bilinear
        neighbours of x + w are valid at t1 (so no hole leaks into the interpolation).
    """
    xx, yy = derivatives.pixel_grid(d_t0.shape)
    mx = xx + flow[..., 0]
    my = yy + flow[..., 1]
    d1 = np.where(valid_t1, d_t1, 0.0).astype(np.float32)
    sampled = cv2.remap(d1, mx, my, interpolation=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    # A bilinear sample of the 0/1 mask is exactly 1 only if every neighbour with a
    # non-zero weight is valid.
    vs = cv2.remap(valid_t1.astype(np.float32), mx, my, interpolation=cv2.INTER_LINEAR,
                   borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    valid = valid_t0 & (vs > 0.999) & (derivatives.inside_mask(mx, my) > 0)
    change = np.where(valid, sampled - d_t0, 0.0).astype(np.float32)
    return change, valid


def _decoupled(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    flow: np.ndarray,
    min_disparity: int,
    num_disparities: int,
) -> BaselineSceneFlow:
    d0, v0 = sgbm_disparity(il0, ir0, min_disparity=min_disparity,
                            num_disparities=num_disparities)
    d1, v1 = sgbm_disparity(il1, ir1, min_disparity=min_disparity,
                            num_disparities=num_disparities)
    change, valid = change_along_flow(d0, v0, d1, v1, flow)
    return BaselineSceneFlow(flow=flow, d=np.where(valid, d0, 0.0).astype(np.float32),
                             d_change=change, valid=valid)


def _check_four(il0: np.ndarray, ir0: np.ndarray, il1: np.ndarray,
                ir1: np.ndarray) -> list[np.ndarray]:
    imgs = [as_float_image(a, n, min_size=8)
            for a, n in ((il0, "il0"), (ir0, "ir0"), (il1, "il1"), (ir1, "ir1"))]
    for img, name in zip(imgs[1:], ("ir0", "il1", "ir1"), strict=True):
        check_same_shape(imgs[0], img, "il0", name)
    return imgs


def sgm_brox(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    *,
    min_disparity: int = 0,
    num_disparities: int = 64,
    alpha: float = 0.05,
    beta: float = 0.1,
) -> BaselineSceneFlow:
    """Baseline "SGM + Brox" of Table 3: SGBM at t0 and t1, our Brox flow (Eq. 5).

    Parameters
    ----------
    il0, ir0, il1, ir1 : ndarray, shape (H, W), floating point
        Rectified differential images I_L(t0), I_R(t0), I_L(t1), I_R(t1) in [0, 1].
    min_disparity, num_disparities : int
        SGBM search range in px (see :func:`sgbm_disparity`).
    alpha, beta : float
        Brox flow weights (paper: 0.05, 0.1).
    """
    il0, ir0, il1, ir1 = _check_four(il0, ir0, il1, ir1)
    flow = brox_optical_flow(il0, il1, alpha=alpha, beta=beta)
    return _decoupled(il0, ir0, il1, ir1, flow, min_disparity, num_disparities)


def sgm_farneback(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    *,
    min_disparity: int = 0,
    num_disparities: int = 64,
) -> BaselineSceneFlow:
    """Baseline "SGM + Fbck" of Table 3: SGBM at t0 and t1, OpenCV Farneback flow.

    Parameters as :func:`sgm_brox` (without the Brox weights).
    """
    il0, ir0, il1, ir1 = _check_four(il0, ir0, il1, ir1)
    flow = farneback_flow(il0, il1)
    return _decoupled(il0, ir0, il1, ir1, flow, min_disparity, num_disparities)
