"""Synthetic image pairs with an exactly known optical flow, for the flow tests."""

from __future__ import annotations

import cv2
import numpy as np


def texture(shape: tuple[int, int] = (96, 128), seed: int = 0) -> np.ndarray:
    """Seeded multi-scale random texture in [0, 1], float32 (H, W)."""
    rng = np.random.default_rng(seed)
    img = np.zeros(shape, np.float32)
    for sigma, weight in ((1.0, 0.3), (2.5, 0.5), (6.0, 1.0)):
        layer = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), sigma)
        img += weight * (layer - layer.mean()) / layer.std()
    return ((img - img.min()) / (img.max() - img.min())).astype(np.float32)


def pair_with_flow(image1: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Return image0 with image0(x) = image1(x + flow(x)) exactly (bicubic sampling)."""
    h, w = image1.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return cv2.remap(image1, xx + flow[..., 0], yy + flow[..., 1],
                     interpolation=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
