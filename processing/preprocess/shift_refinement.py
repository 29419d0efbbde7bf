"""Robust Gauss-Newton refinement of a translation, coarse to fine (paper Sec. 4.1).

Step 2 of the jitter removal (:mod:`processing.preprocess.registration`): the moving frame
is resampled at x + d and d is updated from the linearised residual with Cauchy weights,
first on the half-resolution images, then on the full ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from processing.preprocess.translation import translate_into


@numba.njit(cache=True, fastmath=True, error_model="numpy")
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
    one = np.float32(1.0)
    a11 = a12 = a22 = b1 = b2 = np.float32(0.0)
    for i in range(border, h - border):
        # Row views and per-row partial sums: a loop LLVM vectorises.
        r = resid[i, border:w - border]
        x = gx[i, border:w - border]
        y = gy[i, border:w - border]
        s11 = s12 = s22 = t1 = t2 = np.float32(0.0)
        for j in range(r.shape[0]):
            rr = r[j]
            wgt = one / (one + rr * rr * inv_c2)
            wx = wgt * x[j]
            wy = wgt * y[j]
            s11 += wx * x[j]
            s12 += wx * y[j]
            s22 += wy * y[j]
            t1 += wx * rr
            t2 += wy * rr
        a11 += s11
        a12 += s12
        a22 += s22
        b1 += t1
        b2 += t2
    return float(a11), float(a12), float(a22), float(b1), float(b2)


@numba.njit(cache=True, error_model="numpy")
def _cauchy_scale(resid: np.ndarray, border: int, robust_scale: float,
                  sample: np.ndarray) -> float:
    """c = robust_scale x 1.4826 x median|r| over the inner region (every 3rd pixel);
    ``sample`` is scratch of at least that many values.

    The median, not the mean: a warm object moving over a fifth of the frame inflates the
    mean residual so much that its pixels keep weight and pull the shift towards their own
    motion (measured: 0.1 px); the median stays at the noise of the static background.
    """
    h, w = resid.shape
    n = 0
    for i in range(border, h - border, 3):
        for j in range(border, w - border, 3):
            sample[n] = abs(resid[i, j])
            n += 1
    return robust_scale * 1.4826 * float(np.median(sample[:n])) + 1e-12


@numba.njit(cache=True, error_model="numpy")
def _scratch(h: int, w: int, border: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Buffers of :func:`_residual_scale` on an (h, w) level: the residual, the horizontally
    interpolated rows and the row buffer of ``translate_into``, and the median's sample."""
    return (np.empty((h, w), np.float32), np.empty((h, w), np.float32),
            np.empty(w + 2 * (min(h, w) // 2) + 8, np.float32),
            np.empty(((h - 2 * border) // 3 + 1) * ((w - 2 * border) // 3 + 1), np.float32))


@numba.njit(cache=True, error_model="numpy")
def _residual_scale(ref: np.ndarray, mov: np.ndarray, dx: float, dy: float, border: int,
                    robust_scale: float, resid: np.ndarray, rows: np.ndarray,
                    buf: np.ndarray, sample: np.ndarray) -> float:
    """``resid`` = mov(x + d) - ref(x) and its Cauchy scale (:func:`_cauchy_scale`): the
    refinement's cost at d; the other arrays are :func:`_scratch`'s."""
    translate_into(mov, dx, dy, resid, rows, buf)
    h, w = ref.shape
    for i in range(h):
        ri = resid[i]
        fi = ref[i]
        for j in range(w):
            ri[j] -= fi[j]
    return _cauchy_scale(resid, border, robust_scale, sample)


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _gauss_newton_loop(ref: np.ndarray, mov: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                       border: int, dx: float, dy: float, robust_scale: float, max_iter: int,
                       tol: float, give_up: float) -> tuple[float, float, bool, float]:
    """The iterations of :func:`_gauss_newton` in compiled code: (dx, dy, converged, cost);
    not converged as soon as the shift leaves the disc of radius ``give_up`` px."""
    h, w = ref.shape
    resid, rows, buf, sample = _scratch(h, w, border)
    c = np.inf
    for _ in range(max_iter):
        if max(abs(dx), abs(dy)) + 3 > min(h, w) // 2:
            return dx, dy, False, np.inf  # diverged far beyond any jitter
        c = _residual_scale(ref, mov, dx, dy, border, robust_scale, resid, rows, buf, sample)
        a11, a12, a22, b1, b2 = _gauss_newton_sums(resid, gx, gy, border, c)
        det = a11 * a22 - a12 * a12
        if det <= 0.0:
            return dx, dy, False, np.inf
        # moving(x + d + delta) ~ moving(x + d) + grad . delta = reference(x)
        step_x = -(a22 * b1 - a12 * b2) / det
        step_y = -(a11 * b2 - a12 * b1) / det
        dx += step_x
        dy += step_y
        if step_x * step_x + step_y * step_y < tol * tol:
            return dx, dy, True, c
        if dx * dx + dy * dy > give_up * give_up:
            return dx, dy, False, c
    # No convergence: a rigid shift does not explain the change (moving gas over a
    # featureless background, not camera jitter over a static scene).
    return dx, dy, False, c


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _gradient_moments(gx: np.ndarray, gy: np.ndarray, border: int
                      ) -> tuple[float, float, float]:
    """sum gx^2, sum gy^2, sum gx gy over the inner region (``border`` px left out), with
    float64 sums of float32 rows (the texture test compares their determinant with a
    tiny threshold)."""
    h, w = gx.shape
    sxx = syy = sxy = 0.0
    for i in range(border, h - border):
        x = gx[i, border:w - border]
        y = gy[i, border:w - border]
        for j in range(x.shape[0]):
            a = np.float64(x[j])
            b = np.float64(y[j])
            sxx += a * a
            syy += b * b
            sxy += a * b
    return sxx, syy, sxy


@dataclass(frozen=True)
class Level:
    """One resolution of the refinement: the (smoothed, normalised) images, the fixed
    reference gradient (inverse-compositional style: the 2x2 normal matrix then changes
    only through the robust weights) and the border left out of the fit, px."""

    ref: np.ndarray
    mov: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    border: int


def make_level(ref: np.ndarray, mov: np.ndarray, border: int) -> Level | None:
    """A refinement level of ``ref`` and ``mov``, or None when ``ref`` has no texture
    (its gradients' normal matrix is singular)."""
    h, w = ref.shape
    gx = cv2.Sobel(ref, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    gy = cv2.Sobel(ref, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / 8.0)
    sxx, syy, sxy = _gradient_moments(gx, gy, border)
    n_inner = (h - 2 * border) * (w - 2 * border)
    if sxx * syy - sxy * sxy <= 1e-12 * n_inner**2:
        return None
    return Level(ref, mov, gx, gy, border)


def refine(levels: tuple[Level, ...], start: tuple[float, float], *, robust_scale: float,
           max_iter: int, tol: float, give_up: float = np.inf
           ) -> tuple[tuple[float, float], bool, float]:
    """Coarse-to-fine robust Gauss-Newton refinement of the shift from ``start``.

    ``levels`` run coarsest first, each half the size of the next; ``start``, the result
    and ``give_up`` are in full-resolution px, ``tol`` in each level's own px. A level that
    does not converge, or whose shift leaves the disc of radius ``give_up`` about zero,
    ends the refinement, not converged (:mod:`processing.preprocess.registration`). Returns
    (shift, converged, cost), cost the Cauchy scale of the last level's residual.
    """
    shift, converged, cost = start, False, np.inf
    for k, level in enumerate(levels):
        f = 2.0 ** (len(levels) - 1 - k)  # full-resolution px per px of this level
        s, converged, cost = _gauss_newton(level, (shift[0] / f, shift[1] / f),
                                           robust_scale=robust_scale, max_iter=max_iter,
                                           tol=tol, give_up=give_up / f)
        shift = (s[0] * f, s[1] * f)
        if not converged:
            break
    return shift, converged, cost


def shift_cost(level: Level, shift: tuple[float, float], robust_scale: float) -> float:
    """The refinement's cost (:func:`refine`) of ``level`` at ``shift`` (its px): the Cauchy
    scale of the residual moving(x + shift) - reference(x), i.e. how well the static
    background fits there."""
    h, w = level.ref.shape
    return float(_residual_scale(level.ref, level.mov, float(shift[0]), float(shift[1]),
                                 level.border, float(robust_scale),
                                 *_scratch(h, w, level.border)))


def _gauss_newton(level: Level, start: tuple[float, float], *, robust_scale: float,
                  max_iter: int, tol: float, give_up: float
                  ) -> tuple[tuple[float, float], bool, float]:
    """Robust Gauss-Newton refinement of the shift from ``start`` on one level (its px).

    Returns (shift, converged, cost), cost the Cauchy scale of the last residual (the
    median |r|, i.e. how well the static background fits; inf when it diverged).
    """
    dx, dy, converged, cost = _gauss_newton_loop(
        level.ref, level.mov, level.gx, level.gy, level.border, float(start[0]),
        float(start[1]), float(robust_scale), int(max_iter), float(tol), float(give_up))
    return (float(dx), float(dy)), bool(converged), float(cost)
