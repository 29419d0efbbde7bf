"""Disparity accuracy on a rectified pair with ground truth (``ogiflow eval stereo``).

Runs our variational disparity (the joint solver of Eq. 6 on a static pair: the same
images at t0 and t1 and zero flow, so d' = 0) and OpenCV StereoSGBM in the same run and
reports the mean absolute error and the bad-pixel rate (error > 1 px) over the pixels
with known ground truth (gt > 0).
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from processing.stereo.joint import joint_disparity
from processing.stereo.sgm import sgbm_disparity, sgbm_initial_disparity

METHOD_VARIATIONAL = "variational"
METHOD_SGBM = "sgbm"


def _imread(path: Path, what: str, flags: int) -> np.ndarray:
    if not path.is_file():
        raise ValueError(f"{what} image not found: {path}")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise ValueError(f"cannot read {what} image {path} (unknown or corrupt format)")
    return img


def read_grey(path: Path, what: str) -> np.ndarray:
    """An 8-bit grey image as float32 in [0, 1] (colour is converted to grey)."""
    img = _imread(path, what, cv2.IMREAD_GRAYSCALE)
    if img.dtype != np.uint8:
        raise ValueError(f"{what} image {path} must be 8-bit, got {img.dtype}")
    return img.astype(np.float32) / 255.0


def read_gt(path: Path, scale: float) -> np.ndarray:
    """A ground-truth disparity image in px: pixel value / ``scale``; 0 = unknown."""
    raw = _imread(path, "ground-truth", cv2.IMREAD_UNCHANGED)
    if raw.ndim != 2:
        raise ValueError(f"ground-truth image {path} must be single-channel, got {raw.shape}")
    return raw.astype(np.float32) / np.float32(scale)


def evaluate_stereo(
    left: np.ndarray, right: np.ndarray, gt: np.ndarray, *, d0: float = 0.0,
    sgm_init: bool = False, max_disparity: int = 64,
) -> dict[str, dict[str, float]]:
    """Scores of both methods on one rectified pair.

    Parameters
    ----------
    left, right
        (H, W) float32 grey images in [0, 1].
    gt
        (H, W) ground-truth disparity of the left view in px (x_right = x_left - d);
        0 = unknown.
    d0
        Initial (minimum) disparity of the variational solver, px.
    sgm_init
        Initialise the variational solver from the SGBM estimate instead of ``d0``.
    max_disparity
        SGBM search range in px, a positive multiple of 16.

    Returns
    -------
    dict
        {"variational": {"mae", "bad1", "ms"}, "sgbm": {"mae", "bad1", "valid", "ms"}}
        with mae in px, bad1 and valid as fractions of the known ground-truth pixels.
    """

    known = gt > 0
    if not known.any():
        raise ValueError("the ground truth has no known pixel (all values are 0)")
    t = time.perf_counter()
    d_sgbm, valid = sgbm_disparity(left, right, num_disparities=max_disparity)
    ms_sgbm = (time.perf_counter() - t) * 1e3
    init = None
    if sgm_init:
        init = sgbm_initial_disparity(left, right, num_disparities=max_disparity, fallback=d0)
    zero = np.zeros((*left.shape, 2), np.float32)
    # Warm-up on a tiny pair: the first call loads the compiled numba code from its cache,
    # which must not count as run time.
    tiny = np.zeros((16, 16), np.float32)
    joint_disparity(tiny, tiny, tiny, tiny, np.zeros((16, 16, 2), np.float32))
    t = time.perf_counter()
    d_var, _ = joint_disparity(left, right, left, right, zero, d0=d0, initial_disparity=init)
    ms_var = (time.perf_counter() - t) * 1e3

    err_var = np.abs(d_var - gt)[known]
    err_sgbm = np.abs(d_sgbm - gt)[known]
    valid_k = valid[known]
    bad_sgbm = (~valid_k) | (err_sgbm > 1.0)
    return {
        METHOD_VARIATIONAL: {"mae": float(err_var.mean()), "bad1": float(np.mean(err_var > 1.0)),
                             "ms": ms_var},
        METHOD_SGBM: {
            "mae": float(err_sgbm[valid_k].mean()) if valid_k.any() else float("nan"),
            "bad1": float(bad_sgbm.mean()),
            "valid": float(valid_k.mean()),
            "ms": ms_sgbm,
        },
    }
