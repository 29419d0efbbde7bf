"""Sub-pixel translation of a frame: the warp of the jitter removal (paper Sec. 4.1).

Convention: a shift d = (dx, dy) means ``moving(x + d) ~ reference(x)``
(:mod:`processing.preprocess.registration`); :func:`warp_translation` with that d resamples
``moving`` onto ``reference``.
"""

from __future__ import annotations

import cv2
import numpy as np


def _cubic_weights(frac: float) -> np.ndarray:
    """Keys cubic-convolution weights (a = -0.5) for taps at -1, 0, 1, 2 and offset ``frac``."""
    t = np.array([1.0 + frac, frac, 1.0 - frac, 2.0 - frac])
    a = -0.5
    near = (a + 2.0) * t**3 - (a + 3.0) * t**2 + 1.0
    far = a * t**3 - 5.0 * a * t**2 + 8.0 * a * t - 4.0 * a
    return np.where(t <= 1.0, near, far)


def warp_translation(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """Resample ``image`` at x + shift (separable bicubic, mirrored borders).

    A pure translation gives every pixel the same interpolation weights, so the warp is
    4 + 4 weighted sums of integer-shifted views. Unlike ``cv2.warpAffine``, which rounds
    sub-pixel positions to 1/32 px, the weights here use the exact fractional shift: the
    0.05 px registration target needs that.

    Parameters
    ----------
    image : ndarray, shape (H, W), float
        The moving frame.
    shift : (float, float)
        (dx, dy) in pixels as returned by :func:`estimate_shift`.

    Returns
    -------
    ndarray, shape (H, W), float32
        ``out(x, y) = image(x + dx, y + dy)``, i.e. the moving frame aligned with the
        reference. Pixels whose source lies outside the frame take mirrored values (a border
        strip of width ``ceil(|shift|) + 1`` px is therefore not real data).
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    dx, dy = float(shift[0]), float(shift[1])
    if not (np.isfinite(dx) and np.isfinite(dy)):
        raise ValueError(f"shift must be finite, got {shift!r}")
    if dx == 0.0 and dy == 0.0:
        return img.copy()
    h, w = img.shape
    ix, iy = int(np.floor(dx)), int(np.floor(dy))
    if abs(ix) + 3 > w or abs(iy) + 3 > h:
        raise ValueError(f"shift {shift!r} is larger than the {w}x{h} image")
    pad = max(abs(ix), abs(iy)) + 3
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
    wx = _cubic_weights(dx - ix).astype(np.float32)
    wy = _cubic_weights(dy - iy).astype(np.float32)
    rows = np.zeros((h + 2 * pad, w), dtype=np.float32)
    for k in range(4):
        x0 = pad + ix + k - 1
        rows += wx[k] * padded[:, x0 : x0 + w]
    out = np.zeros((h, w), dtype=np.float32)
    for k in range(4):
        y0 = pad + iy + k - 1
        out += wy[k] * rows[y0 : y0 + h, :]
    return out


def warp_border_px(*shifts: tuple[float, float]) -> int:
    """Width of the border strip that :func:`warp_translation` fills with mirrored values
    for the largest of ``shifts`` (0 when none moves the frame), px: ceil(|shift|) plus
    the bicubic kernel's reach of 2 px."""
    largest = max((max(abs(float(s[0])), abs(float(s[1]))) for s in shifts), default=0.0)
    return 0 if largest == 0.0 else int(np.ceil(largest)) + 2
