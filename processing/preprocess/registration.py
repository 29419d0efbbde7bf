"""Jitter removal: sub-pixel registration of consecutive OGI frames (paper Sec. 4.1).

The cooling engine of an OGI camera shakes the detector by fractions of a pixel from frame to
frame. A differential image (Eq. 2) of two frames that are shifted against each other shows
every background edge as a bright/dark double line that looks like moving gas, so frame t+1 is
warped onto frame t before differencing.

The shift is a pure translation estimated on the whole frame, i.e. on the static background
that dominates it (the gas is semi-transparent and faint). Two steps:

1. a coarse estimate with OpenCV's phase correlation (``cv2.phaseCorrelate`` with a Hanning
   window, on half-resolution images), which finds shifts of several pixels but whose
   sub-pixel part is biased by up to ~0.4 px (its centroid peak interpolation; measured on
   this OpenCV build);
2. a robust Gauss-Newton (Lucas-Kanade) refinement of the translation: the moving frame is
   resampled at x + d with bicubic interpolation and d is updated from the linearised
   residual, with Cauchy weights so that the gas and moving objects (large residuals) count
   less than the background. Both images are pre-smoothed slightly (Gaussian, sigma 1 px),
   which widens the basin of convergence and averages out sensor noise. The refinement runs
   coarse to fine: on the half-resolution images until it converges, then on the full ones
   from there (a few steps). Only a converged coarse fit goes on to full resolution: one
   that does not converge is not camera jitter (moving gas in front of a featureless sky or
   wall crawls for every iteration it is given), and at a quarter of the pixels it is
   recognised at a quarter of the cost (measured: 9 -> 2.5 ms per rejected shift at 320x240).

Convention: a shift d = (dx, dy) means ``moving(x + d) ~ reference(x)``, i.e. the content of
``moving`` is displaced by +d (to the right for dx > 0, downwards for dy > 0) with respect to
``reference``. :func:`warp_translation` with that d resamples ``moving`` onto ``reference``.
Shifts compose additively: shift(t0 -> t2) = shift(t0 -> t1) + shift(t1 -> t2), which lets a
caller register each new frame against its predecessor only once and reuse the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
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


def warp_border_px(*shifts: tuple[float, float]) -> int:
    """Width of the border strip that :func:`warp_translation` fills with mirrored values
    for the largest of ``shifts`` (0 when none moves the frame), px: ceil(|shift|) plus
    the bicubic kernel's reach of 2 px."""
    largest = max((max(abs(float(s[0])), abs(float(s[1]))) for s in shifts), default=0.0)
    return 0 if largest == 0.0 else int(np.ceil(largest)) + 2


@numba.njit(cache=True, fastmath=True)
def _gauss_newton_sums(
    resid: np.ndarray, gx: np.ndarray, gy: np.ndarray, border: int, c: float
) -> tuple[float, float, float, float, float]:
    """Robustly weighted normal equations of one Gauss-Newton step.

    ``resid`` is r = moving(x + d) - reference(x). Cauchy weights 1 / (1 + (r / c)^2) with
    the scale ``c`` (:func:`_cauchy_scale`). Returns (a11, a12, a22, b1, b2) of sum w g g^T
    and sum w g r over the inner region (``border`` px left out on each side).
    """
    h, w = resid.shape
    inv_c2 = np.float32(1.0 / (c * c))
    a11 = np.float32(0.0)
    a12 = np.float32(0.0)
    a22 = np.float32(0.0)
    b1 = np.float32(0.0)
    b2 = np.float32(0.0)
    for i in range(border, h - border):
        for j in range(border, w - border):
            r = resid[i, j]
            wgt = np.float32(1.0) / (np.float32(1.0) + r * r * inv_c2)
            ggx = gx[i, j]
            ggy = gy[i, j]
            a11 += wgt * ggx * ggx
            a12 += wgt * ggx * ggy
            a22 += wgt * ggy * ggy
            b1 += wgt * ggx * r
            b2 += wgt * ggy * r
    return float(a11), float(a12), float(a22), float(b1), float(b2)


def _cauchy_scale(resid: np.ndarray, border: int, robust_scale: float) -> float:
    """c = robust_scale x 1.4826 x median|r| over the inner region (every 3rd pixel).

    The median, not the mean: a warm object moving over a fifth of the frame inflates the
    mean residual so much that its pixels keep weight and pull the shift towards their own
    motion (measured: 0.1 px); the median stays at the noise of the static background.
    """
    h, w = resid.shape
    inner = resid[border:h - border:3, border:w - border:3]
    return robust_scale * 1.4826 * float(np.median(np.abs(inner))) + 1e-12


@lru_cache(maxsize=8)
def _hanning(shape: tuple[int, int]) -> np.ndarray:
    """Hanning window of (H, W) for phase correlation (read-only, cached)."""
    win = cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_32F)
    win.setflags(write=False)
    return win


