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
``reference``. :func:`processing.preprocess.translation.warp_translation` with that d
resamples ``moving`` onto ``reference``.
Shifts compose additively: shift(t0 -> t2) = shift(t0 -> t1) + shift(t1 -> t2), which lets a
caller register each new frame against its predecessor only once and reuse the result.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import cv2
import numpy as np

from processing.preprocess import shift_refinement
from processing.preprocess.shift_refinement import Level, make_level
from processing.preprocess.translation import warp_translation
from processing.validation import as_float_image, check_same_shape

#: Smallest accepted image side in pixels for registration.
MIN_REGISTRATION_SIZE = 16
#: How far beyond ``max_shift`` a refinement from a plausible start may go before it is
#: given up, px (:func:`estimate_shift_checked`).
GIVE_UP_BEYOND_PX = 1.0
#: A converged shift longer than this (px) must fit the static background better than the
#: opposite shift (:data:`MAX_COST_RATIO`); a shorter one changes no differential image
#: measurably (the chain's ``jitter_corrected`` flag starts there too,
#: :data:`processing.chain.flags.JITTER_FLAG_PX`).
CHECKED_ABOVE_PX = 0.05
#: Largest ratio of the background's robust residual at a shift d to that at -d for d to be
#: camera jitter. -d, not 0: resampling at a fractional shift smooths the noise, so against
#: the unresampled frame any shift "fits" a noisy featureless wall better (0.65-0.73
#: measured); d and -d resample alike. Measured on the robustness matrices' frames (wide
#: development part, default matrix): real jitter of 0.06-1.44 px over a plant wall or a
#: sky gradient 0.09 at most without noise, 0.93 at most with noise, a warm object and a
#: gain mismatch besides; the fit converged on the gas itself, with no jitter at all, above
#: 0.95 for 56 of 63 shifts over a sky and 1.00 over a uniform wall (the median pixel is
#: the featureless wall, which no shift changes).
MAX_COST_RATIO = 0.95
#: Below this residual scale at -d (the frames in units of their spread) the background
#: is flat whichever way it is shifted: nothing there measures a shift (a noise-free
#: featureless wall).
MIN_MIRROR_COST = 1e-4


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
        Largest plausible shift in px (the camera's jitter). A refinement from a start
        within it stops, not converged, once it is :data:`GIVE_UP_BEYOND_PX` beyond it; one
        that has not converged but stays within it goes on for another ``max_iter`` steps;
        when the phase-correlation start lies beyond it, or the refinement converged beyond
        it, a second refinement starts from zero and the converged one with the smaller
        residual is returned (see the comments in the code). None: no bound.

    Returns
    -------
    (float, float)
        (dx, dy) in px with ``moving(x + d) ~ reference(x)``.
    bool
        True when the Gauss-Newton refinement converged (step below ``tol``) and, for a
        shift d above :data:`CHECKED_ABOVE_PX`, the static background fits d clearly
        better than -d (:data:`MAX_COST_RATIO`). Camera jitter over a static scene
        converges in a few steps and fits the background's texture; when it does not
        converge, no rigid shift explains the change (e.g. moving gas in front of a
        featureless background), and when it converges without fitting the background
        better it followed the only texture there is, the gas: the estimate must not be
        applied.

    Raises
    ------
    ValueError
        Shapes differ, not 2-D float, NaN/inf, too small, or a flat (textureless) reference
        on which no translation can be measured.
    """
    levels, start = _levels_and_start(reference, moving, border=border,
                                      smooth_sigma=smooth_sigma)

    def refine(from_: tuple[float, float]) -> tuple[tuple[float, float], bool, float]:
        # From a plausible start, a refinement that has gone a pixel beyond the plausible
        # shifts is following the gas or an object, not the camera: it stops there, as one
        # that drifted out without converging would after all its iterations (measured on
        # the bench's plume, where every shift is rejected: 0.2-0.4 ms of a warm triple).
        # At the bound itself three more shifts of the default matrix's sky scenes under
        # 0.2 px of jitter were rejected (the refinement came back), two at 0.5 px beyond,
        # none at a pixel.
        give_up = (max_shift + GIVE_UP_BEYOND_PX
                   if max_shift is not None and np.hypot(*from_) <= max_shift else np.inf)
        return shift_refinement.refine(levels, from_, robust_scale=robust_scale,
                                       max_iter=max_iter, tol=tol, give_up=give_up)

    shift, converged, cost = _plausible_shift(refine, start, max_shift)
    if converged and float(np.hypot(*shift)) > CHECKED_ABOVE_PX:
        # The fit's cost is the median pixel's residual: over texture the right shift
        # removes the edges' residual and the opposite one doubles it; on a featureless
        # wall the median pixel is flat whatever the shift, and what converged was the gas.
        mirrored = shift_refinement.shift_cost(levels[-1], (-shift[0], -shift[1]),
                                               robust_scale)
        converged = mirrored > MIN_MIRROR_COST and cost <= MAX_COST_RATIO * mirrored
    return shift, converged


def _levels_and_start(reference: np.ndarray, moving: np.ndarray, *, border: int,
                      smooth_sigma: float) -> tuple[tuple[Level, ...], tuple[float, float]]:
    """The refinement levels of the two frames and the phase-correlation start.

    Parameters
    ----------
    reference, moving : ndarray, shape (H, W), float
        See :func:`estimate_shift_checked`.
    border : int
        Pixels along each edge left out of the fit, px of the full resolution.
    smooth_sigma : float
        Gaussian pre-smoothing in px (0 disables it).

    Returns
    -------
    levels : tuple of Level
        Coarsest first: the half- and the full-resolution level, or the full one alone
        when the half one is too small or has no texture of its own.
    start : (float, float)
        The phase-correlation estimate (dx, dy) in full-resolution px.

    Raises
    ------
    ValueError
        See :func:`estimate_shift_checked`.
    """
    ref = as_float_image(reference, "reference", min_size=MIN_REGISTRATION_SIZE)
    mov = as_float_image(moving, "moving", min_size=MIN_REGISTRATION_SIZE)
    check_same_shape(ref, mov, "reference", "moving")
    h, w = ref.shape
    if border < 0 or 2 * border >= min(h, w) - 4:
        raise ValueError(f"border must be in [0, {(min(h, w) - 5) // 2}], got {border}")
    ref, mov = _normalised(ref, mov, smooth_sigma)

    # Coarse start on half-resolution images (4x cheaper; the Gauss-Newton refinement
    # converges from within about a pixel). Copies are not needed after pyrDown;
    # note that cv2.phaseCorrelate (OpenCV 5.0) multiplies its inputs by the window in place.
    ref_half = cv2.pyrDown(ref)
    mov_half = cv2.pyrDown(mov)
    (hx, hy), _ = cv2.phaseCorrelate(ref_half.copy(), mov_half.copy(),
                                     _hanning(ref_half.shape))

    fine = make_level(ref, mov, border)
    if fine is None:
        raise ValueError("reference image has no texture: the translation cannot be measured")
    coarse = (make_level(ref_half, mov_half, (border + 1) // 2)
              if min(ref_half.shape) >= MIN_REGISTRATION_SIZE else None)
    # A coarse level too small, or without texture of its own (a fine-grained pattern that
    # pyrDown averages away), is skipped: the fine level then refines alone.
    levels = (fine,) if coarse is None else (coarse, fine)
    return levels, (2.0 * hx, 2.0 * hy)


def _normalised(ref: np.ndarray, mov: np.ndarray, smooth_sigma: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Both frames in units of the reference's spread about its mean, then smoothed.

    Radiance (W m^-2 sr^-1, ~1e-2 per K) and 16-bit counts then meet the same texture test
    and the same numerics.

    Parameters
    ----------
    ref, mov : ndarray, shape (H, W), float32
        The validated frames.
    smooth_sigma : float
        Gaussian pre-smoothing in px (0 disables it).

    Returns
    -------
    ndarray, ndarray, shape (H, W), float32
        The normalised (and smoothed) reference and moving frame.

    Raises
    ------
    ValueError
        A flat reference (no spread).
    """
    # One pass with float64 sums (numpy's mean and std take three).
    mean, std = cv2.meanStdDev(ref)
    offset, spread = float(mean[0, 0]), float(std[0, 0])
    if not spread > 0:
        raise ValueError("reference image has no texture: the translation cannot be measured")

    def normalise(a: np.ndarray) -> np.ndarray:
        # The blur is linear and keeps a constant: blur first, then the affine map, in
        # place (one temporary less per frame).
        out = (cv2.GaussianBlur(a, (0, 0), smooth_sigma, borderType=cv2.BORDER_REFLECT_101)
               if smooth_sigma > 0 else a.copy())
        out -= np.float32(offset)
        out *= np.float32(1.0 / spread)
        return out

    return normalise(ref), normalise(mov)


Refinement = Callable[[tuple[float, float]], tuple[tuple[float, float], bool, float]]


def _plausible_shift(refine: Refinement, start: tuple[float, float],
                     max_shift: float | None) -> tuple[tuple[float, float], bool, float]:
    """The shift to report: the refinement from ``start``, continued or checked from zero.

    Parameters
    ----------
    refine : callable (start) -> (shift, converged, cost)
        The coarse-to-fine refinement from a start shift
        (:func:`processing.preprocess.shift_refinement.refine`), cost the median |r| of
        its last level.
    start : (float, float)
        The phase-correlation estimate, px.
    max_shift : float or None
        Largest plausible shift in px (None: no bound).

    Returns
    -------
    (float, float), bool, float
        The shift in px, whether it converged (:func:`estimate_shift_checked`) and its
        cost (the Cauchy scale of the last level's residual).
    """
    def plausible(d: tuple[float, float]) -> bool:
        return max_shift is None or float(np.hypot(*d)) <= max_shift

    shift, converged, cost = refine(start)
    if converged and plausible(shift) and plausible(start):
        return shift, converged, cost
    if plausible(start) and not converged:
        if not plausible(shift):
            # Drifted beyond any jitter without converging: no rigid shift explains the
            # change (gas over a featureless background). A second start would fail the
            # same way and double the cost on every such frame (measured: 23 -> 39 ms).
            return shift, converged, cost
        # Crawling towards a plausible shift (a warm object's residuals slow the robust
        # steps down: measured 20 iterations not enough, 100 converge): go on from there.
        return refine(shift)
    # Phase correlation found something else than the camera's shake: a warm object
    # moving across the view makes the strongest peak (its own motion, 3-3.5 px measured),
    # and the refinement from there converges to that motion or crawls. Check against a
    # refinement from zero (jitter is small): the converged fit with the smaller residual
    # (median |r|: the static background) wins; a true shift beyond ``max_shift`` still
    # wins over a false local fit and is then rejected by the caller.
    z_shift, z_converged, z_cost = refine((0.0, 0.0))
    if z_converged and (not converged or z_cost < cost):
        return z_shift, True, z_cost
    return shift, converged, cost


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
