"""Spatial derivatives and warping shared by the variational solvers."""

from __future__ import annotations

import cv2
import numpy as np

# Fourth-order central difference (Brox et al. 2004, Sec. 3): (-1, 8, 0, -8, 1) / 12.
_D5 = np.array([[1.0, -8.0, 0.0, 8.0, -1.0]], dtype=np.float32) / 12.0


def dx(image: np.ndarray) -> np.ndarray:
    """Horizontal derivative d/dx of a float32 image (H, W), reflecting borders."""
    return cv2.filter2D(image, cv2.CV_32F, _D5, borderType=cv2.BORDER_REFLECT)


def dy(image: np.ndarray) -> np.ndarray:
    """Vertical derivative d/dy of a float32 image (H, W), reflecting borders."""
    return cv2.filter2D(image, cv2.CV_32F, _D5.T, borderType=cv2.BORDER_REFLECT)


def warp(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) float32 at (map_x, map_y) with bicubic interpolation.

    Samples outside the image replicate the border; callers mask them out of the data
    terms with :func:`inside_mask` because replicated values carry no information.
    """
    return cv2.remap(image, map_x, map_y, interpolation=cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REPLICATE)


def inside_mask(map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Float32 mask (H, W): 1 where (map_x, map_y) lies inside the image, else 0."""
    h, w = map_x.shape
    inside = (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
    return inside.astype(np.float32)


def pixel_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (xx, yy), each (H, W) float32."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return xx, yy
