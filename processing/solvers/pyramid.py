"""Image pyramids and flow resampling for coarse-to-fine warping (paper Sec. 4.2, 4.3).

Each level is produced from the previous one by a Gaussian low-pass (against aliasing)
followed by bilinear resampling, with a non-integer factor ``eta`` in (0, 1): Brox et al.
use factors close to 1 so that the linearisation of the warped data term stays valid
between levels.
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np


def pyramid_shapes(
    shape: tuple[int, int], factor: float, min_size: int, max_levels: int = 100
) -> list[tuple[int, int]]:
    """Shapes (H, W) of the pyramid levels, finest first.

    Parameters
    ----------
    shape : (int, int)
        Finest shape (H, W).
    factor : float
        Down-sampling factor per level, 0 < factor < 1.
    min_size : int
        Coarsest level keeps min(H, W) >= min_size (the finest level is always kept).
    max_levels : int
        Upper bound on the number of levels.
    """
    h, w = shape
    shapes = [(h, w)]
    k = 1
    while k < max_levels:
        hk = round(h * factor**k)
        wk = round(w * factor**k)
        if min(hk, wk) < min_size:
            break
        shapes.append((hk, wk))
        k += 1
    return shapes


def downsample(image: np.ndarray, shape: tuple[int, int], factor: float) -> np.ndarray:
    """Low-pass and resample ``image`` (H, W) float32 to ``shape`` (h, w).

    The Gaussian's sigma, 0.6 * sqrt(1/factor^2 - 1), is the anti-aliasing choice of the
    IPOL reference implementations of Brox's method.
    """
    sigma = 0.6 * math.sqrt(1.0 / factor**2 - 1.0)
    blurred = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=sigma,
                               borderType=cv2.BORDER_REFLECT)
    return cv2.resize(blurred, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def image_pyramid(image: np.ndarray, shapes: list[tuple[int, int]]) -> list[np.ndarray]:
    """Pyramid of ``image`` (H, W) float32 at the given level shapes, finest first.

    Each level is filtered from the previous one with the blur of the actual (rounded)
    size ratio between the two.
    """
    levels = [image]
    for shape in shapes[1:]:
        ratio = min(shape[0] / levels[-1].shape[0], shape[1] / levels[-1].shape[1])
        levels.append(downsample(levels[-1], shape, min(ratio, 0.999)))
    return levels


def resize_field(field: np.ndarray, shape: tuple[int, int], *, is_motion: bool) -> np.ndarray:
    """Resample a field (H, W) or (H, W, C) to ``shape``.

    Parameters
    ----------
    field : ndarray, shape (H, W) or (H, W, 2), float32
        For ``is_motion`` a displacement in px: component 0 is horizontal, component 1
        vertical (a 2-D field is taken as horizontal, e.g. a disparity).
    shape : (int, int)
        Target (h, w).
    is_motion : bool
        Scale the values by the size ratio so that displacements stay in target pixels.
    """
    h, w = field.shape[:2]
    out = np.ascontiguousarray(
        cv2.resize(field, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR),
        dtype=np.float32)
    if is_motion:
        sx = np.float32(shape[1] / w)
        sy = np.float32(shape[0] / h)
        # One channel at a time, in place: numpy's broadcast over a last axis of 2 was
        # 10x slower (0.9 ms at 320x240, measured) for the same float32 products.
        if out.ndim == 3:
            out[..., 0] *= sx
            out[..., 1] *= sy
        else:
            out *= sx
    return out


def usable_map(blanked: np.ndarray, shape: tuple[int, int], margin_px: int = 2) -> np.ndarray:
    """Float32 map of one pyramid level of shape (rows, cols): 1 where the image carries
    information, 0 on ``blanked`` (H, W) bool pixels and within ``margin_px`` (level px)
    of them; a coarse pixel is unusable when any fine pixel under it is blanked. The
    margin covers the pre-smoothing and the derivative stencils."""
    k = 2 * margin_px + 1
    frac = cv2.resize(blanked.astype(np.float32), (shape[1], shape[0]),
                      interpolation=cv2.INTER_AREA)
    bad = cv2.dilate((frac > 1e-3).astype(np.uint8), np.ones((k, k), np.uint8))
    return np.ascontiguousarray(1.0 - bad, dtype=np.float32)


@numba.njit(inline="always")
def usable_at(ok: np.ndarray, x: float, y: float) -> float:
    """A :func:`usable_map` ``ok`` (H, W) at the nearest pixel to (x, y), clamped to the
    image (a sample outside it is masked by the solvers' inside tests anyway)."""
    h, w = ok.shape
    xi = min(max(int(np.rint(x)), 0), w - 1)
    yi = min(max(int(np.rint(y)), 0), h - 1)
    return ok[yi, xi]
