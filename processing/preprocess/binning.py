"""Pixel binning of a corrected frame: the mean of each k x k block
(:mod:`processing.chain.binning` runs the chain on such frames)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["bin_image", "check_binning"]


def check_binning(image_size: tuple[int, int], k: int) -> None:
    """Raise ValueError unless ``k`` divides both sides of ``image_size`` (W, H), px."""
    w, h = image_size
    if w % k or h % k:
        raise ValueError(f"binning {k} does not divide the {w}x{h} camera image "
                         f"(each side must be a multiple of {k})")


def bin_image(image: np.ndarray, k: int) -> np.ndarray:
    """Mean of each k x k block of ``image``.

    Parameters
    ----------
    image : ndarray, shape (H, W), float32
        A corrected, rectified frame; H and W multiples of k.
    k : int
        Block side, px.

    Returns
    -------
    ndarray, shape (H / k, W / k), float32
    """
    if k == 1:
        return image
    h, w = image.shape
    check_binning((w, h), k)
    # OpenCV's area resampling at an integer factor is the block mean (tested against
    # numpy's), 70x faster at 640x480 than numpy's mean over two axes (0.03 against 2.1 ms)
    return cv2.resize(np.asarray(image, np.float32), (w // k, h // k),
                      interpolation=cv2.INTER_AREA)
