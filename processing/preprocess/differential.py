"""Pre-processing of raw OGI frames into differential images (paper Sec. 4.1, Eq. 2).

Per camera and per triple of consecutive frames (t0, t1, t2), in this order:

1. radiometric correction: raw counts -> in-band radiance by the camera's characteristic
   curve (:func:`radiometric_correction`), so that both cameras speak the same unit;
2. rectification with the stereo calibration's maps (:func:`apply_rectification`);
3. jitter removal: t1 and t2 are registered onto t0
   (:mod:`processing.preprocess.registration`), so both differential images of the triple
   live on the t0 pixel grid;
4. differences (Eq. 2): D(t0) = I(t0) - I(t1), D(t1) = I(t1) - I(t2), in radiance units, less
   the step of the camera's offset between the two frames (:func:`offset_step`), or, when
   the gas radiance L_g is known, the differential optical depth (:func:`differential_image`);
5. Sobolev denoising of each difference (:mod:`processing.preprocess.denoise`);
6. normalisation to [0, 1] with one fixed scale shared by both cameras
   (:func:`normalise_difference`).

Why the differential optical depth: with Eq. 1, I = L_bg tau + L_g (1 - tau), so the plain
difference I(t0) - I(t1) = (L_bg - L_g)(tau0 - tau1) carries the background's texture: in
front of pipes and tanks the gas's own signal is modulated by a pattern that does not move
with the gas, and the right camera sees another part of the wall behind the same gas (the
wall has its own disparity). Both break the constancy assumptions of Eq. 3. Dividing by the
local contrast I - L_g = (L_bg - L_g) tau removes L_bg exactly:
(I(t0) - I(t1)) / (I_mid - L_g) ~ (tau0 - tau1) / tau, the change of optical depth, which
moves with the gas and is the same in both views. It needs radiance units (a radiometric
calibration) and L_g, the radiance of a black body at the gas temperature (about the
ambient air temperature, which the anemometer measures). Where |I - L_g| is below
``min_contrast`` the divisor is held at that floor, so noise is not amplified without bound
where the background has the gas's temperature (the low-contrast case).

Why one shared, slowly varying scale: see :mod:`processing.preprocess.normalisation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from processing.calibration.radiometric import CharacteristicCurve, apply_characteristic_curve
from processing.preprocess.denoise import sobolev_denoise
from processing.preprocess.normalisation import normalise_difference
from processing.preprocess.offset import offset_step
from processing.preprocess.registration import estimate_shift_checked
from processing.preprocess.translation import warp_border_px, warp_translation
from processing.validation import as_float_image, check_positive, check_same_shape


def radiometric_correction(counts: np.ndarray, curve: CharacteristicCurve | None) -> np.ndarray:
    """Convert raw detector counts to in-band radiance by the characteristic curve.

    Validates the frame, then inverts the curve of the calibration file with
    :func:`processing.calibration.apply_characteristic_curve` (one implementation of the
    inversion for the whole code base).

    Parameters
    ----------
    counts : ndarray, shape (H, W), uint8/uint16/float
        Raw frame.
    curve : CharacteristicCurve or None
        The camera's characteristic curve, counts = offset + gain L + curvature L^2, as
        loaded from the calibration file. ``None`` means identity: the result is the
        counts as float32 (unit "counts").

    Returns
    -------
    ndarray, shape (H, W), float32
        Radiance L in W m^-2 sr^-1 (or counts when ``curve`` is None).

    Raises
    ------
    ValueError
        Not 2-D, not numeric, NaN/inf, or ``curve`` is not a CharacteristicCurve.
    """
    if not isinstance(counts, np.ndarray) or counts.ndim != 2:
        raise ValueError(
            f"counts must be a 2-D array, got {getattr(counts, 'shape', type(counts).__name__)}"
        )
    if not (np.issubdtype(counts.dtype, np.integer) or np.issubdtype(counts.dtype, np.floating)):
        raise ValueError(f"counts must be integer or float, got {counts.dtype}")
    if curve is not None and not isinstance(curve, CharacteristicCurve):
        raise ValueError(
            f"curve must be a CharacteristicCurve or None, got {type(curve).__name__}"
        )
    if np.issubdtype(counts.dtype, np.floating) and not np.all(np.isfinite(counts)):
        raise ValueError("counts contain NaN or infinite values")
    return apply_characteristic_curve(counts, curve)


def apply_rectification(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Resample an image with rectification maps (``cv2.remap``, bilinear, replicated border).

    Parameters
    ----------
    image : ndarray, shape (H, W), float
        Radiometrically corrected frame.
    map_x, map_y : ndarray, shape (H', W'), float32
        Source x and y coordinates per output pixel, as produced by
        ``cv2.initUndistortRectifyMap(..., cv2.CV_32FC1)`` from the stereo calibration.

    Returns
    -------
    ndarray, shape (H', W'), float32
        The rectified frame.
    """
    img = as_float_image(image, "image")
    if not isinstance(map_x, np.ndarray) or not isinstance(map_y, np.ndarray):
        raise ValueError("map_x and map_y must be numpy arrays")
    check_same_shape(map_x, map_y, "map_x", "map_y")
    if map_x.ndim != 2:
        raise ValueError(f"rectification maps must be 2-D, got shape {map_x.shape}")
    return cv2.remap(
        img,
        np.ascontiguousarray(map_x, dtype=np.float32),
        np.ascontiguousarray(map_y, dtype=np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )


def differential_image(
    earlier: np.ndarray,
    later: np.ndarray,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
) -> np.ndarray:
    """Differential image of two registered frames (Eq. 2), optionally as optical depth:
    :func:`levelled_difference` without the step it levelled out."""
    return levelled_difference(earlier, later, gas_radiance, min_contrast)[0]


def levelled_difference(
    earlier: np.ndarray,
    later: np.ndarray,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Differential image of two registered frames (Eq. 2), optionally as optical depth,
    and the step of the camera's offset levelled out of it.

    Parameters
    ----------
    earlier, later : ndarray, shape (H, W), float32
        I(t) and I(t+1) in radiance units (or counts when ``gas_radiance`` is None).
    gas_radiance : float or None
        L_g, in-band radiance of a black body at the gas temperature, same unit as the
        frames. None gives the plain difference I(t) - I(t+1).
    min_contrast : float
        Floor of |I_mid - L_g| (radiance units, > 0 when ``gas_radiance`` is given).

    Returns
    -------
    difference : ndarray, shape (H, W), float32
        I(t) - I(t+1) less the camera's offset step between them (:func:`offset_step`), or
        that divided by c = I_mid - L_g held at +-``min_contrast`` (module docstring, I(t+1)
        brought onto I(t)'s offset): dimensionless, ~ the change of optical depth.
    step : float
        The step levelled out, in the frames' unit (0.0: none found).
    """
    diff = earlier - later
    step = offset_step(diff, float(np.abs(earlier[::2, ::2]).mean()))
    # The later frame brought onto the earlier one's offset (a shutter, a NUC, a drift of
    # the camera's offset between the two), so the difference is gas and noise alone.
    if step:
        diff -= np.float32(step)
    if gas_radiance is None:
        return diff, step
    floor = check_positive(min_contrast, "min_contrast")
    contrast = 0.5 * (earlier + later + np.float32(step)) - np.float32(gas_radiance)
    # The divisor keeps its sign (gas in front of a warmer or a colder background) and is
    # held at the floor where the background has about the gas's temperature.
    mag = np.maximum(np.abs(contrast), np.float32(floor))
    return (diff / np.where(contrast < 0, -mag, mag)).astype(np.float32, copy=False), step


@dataclass(frozen=True)
class PreprocessedTriple:
    """Normalised differential images of one camera for one triple (t0, t1, t2).

    Attributes
    ----------
    diff0, diff1 : ndarray, shape (H, W), float32 in [0, 1]
        Normalised I_diff(t0) = I(t0) - I(t1) and I_diff(t1) = I(t1) - I(t2) (Eq. 2), both on
        the pixel grid of frame t0, denoised.
    raw0, raw1 : ndarray, shape (H, W), float32
        The same differences in radiance units before denoising and normalisation (for a
        :class:`DiffScaleTracker`).
    shifts : ((float, float), (float, float))
        Jitter (dx, dy) in px of t1 relative to t0 and of t2 relative to t1 that was
        removed (zeros when registration is off or rejected). Pass ``shifts[1]`` as
        ``shift01`` of the next triple.
    rejected_shifts : int
        How many estimated shifts of this triple (0-2) exceeded ``max_shift_px`` and were
        therefore not applied.
    rejected : (bool, bool)
        Which of the two shifts this call estimated and rejected (False for a known one).
    offset_step1 : float
        The step of the camera's offset levelled out of D(t1) (:func:`levelled_difference`),
        radiance units (counts without a characteristic curve); 0.0: none. D(t0) is the
        previous triple's D(t1), so each frame pair's step is reported once, by the triple
        that computed its difference as D(t1).
    """

    diff0: np.ndarray
    diff1: np.ndarray
    raw0: np.ndarray
    raw1: np.ndarray
    shifts: tuple[tuple[float, float], tuple[float, float]]
    rejected_shifts: int = 0
    rejected: tuple[bool, bool] = (False, False)
    offset_step1: float = 0.0

    @property
    def border_px(self) -> int:
        """Width of the border strip of ``raw0``/``raw1`` (and the diffs) that the
        registration's warps filled with mirrored values rather than measurements, px
        (:func:`triple_border_px` of its shifts)."""
        return triple_border_px(self.shifts)


def triple_border_px(shifts: tuple[tuple[float, float], tuple[float, float]]) -> int:
    """Width of the border strip a triple's registration filled with mirrored values, px:
    :func:`processing.preprocess.translation.warp_border_px` of the warps of t1 (shift
    t0 -> t1) and t2 (t0 -> t1 plus t1 -> t2), from the triple's ``shifts`` (s01, s12)."""
    s01, s12 = shifts
    return warp_border_px(s01, (s01[0] + s12[0], s01[1] + s12[1]))


@dataclass(frozen=True)
class SecondDifference:
    """One camera's triple registered and its D(t1) computed: what
    :func:`preprocess_camera` knows before it needs D(t0).

    D(t0) is the previous triple's D(t1) (another worker's, when two share a stream), so
    it is looked up only after this triple's own D(t1) exist: the later, the likelier the
    other worker has shared it (:func:`complete_triple`).

    Attributes
    ----------
    frames : tuple of 3 ndarrays, shape (H, W), float32
        Corrected frames t0, t1, t2, with t1 and t2 registered onto t0's grid.
    shifts, rejected
        As :class:`PreprocessedTriple`.
    raw1, denoised1 : ndarray, shape (H, W), float32
        D(t1) = I(t1) - I(t2) (Eq. 2) in radiance units, and denoised.
    step1 : float
        The camera's offset step levelled out of D(t1), radiance units (0.0: none).
    """

    frames: tuple[np.ndarray, np.ndarray, np.ndarray]
    shifts: tuple[tuple[float, float], tuple[float, float]]
    rejected: tuple[bool, bool]
    raw1: np.ndarray
    denoised1: np.ndarray
    step1: float = 0.0


def second_difference(
    frames: Sequence[np.ndarray],
    *,
    curve: CharacteristicCurve | None = None,
    maps: tuple[np.ndarray, np.ndarray] | None = None,
    register: bool = True,
    denoise_lambda: float = 2.0,
    shift01: tuple[float, float] | None = None,
    max_shift_px: float = 1.0,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
    shift12: tuple[float, float] | None = None,
) -> SecondDifference:
    """Steps 1-5 of the module docstring for one camera's triple, D(t1) only.

    Parameters and errors as :func:`preprocess_camera` (less ``scale`` and ``diff0``).
    """
    if len(frames) != 3:
        raise ValueError(f"need exactly 3 consecutive frames (t0, t1, t2), got {len(frames)}")
    imgs = [radiometric_correction(f, curve) for f in frames]
    check_same_shape(imgs[0], imgs[1], "frame t0", "frame t1")
    check_same_shape(imgs[0], imgs[2], "frame t0", "frame t2")
    if maps is not None:
        if len(maps) != 2:
            raise ValueError("maps must be a pair (map_x, map_y)")
        imgs = [apply_rectification(im, maps[0], maps[1]) for im in imgs]
    s01: tuple[float, float] = (0.0, 0.0)
    s12: tuple[float, float] = (0.0, 0.0)
    rejected = [False, False]
    if register:
        max_shift = check_positive(max_shift_px, "max_shift_px")

        def plausible(k: int) -> tuple[float, float]:
            try:
                shift, converged = estimate_shift_checked(imgs[k], imgs[k + 1], max_iter=20,
                                                          max_shift=max_shift)
            except ValueError:  # a flat frame (uniform sky, no noise): nothing to lock onto
                shift, converged = (0.0, 0.0), False
            if converged and float(np.hypot(*shift)) <= max_shift:
                return shift
            rejected[k] = True
            return (0.0, 0.0)

        s01 = shift01 if shift01 is not None else plausible(0)
        s12 = shift12 if shift12 is not None else plausible(1)
        s02 = (s01[0] + s12[0], s01[1] + s12[1])
        imgs[1] = warp_translation(imgs[1], s01)
        imgs[2] = warp_translation(imgs[2], s02)
    raw1, step1 = levelled_difference(imgs[1], imgs[2], gas_radiance, min_contrast)
    return SecondDifference((imgs[0], imgs[1], imgs[2]), (s01, s12),
                            (rejected[0], rejected[1]), raw1,
                            sobolev_denoise(raw1, denoise_lambda), step1)


def complete_triple(
    second: SecondDifference,
    *,
    scale: float,
    denoise_lambda: float = 2.0,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
    diff0: tuple[np.ndarray, np.ndarray] | None = None,
) -> PreprocessedTriple:
    """Steps 4-6 of the module docstring for D(t0), then both differences normalised.

    Parameters
    ----------
    second : SecondDifference
        The camera's registered triple and D(t1) (:func:`second_difference`).
    scale, denoise_lambda, gas_radiance, min_contrast, diff0
        As :func:`preprocess_camera`; ``diff0`` must belong to ``second``'s t0 -> t1 shift.

    Returns
    -------
    PreprocessedTriple
    """
    if diff0 is None:
        raw0 = differential_image(second.frames[0], second.frames[1], gas_radiance,
                                  min_contrast)
        smooth0 = sobolev_denoise(raw0, denoise_lambda)
    else:
        raw0, smooth0 = diff0
    return PreprocessedTriple(normalise_difference(smooth0, scale),
                              normalise_difference(second.denoised1, scale), raw0,
                              second.raw1, second.shifts, sum(second.rejected),
                              second.rejected, second.step1)


def preprocess_camera(
    frames: Sequence[np.ndarray],
    *,
    scale: float,
    curve: CharacteristicCurve | None = None,
    maps: tuple[np.ndarray, np.ndarray] | None = None,
    register: bool = True,
    denoise_lambda: float = 2.0,
    shift01: tuple[float, float] | None = None,
    max_shift_px: float = 1.0,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
    shift12: tuple[float, float] | None = None,
    diff0: tuple[np.ndarray, np.ndarray] | None = None,
) -> PreprocessedTriple:
    """Steps 1-6 of the module docstring for one camera and three consecutive frames.

    Parameters
    ----------
    frames : sequence of 3 ndarrays, shape (H, W), uint8/uint16/float
        Raw frames at t0, t1, t2 of one camera.
    scale : float
        Shared normalisation scale in radiance units (:func:`normalise_difference`).
    curve : mapping or None
        The camera's characteristic curve (:func:`radiometric_correction`).
    maps : (map_x, map_y) or None
        The camera's rectification maps (:func:`apply_rectification`); None skips it.
    register : bool
        Remove jitter by registering t1 and t2 onto t0.
    denoise_lambda : float
        Sobolev prior weight in px^2 (:func:`processing.preprocess.denoise.sobolev_denoise`);
        0 = off.
    shift01, shift12 : (float, float) or None
        Known shifts of t1 relative to t0 and of t2 relative to t1 (measured by an earlier
        triple that shared the frames, :class:`processing.chain.shifts.ShiftMemo`; shifts
        compose additively); each saves one registration.
    max_shift_px : float
        Largest plausible jitter in px. The registration assumes a static textured
        background; in front of a featureless one (sky, a uniform wall, the synthetic
        data) it locks onto the moving gas instead and would cancel the very motion we
        measure. Camera jitter is sub-pixel (paper Sec. 4.1), so an estimate larger than
        this, or one whose refinement did not converge (no rigid shift explains the
        change), is treated as gas motion: not applied, and counted in ``rejected_shifts``.
    gas_radiance, min_contrast : float or None, float
        L_g and the contrast floor of :func:`differential_image` (radiance units; needs
        ``curve``); None keeps the plain difference.
    diff0 : (ndarray, ndarray) or None
        D(t0) raw and denoised, shape (H, W) float32, when already known: the previous
        triple's D(t1) raw and denoised (:class:`SecondDifference`) of the same camera and
        settings, which are this D(t0) exactly when that triple left its t1 (this t0)
        unmoved and moved its t2 (this t1) by this ``shift01``. The caller vouches for
        that; it saves a difference and a denoising.

    Returns
    -------
    PreprocessedTriple

    Raises
    ------
    ValueError
        Not exactly three frames, shapes differ, bad frame, curve, maps or parameters.
    """
    scale = check_positive(scale, "scale")
    second = second_difference(frames, curve=curve, maps=maps, register=register,
                               denoise_lambda=denoise_lambda, shift01=shift01,
                               max_shift_px=max_shift_px, gas_radiance=gas_radiance,
                               min_contrast=min_contrast, shift12=shift12)
    return complete_triple(second, scale=scale, denoise_lambda=denoise_lambda,
                           gas_radiance=gas_radiance, min_contrast=min_contrast, diff0=diff0)
