"""Jitter removal: sub-pixel registration of consecutive OGI frames (paper Sec. 4.1).

The cooling engine of an OGI camera shakes the detector by fractions of a pixel from frame to
frame. A differential image (Eq. 2) of two frames that are shifted against each other shows
every background edge as a bright/dark double line that looks like moving gas, so frame t+1 is
warped onto frame t before differencing.

The shift is a pure translation estimated on the whole frame, i.e. on the static background
that dominates it (the gas is semi-transparent and faint). Two steps:

1. a coarse estimate with OpenCV's phase correlation (``cv2.phaseCorrelate`` with a Hanning
   window), which finds shifts of several pixels but whose sub-pixel part is biased by up to
   ~0.4 px (its centroid peak interpolation; measured on this OpenCV build);
2. a robust Gauss-Newton (Lucas-Kanade) refinement of the translation: the moving frame is
   resampled at x + d with bicubic interpolation and d is updated from the linearised
   residual, with Cauchy weights so that the gas and moving objects (large residuals) count
   less than the background. Both images are pre-smoothed slightly (Gaussian, sigma 1 px),
   which widens the basin of convergence and averages out sensor noise.

Convention: a shift d = (dx, dy) means ``moving(x + d) ~ reference(x)``, i.e. the content of
``moving`` is displaced by +d (to the right for dx > 0, downwards for dy > 0) with respect to
``reference``. :func:`warp_translation` with that d resamples ``moving`` onto ``reference``.
Shifts compose additively: shift(t0 -> t2) = shift(t0 -> t1) + shift(t1 -> t2), which lets a
caller register each new frame against its predecessor only once and reuse the result.
"""

from __future__ import annotations

import cv2
import numpy as np

from processing.validation import as_float_image, check_same_shape

#: Smallest accepted image side in pixels for registration.
MIN_REGISTRATION_SIZE = 16


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


def estimate_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    *,
    max_iter: int = 20,
    tol: float = 1e-3,
    border: int = 8,
    smooth_sigma: float = 1.0,
    robust_scale: float = 2.0,
) -> tuple[float, float]:
    """Sub-pixel translation of ``moving`` with respect to ``reference``.

    Parameters
    ----------
    reference, moving : ndarray, shape (H, W), float
        Two frames of the same camera (raw or radiometrically corrected, any consistent
        intensity unit). H, W >= 16.
    max_iter : int
        Most Gauss-Newton iterations after the phase-correlation start.
    tol : float
        Stop when the update is smaller than this (px).
    border : int
        Pixels along each edge left out of the fit (mirrored samples after warping).
    smooth_sigma : float
        Gaussian pre-smoothing in px (0 disables it).
    robust_scale : float
        Cauchy weight scale in multiples of the robust (MAD) residual spread; residuals far
        above it (gas, moving objects) get weights ~ (scale / residual)^2.

    Returns
    -------
    (float, float)
        (dx, dy) in px with ``moving(x + d) ~ reference(x)``.

    Raises
    ------
    ValueError
        Shapes differ, not 2-D float, NaN/inf, too small, or a flat (textureless) reference
        on which no translation can be measured.
    """
    ref = as_float_image(reference, "reference", min_size=MIN_REGISTRATION_SIZE)
    mov = as_float_image(moving, "moving", min_size=MIN_REGISTRATION_SIZE)
    check_same_shape(ref, mov, "reference", "moving")
    h, w = ref.shape
    if border < 0 or 2 * border >= min(h, w) - 4:
        raise ValueError(f"border must be in [0, {(min(h, w) - 5) // 2}], got {border}")
    if smooth_sigma > 0:
        ref = cv2.GaussianBlur(ref, (0, 0), smooth_sigma, borderType=cv2.BORDER_REFLECT_101)
        mov = cv2.GaussianBlur(mov, (0, 0), smooth_sigma, borderType=cv2.BORDER_REFLECT_101)

    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    # Copies: cv2.phaseCorrelate (OpenCV 5.0) multiplies its inputs by the window in place.
    (dx, dy), _ = cv2.phaseCorrelate(ref.copy(), mov.copy(), window)

    # Inverse-compositional style: the reference gradient is fixed, so the 2x2 normal
    # matrix changes only through the robust weights.
    gx = cv2.Sobel(ref, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    gy = cv2.Sobel(ref, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / 8.0)
    inner = (slice(border, h - border), slice(border, w - border))
    gx, gy, ref_in = gx[inner], gy[inner], ref[inner]
    gxx, gxy, gyy = gx * gx, gx * gy, gy * gy
    if float(gxx.sum()) * float(gyy.sum()) - float(gxy.sum()) ** 2 <= 1e-12 * ref_in.size**2:
        raise ValueError("reference image has no texture: the translation cannot be measured")

    for _ in range(max_iter):
        r = warp_translation(mov, (dx, dy))[inner] - ref_in
        # Mean absolute residual x 1.25 ~ its standard deviation for Gaussian noise; cheaper
        # than a median and only sets the scale of the weights.
        c = robust_scale * 1.25 * float(np.mean(np.abs(r))) + 1e-12
        wgt = 1.0 / (1.0 + (r / c) ** 2)
        a11 = float(np.dot(wgt.ravel(), gxx.ravel()))
        a12 = float(np.dot(wgt.ravel(), gxy.ravel()))
        a22 = float(np.dot(wgt.ravel(), gyy.ravel()))
        wr = wgt * r
        b1 = float(np.dot(wr.ravel(), gx.ravel()))
        b2 = float(np.dot(wr.ravel(), gy.ravel()))
        det = a11 * a22 - a12 * a12
        if det <= 0.0:
            break
        # moving(x + d + delta) ~ moving(x + d) + grad . delta = reference(x)
        step_x = -(a22 * b1 - a12 * b2) / det
        step_y = -(a11 * b2 - a12 * b1) / det
        dx += step_x
        dy += step_y
        if step_x * step_x + step_y * step_y < tol * tol:
            break
    return float(dx), float(dy)


def register_to_reference(
    reference: np.ndarray, moving: np.ndarray, **kwargs: float
) -> tuple[np.ndarray, tuple[float, float]]:
    """Estimate the jitter of ``moving`` and warp it onto ``reference``.

    Parameters
    ----------
    reference, moving : ndarray, shape (H, W), float
        See :func:`estimate_shift`.
    **kwargs
        Passed to :func:`estimate_shift`.

    Returns
    -------
    warped : ndarray, shape (H, W), float32
        ``moving`` resampled onto the reference grid (not smoothed).
    shift : (float, float)
        The estimated (dx, dy) in px.
    """
    shift = estimate_shift(reference, moving, **kwargs)
    return warp_translation(moving, shift), shift
