"""Pre-processing of a stereo triple (paper Sec. 4.1) with one normalisation scale for
both cameras, and what the chain does with the scale afterwards: the samples a scale
quantile may look at, and a triple renormalised to a new scale.

Each camera goes through :mod:`processing.preprocess.differential`; this module orders the
two cameras' steps so that D(t0), which the previous triple may already have computed,
is looked up as late as possible (:func:`preprocess_stereo`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from processing.calibration.radiometric import CharacteristicCurve
from processing.preprocess.differential import (
    PreprocessedTriple,
    SecondDifference,
    complete_triple,
    second_difference,
)
from processing.validation import check_positive, check_same_shape

#: Per camera (left, right): D(t0) raw and denoised when already known, else None.
KnownDiff0 = tuple[tuple[np.ndarray, np.ndarray] | None, tuple[np.ndarray, np.ndarray] | None]


def preprocess_stereo(
    left: Sequence[np.ndarray],
    right: Sequence[np.ndarray],
    *,
    scale: float,
    curves: tuple[CharacteristicCurve | None, CharacteristicCurve | None] = (None, None),
    maps: tuple[tuple[np.ndarray, np.ndarray] | None, tuple[np.ndarray, np.ndarray] | None] = (
        None,
        None,
    ),
    register: bool = True,
    denoise_lambda: float = 2.0,
    shift01: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None),
    max_shift_px: float = 1.0,
    gas_radiance: float | None = None,
    min_contrast: float = 0.0,
    shift12: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None),
    diff0: Callable[[tuple[SecondDifference, SecondDifference]], KnownDiff0] | None = None,
) -> tuple[PreprocessedTriple, PreprocessedTriple]:
    """``preprocess_camera`` (:mod:`processing.preprocess.differential`) for both cameras
    of a stereo triple with ONE shared scale.

    The single ``scale`` argument is the point: E1 and E4 (Eq. 3a, 3d) compare left and
    right intensities, so both cameras must be normalised by the same affine map.

    Parameters
    ----------
    left, right : sequence of 3 ndarrays, shape (H, W)
        Raw frames at t0, t1, t2 of the left and right camera.
    scale : float
        Shared normalisation scale in radiance units.
    curves, maps, shift01, shift12 : pairs (left, right)
        Per-camera characteristic curve, rectification maps, known t0 -> t1 and
        t1 -> t2 shifts (``preprocess_camera``).
    diff0 : callable or None
        A look-up of the known D(t0) per camera (``diff0`` of ``preprocess_camera``, or
        None), called with both cameras' :class:`SecondDifference` once their D(t1)
        exist; None: compute every D(t0). Two
        workers of one stream start their triples at about the same time when they run
        flat out, and each one's D(t0) is the other's D(t1): asked for at the start, it is
        rarely there yet; asked for after both D(t1), mostly (the look-up can publish this
        triple's D(t1) first).
    register, denoise_lambda, max_shift_px, gas_radiance, min_contrast
        As in ``preprocess_camera``, the same for both cameras.

    Returns
    -------
    (PreprocessedTriple, PreprocessedTriple)
        Left and right.

    Raises
    ------
    ValueError
        As ``preprocess_camera``, or when the two cameras' results differ in shape.
    """
    scale = check_positive(scale, "scale")
    seconds = [
        second_difference(frames, curve=curves[k], maps=maps[k], register=register,
                          denoise_lambda=denoise_lambda, shift01=shift01[k],
                          max_shift_px=max_shift_px, gas_radiance=gas_radiance,
                          min_contrast=min_contrast, shift12=shift12[k])
        for k, frames in enumerate((left, right))
    ]
    pair = (seconds[0], seconds[1])
    check_same_shape(pair[0].raw1, pair[1].raw1, "left differential image", "right")
    known: KnownDiff0 = (None, None) if diff0 is None else diff0(pair)
    out = tuple(
        complete_triple(second, scale=scale, denoise_lambda=denoise_lambda,
                        gas_radiance=gas_radiance, min_contrast=min_contrast, diff0=known[k])
        for k, second in enumerate(pair)
    )
    return out[0], out[1]


def rescale_differences(triple: PreprocessedTriple, factor: float) -> PreprocessedTriple:
    """``triple`` normalised with its scale divided by ``factor``.

    The map to [0, 1] is affine (0.5 + D / 2s), so 0.5 + (diff - 0.5) factor, clipped,
    equals normalising anew - exactly for factor >= 1 (a smaller scale), up to the values
    the old scale had clipped otherwise. The raw differences stay as they are.
    """
    f = np.float32(factor)

    def one(diff: np.ndarray) -> np.ndarray:
        return np.clip((diff - np.float32(0.5)) * f + np.float32(0.5), 0.0, 1.0).astype(
            np.float32, copy=False)

    return dataclasses.replace(triple, diff0=one(triple.diff0), diff1=one(triple.diff1))


def scale_samples(pl: PreprocessedTriple, pr: PreprocessedTriple) -> list[np.ndarray]:
    """The four raw differential images of a triple without the border strip the
    registration's warps filled with mirrored values (:attr:`PreprocessedTriple.border_px`,
    the wider of the two cameras'): what a normalisation quantile may look at."""
    b = max(pl.border_px, pr.border_px)
    raws = (pl.raw0, pl.raw1, pr.raw0, pr.raw1)
    return [r[b:-b, b:-b] for r in raws] if b else list(raws)