def estimate_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    *,
    max_iter: int = 20,
    tol: float = 5e-3,
    border: int = 8,
    smooth_sigma: float = 1.0,
    robust_scale: float = 2.0,
) -> tuple[float, float]:
    """Sub-pixel translation of ``moving`` with respect to ``reference``.

    :func:`estimate_shift_checked` without the convergence flag; see there.
    """
    shift, _converged = estimate_shift_checked(
        reference, moving, max_iter=max_iter, tol=tol, border=border,
        smooth_sigma=smooth_sigma, robust_scale=robust_scale)
    return shift


def estimate_shift_checked(
    reference: np.ndarray,
    moving: np.ndarray,
    *,
    max_iter: int = 20,
    tol: float = 5e-3,
    border: int = 8,
    smooth_sigma: float = 1.0,
    robust_scale: float = 2.0,
    max_shift: float | None = None,
) -> tuple[tuple[float, float], bool]:
    """Sub-pixel translation of ``moving`` with respect to ``reference``.

    Parameters
    ----------
    reference, moving : ndarray, shape (H, W), float
        Two frames of the same camera (raw or radiometrically corrected, any consistent
        intensity unit). H, W >= 16.
    max_iter : int
        Most Gauss-Newton iterations after the phase-correlation start, per level (half
        and full resolution).
    tol : float
        Stop a level when the update is smaller than this (px of the level).
    border : int
        Pixels along each edge left out of the fit (mirrored samples after warping).
    smooth_sigma : float
        Gaussian pre-smoothing in px (0 disables it).
    robust_scale : float
        Cauchy weight scale in multiples of the robust (MAD) residual spread; residuals far
        above it (gas, moving objects) get weights ~ (scale / residual)^2.
    max_shift : float or None
        Largest plausible shift in px (the camera's jitter). A refinement that has not
        converged but stays within it goes on for another ``max_iter`` steps; when the
        phase-correlation start lies beyond it, or the refinement converged beyond it, a
        second refinement starts from zero and the converged one with the smaller residual
        is returned (see the comments in the code). None: no bound.

    Returns
    -------
    (float, float)
        (dx, dy) in px with ``moving(x + d) ~ reference(x)``.
    bool
        True when the Gauss-Newton refinement converged (step below ``tol``). Camera
        jitter over a static scene converges in a few steps; when it does not, no rigid
        shift explains the change (e.g. moving gas in front of a featureless background)
        and the estimate must not be applied.

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
    # Work in units of the reference's spread: radiance (W m^-2 sr^-1, ~1e-2 per K) and
    # 16-bit counts then meet the same texture test and the same numerics.
    spread = float(ref.std())
    if not spread > 0:
        raise ValueError("reference image has no texture: the translation cannot be measured")
    offset = float(ref.mean())
    ref = (ref - offset) / spread
    mov = (mov - offset) / spread
    if smooth_sigma > 0:
        ref = cv2.GaussianBlur(ref, (0, 0), smooth_sigma, borderType=cv2.BORDER_REFLECT_101)
        mov = cv2.GaussianBlur(mov, (0, 0), smooth_sigma, borderType=cv2.BORDER_REFLECT_101)

    # Coarse start on half-resolution images (4x cheaper; the Gauss-Newton refinement
    # below converges from within about a pixel). Copies are not needed after pyrDown;
    # note that cv2.phaseCorrelate (OpenCV 5.0) multiplies its inputs by the window in place.
    ref_half = cv2.pyrDown(ref)
    mov_half = cv2.pyrDown(mov)
    (hx, hy), _ = cv2.phaseCorrelate(ref_half.copy(), mov_half.copy(),
                                     _hanning(ref_half.shape))

    fine = _level(ref, mov, border)
    if fine is None:
        raise ValueError("reference image has no texture: the translation cannot be measured")
    coarse = (_level(ref_half, mov_half, (border + 1) // 2)
              if min(ref_half.shape) >= MIN_REGISTRATION_SIZE else None)
    # A coarse level too small, or without texture of its own (a fine-grained pattern that
    # pyrDown averages away), is skipped: the fine level then refines alone.
    levels = (fine,) if coarse is None else (coarse, fine)

    def refine(from_: tuple[float, float]) -> tuple[tuple[float, float], bool, float]:
        return _refine(levels, from_, robust_scale=robust_scale, max_iter=max_iter, tol=tol)

    start = (2.0 * hx, 2.0 * hy)
    shift, converged, cost = refine(start)

    def plausible(d: tuple[float, float]) -> bool:
        return max_shift is None or float(np.hypot(*d)) <= max_shift

    if converged and plausible(shift) and plausible(start):
        return shift, converged
    if plausible(start) and not converged:
        if not plausible(shift):
            # Drifted beyond any jitter without converging: no rigid shift explains the
            # change (gas over a featureless background). A second start would fail the
            # same way and double the cost on every such frame (measured: 23 -> 39 ms).
            return shift, converged
        # Crawling towards a plausible shift (a warm object's residuals slow the robust
        # steps down: measured 20 iterations not enough, 100 converge): go on from there.
        shift, converged, _cost = refine(shift)
        return shift, converged
    # Phase correlation found something else than the camera's shake: a warm object
    # moving across the view makes the strongest peak (its own motion, 3-3.5 px measured),
    # and the refinement from there converges to that motion or crawls. Check against a
    # refinement from zero (jitter is small): the converged fit with the smaller residual
    # (median |r|: the static background) wins; a true shift beyond ``max_shift`` still
    # wins over a false local fit and is then rejected by the caller.
    z_shift, z_converged, z_cost = refine((0.0, 0.0))
    if z_converged and (not converged or z_cost < cost):
        return z_shift, True
    return shift, converged


@dataclass(frozen=True)
class _Level:
    """One resolution of the refinement: the (smoothed, normalised) images, the fixed
    reference gradient (inverse-compositional style: the 2x2 normal matrix then changes
    only through the robust weights) and the border left out of the fit, px."""

    ref: np.ndarray
    mov: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    border: int


def _level(ref: np.ndarray, mov: np.ndarray, border: int) -> _Level | None:
    """A refinement level of ``ref`` and ``mov``, or None when ``ref`` has no texture
    (its gradients' normal matrix is singular)."""
    h, w = ref.shape
    gx = cv2.Sobel(ref, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    gy = cv2.Sobel(ref, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / 8.0)
    inner = (slice(border, h - border), slice(border, w - border))
    sxx = float(np.square(gx[inner], dtype=np.float64).sum())
    syy = float(np.square(gy[inner], dtype=np.float64).sum())
    sxy = float((gx[inner].astype(np.float64) * gy[inner]).sum())
    n_inner = (h - 2 * border) * (w - 2 * border)
    if sxx * syy - sxy * sxy <= 1e-12 * n_inner**2:
        return None
    return _Level(ref, mov, gx, gy, border)


def _refine(levels: tuple[_Level, ...], start: tuple[float, float], *, robust_scale: float,
            max_iter: int, tol: float) -> tuple[tuple[float, float], bool, float]:
    """Coarse-to-fine robust Gauss-Newton refinement of the shift from ``start``.

    ``levels`` run coarsest first, each half the size of the next; ``start`` and the result
    are in full-resolution px, ``tol`` in each level's own px. A level that does not
    converge ends the refinement (module docstring). Returns (shift, converged, cost), cost
    the Cauchy scale of the last level's residual.
    """
    shift, converged, cost = start, False, np.inf
    for k, level in enumerate(levels):
        f = 2.0 ** (len(levels) - 1 - k)  # full-resolution px per px of this level
        s, converged, cost = _gauss_newton(level, (shift[0] / f, shift[1] / f),
                                           robust_scale=robust_scale, max_iter=max_iter,
                                           tol=tol)
        shift = (s[0] * f, s[1] * f)
        if not converged:
            break
    return shift, converged, cost


def _gauss_newton(level: _Level, start: tuple[float, float], *, robust_scale: float,
                  max_iter: int, tol: float) -> tuple[tuple[float, float], bool, float]:
    """Robust Gauss-Newton refinement of the shift from ``start`` on one level (its px).

    Returns (shift, converged, cost), cost the Cauchy scale of the last residual (the
    median |r|, i.e. how well the static background fits; inf when it diverged).
    """
    ref, mov, gx, gy, border = level.ref, level.mov, level.gx, level.gy, level.border
    h, w = ref.shape
    dx, dy = start
    c = np.inf
    for _ in range(max_iter):
        if max(abs(dx), abs(dy)) + 3 > min(h, w) // 2:
            return (float(dx), float(dy)), False, np.inf  # diverged far beyond any jitter
        resid = warp_translation(mov, (dx, dy))
        resid -= ref
        c = _cauchy_scale(resid, border, robust_scale)
        a11, a12, a22, b1, b2 = _gauss_newton_sums(resid, gx, gy, border, c)
        det = a11 * a22 - a12 * a12
        if det <= 0.0:
            return (float(dx), float(dy)), False, np.inf
        # moving(x + d + delta) ~ moving(x + d) + grad . delta = reference(x)
        step_x = -(a22 * b1 - a12 * b2) / det
        step_y = -(a11 * b2 - a12 * b1) / det
        dx += step_x
        dy += step_y
        if step_x * step_x + step_y * step_y < tol * tol:
            return (float(dx), float(dy)), True, c
    # No convergence: a rigid shift does not explain the change (moving gas over a
    # featureless background, not camera jitter over a static scene).
    return (float(dx), float(dy)), False, c


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
