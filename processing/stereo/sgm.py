"""Semi-global matching (OpenCV StereoSGBM, Hirschmueller 2008) on differential images.

The chain's initial disparity of a cold start (paper Sec. 4.3: the joint solver of Eq. 6
needs a start near the gas's disparity) and the depth gate's disparity band use it; the
decoupled baselines of the paper's Sec. 5.1 (:mod:`processing.metrics.baselines`) build on
it too. SGBM leaves holes (occlusions, failed uniqueness or left-right checks, untextured
areas): :func:`sgbm_disparity` returns them as invalid, never as numbers.
"""

from __future__ import annotations

import cv2
import numpy as np

from processing.flow.opencv import to_uint8
from processing.validation import as_float_image, check_same_shape

#: StereoSGBM parameters used by the baselines (documented, not tuned per scene).
#: block 5 px; P1 = 8 * block^2 and P2 = 32 * block^2 are OpenCV's recommended smoothness
#: penalties for one channel; uniqueness 10 %, left-right check 1 px, speckle filter
#: removing blobs < 100 px that vary by more than 2 px; full 8-path SGBM (MODE_HH) would
#: be slower for little gain on 320x240, so the 5-path default mode is used.
SGBM_BLOCK_SIZE = 5
SGBM_UNIQUENESS = 10
SGBM_DISP12_MAX_DIFF = 1
SGBM_SPECKLE_WINDOW = 100
SGBM_SPECKLE_RANGE = 2


def sgbm_disparity(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int = 0,
    num_disparities: int = 64,
    block_size: int = SGBM_BLOCK_SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """Semi-global matching disparity of a rectified pair (OpenCV StereoSGBM).

    Parameters
    ----------
    left, right : ndarray, shape (H, W), floating point
        Rectified images in [0, 1]; they are quantised to uint8 for SGBM.
    min_disparity : int
        Smallest disparity searched, px.
    num_disparities : int
        Width of the search range, px, a positive multiple of 16.
    block_size : int
        Matching block side, odd, px.

    Returns
    -------
    d : ndarray, shape (H, W), float32
        Disparity in px, ``x_R = x_L - d`` (1/16 px resolution); 0 where invalid.
    valid : ndarray, shape (H, W), bool
        False where SGBM reports no disparity (its value minDisparity - 1).

    Raises
    ------
    ValueError
        Bad images, or a search range that is not a positive multiple of 16.
    """
    lf = as_float_image(left, "left", min_size=block_size)
    rf = as_float_image(right, "right", min_size=block_size)
    check_same_shape(lf, rf, "left", "right")
    if int(num_disparities) != num_disparities or num_disparities <= 0 \
            or num_disparities % 16:
        raise ValueError(f"num_disparities must be a positive multiple of 16, "
                         f"got {num_disparities!r}")
    if int(block_size) != block_size or block_size < 1 or block_size % 2 == 0:
        raise ValueError(f"block_size must be a positive odd integer, got {block_size!r}")
    matcher = cv2.StereoSGBM_create(
        minDisparity=int(min_disparity),
        numDisparities=int(num_disparities),
        blockSize=int(block_size),
        P1=8 * block_size * block_size,
        P2=32 * block_size * block_size,
        disp12MaxDiff=SGBM_DISP12_MAX_DIFF,
        uniquenessRatio=SGBM_UNIQUENESS,
        speckleWindowSize=SGBM_SPECKLE_WINDOW,
        speckleRange=SGBM_SPECKLE_RANGE,
    )
    raw = matcher.compute(to_uint8(lf), to_uint8(rf))  # int16, disparity * 16
    valid = raw >= int(min_disparity) * 16
    d = np.where(valid, raw.astype(np.float32) / 16.0, 0.0).astype(np.float32)
    return d, valid


def sgbm_initial_disparity(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int = 0,
    num_disparities: int = 64,
    fallback: float | None = None,
) -> np.ndarray:
    """An SGBM disparity with its holes filled, to initialise the joint solver (Eq. 6).

    :func:`processing.stereo.joint.joint_disparity` accepts an initial disparity field
    instead of a constant minimum disparity d0; it resamples the field to its coarsest
    pyramid level, so only the large-scale layout matters. Holes take the median of the
    valid disparities (or ``fallback`` when SGBM found none; ``min_disparity`` if that is
    None).

    Returns
    -------
    ndarray, shape (H, W), float32
        Disparity in px (``x_R = x_L - d``), finite everywhere.
    """
    d, valid = sgbm_disparity(left, right, min_disparity=min_disparity,
                              num_disparities=num_disparities)
    if valid.any():
        fill = float(np.median(d[valid]))
    else:
        fill = float(min_disparity if fallback is None else fallback)
    return np.where(valid, d, fill).astype(np.float32)
