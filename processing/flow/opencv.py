"""OpenCV optical flow methods used as references (paper Table 1 and Sec. 5.1 baselines)."""

from __future__ import annotations

import cv2
import numpy as np

from processing.validation import as_float_image, check_same_shape

#: Farneback parameters (OpenCV sample values; the paper does not state its own).
FARNEBACK_PARAMS = {
    "pyr_scale": 0.5,
    "levels": 5,
    "winsize": 15,
    "iterations": 3,
    "poly_n": 5,
    "poly_sigma": 1.2,
    "flags": 0,
}


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Map a [0, 1] float image to uint8 (values outside are clipped)."""
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def farneback_flow(image0: np.ndarray, image1: np.ndarray) -> np.ndarray:
    """Farneback (2003) flow between two [0, 1] float images.

    Returns
    -------
    ndarray, shape (H, W, 2), float32
        (u, v) in px with image1(x + u, y + v) ~ image0(x, y).
    """
    i0 = as_float_image(image0, "image0")
    i1 = as_float_image(image1, "image1")
    check_same_shape(i0, i1, "image0", "image1")
    p = FARNEBACK_PARAMS
    return cv2.calcOpticalFlowFarneback(
        to_uint8(i0), to_uint8(i1), None, p["pyr_scale"], p["levels"], p["winsize"],
        p["iterations"], p["poly_n"], p["poly_sigma"], p["flags"],
    )


def dis_flow(image0: np.ndarray, image1: np.ndarray, *, preset: str = "medium") -> np.ndarray:
    """DIS flow (Kroeger et al. 2016) with an OpenCV preset ("ultrafast", "fast", "medium").

    Returns
    -------
    ndarray, shape (H, W, 2), float32
    """
    presets = {
        "ultrafast": cv2.DISOpticalFlow_PRESET_ULTRAFAST,
        "fast": cv2.DISOpticalFlow_PRESET_FAST,
        "medium": cv2.DISOpticalFlow_PRESET_MEDIUM,
    }
    if preset not in presets:
        raise ValueError(f"unknown DIS preset {preset!r}; choose one of {sorted(presets)}")
    i0 = as_float_image(image0, "image0")
    i1 = as_float_image(image1, "image1")
    check_same_shape(i0, i1, "image0", "image1")
    dis = cv2.DISOpticalFlow_create(presets[preset])
    return dis.calc(to_uint8(i0), to_uint8(i1), None)
