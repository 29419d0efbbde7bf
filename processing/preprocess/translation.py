"""Sub-pixel translation of a frame: the warp of the jitter removal (paper Sec. 4.1).

Convention: a shift d = (dx, dy) means ``moving(x + d) ~ reference(x)``
(:mod:`processing.preprocess.registration`); :func:`warp_translation` with that d resamples
``moving`` onto ``reference``.
"""

from __future__ import annotations

import numba
import numpy as np

from processing.solvers.derivatives import catmull_rom_weights


@numba.njit(cache=True, error_model="numpy", inline="always")
def _reflect(i: int, n: int) -> int:
    """Index ``i`` mirrored into [0, n) without repeating the edge (OpenCV's
    BORDER_REFLECT_101); |i| < 2n - 1."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def translate_into(image: np.ndarray, dx: float, dy: float, out: np.ndarray,
                   rows: np.ndarray, buf: np.ndarray) -> None:
    """``out(x, y) = image(x + dx, y + dy)``: separable bicubic, mirrored borders.

    Parameters
    ----------
    image : ndarray, shape (H, W), float32
        The frame; |dx| + 3 <= W and |dy| + 3 <= H.
    dx, dy : float
        The shift, px.
    out, rows : ndarray, shape (H, W), float32
        Output, and scratch for the horizontally interpolated rows.
    buf : ndarray, shape (>= W + 2 |floor(dx)| + 6,), float32
        Scratch for one mirrored row.
    """
    h, w = image.shape
    ix = int(np.floor(dx))
    iy = int(np.floor(dy))
    wx0, wx1, wx2, wx3 = catmull_rom_weights(dx - ix)
    wy0, wy1, wy2, wy3 = catmull_rom_weights(dy - iy)
    fx0, fx1, fx2, fx3 = (np.float32(wx0), np.float32(wx1), np.float32(wx2),
                          np.float32(wx3))
    fy0, fy1, fy2, fy3 = (np.float32(wy0), np.float32(wy1), np.float32(wy2),
                          np.float32(wy3))
    pad = abs(ix) + 2
    # The horizontal pass on each source row; a mirrored row's interpolation is the
    # mirror of the rows' interpolations, so the vertical pass mirrors row indices.
    for r in range(h):
        src = image[r]
        buf[pad:pad + w] = src
        for j in range(pad):
            buf[j] = src[_reflect(j - pad, w)]
            buf[pad + w + j] = src[_reflect(w + j, w)]
        o = rows[r]
        b = pad + ix - 1
        # Views, not buf[b + x + k]: a signed index costs a wrap-around test per load and
        # keeps LLVM from vectorising (measured: 2x slower).
        t0, t1 = buf[b:b + w], buf[b + 1:b + 1 + w]
        t2, t3 = buf[b + 2:b + 2 + w], buf[b + 3:b + 3 + w]
        for x in range(w):
            o[x] = (((fx0 * t0[x]) + fx1 * t1[x]) + fx2 * t2[x]) + fx3 * t3[x]
    for y in range(h):
        r0 = rows[_reflect(y + iy - 1, h)]
        r1 = rows[_reflect(y + iy, h)]
        r2 = rows[_reflect(y + iy + 1, h)]
        r3 = rows[_reflect(y + iy + 2, h)]
        o = out[y]
        for x in range(w):
            o[x] = (((fy0 * r0[x]) + fy1 * r1[x]) + fy2 * r2[x]) + fy3 * r3[x]


def warp_translation(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """Resample ``image`` at x + shift (separable bicubic, mirrored borders).

    A pure translation gives every pixel the same interpolation weights (Keys' cubic,
    a = -0.5: :func:`processing.solvers.derivatives.catmull_rom_weights`), so the warp is
    4 + 4 weighted sums of integer-shifted rows (:func:`translate_into`). Unlike
    ``cv2.warpAffine``, which rounds sub-pixel positions to 1/32 px, the weights here use
    the exact fractional shift: the 0.05 px registration target needs that.

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
    if abs(int(np.floor(dx))) + 3 > w or abs(int(np.floor(dy))) + 3 > h:
        raise ValueError(f"shift {shift!r} is larger than the {w}x{h} image")
    out = np.empty_like(img)
    translate_into(img, dx, dy, out, np.empty_like(img), scratch_row(w, dx))
    return out


def scratch_row(width: int, dx: float) -> np.ndarray:
    """The row buffer :func:`translate_into` needs for a shift of ``dx`` px."""
    return np.empty(width + 2 * abs(int(np.floor(dx))) + 6, np.float32)


def warp_border_px(*shifts: tuple[float, float]) -> int:
    """Width of the border strip that :func:`warp_translation` fills with mirrored values
    for the largest of ``shifts`` (0 when none moves the frame), px: ceil(|shift|) plus
    the bicubic kernel's reach of 2 px."""
    largest = max((max(abs(float(s[0])), abs(float(s[1]))) for s in shifts), default=0.0)
    return 0 if largest == 0.0 else int(np.ceil(largest)) + 2
