"""Stage 1 of the chain (paper Sec. 4.1) for one triple of both cameras, with what the
stream already knows: each raw frame corrected (radiometric curve, rectification, then with
``binning`` the means of k x k blocks) only once per stream, the registration's shifts
estimated once per frame pair, and D(t0) taken from the previous triple's D(t1)
(:class:`processing.chain.state.ChainState`), looked up only after this triple's own D(t1)
(:func:`processing.preprocess.stereo_triple.preprocess_stereo`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from processing.calibration.radiometric import CharacteristicCurve
from processing.chain.binning import bin_image
from processing.chain.parameters import ChainParameters
from processing.chain.scale import gas_radiance
from processing.chain.state import ChainState, Times
from processing.preprocess.differential import (
    PreprocessedTriple,
    apply_rectification,
    radiometric_correction,
)
from processing.preprocess.stereo_triple import preprocess_stereo
from processing.stereo_geometry import Maps, StereoGeometry

#: Both cameras' pre-processed triples, (left, right).
Pair = tuple[PreprocessedTriple, PreprocessedTriple]


def check_frames(left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                 geometry: StereoGeometry) -> None:
    """ValueError unless there are three frames per camera, each of the geometry's size."""
    if len(left) != 3 or len(right) != 3:
        raise ValueError(f"need 3 left and 3 right frames, got {len(left)} and {len(right)}")
    w, h = geometry.image_size
    for side, frames in (("left", left), ("right", right)):
        for i, f in enumerate(frames):
            shape = getattr(f, "shape", None)
            if shape != (h, w):
                raise ValueError(
                    f"{side} frame t{i} has shape {shape}, the calibration expects {(h, w)}"
                )


def _correct(frame: np.ndarray, curve: CharacteristicCurve | None, maps: Maps | None,
             binning: int = 1) -> np.ndarray:
    """Radiometric correction and rectification of one raw frame, then its k x k blocks'
    means (``binning`` k)."""
    img = radiometric_correction(frame, curve)
    img = img if maps is None else apply_rectification(img, maps[0], maps[1])
    return bin_image(img, binning)


def preprocess_triple(left: Sequence[np.ndarray], right: Sequence[np.ndarray], times: Times,
                      geometry: StereoGeometry, params: ChainParameters, stream: ChainState,
                      scale: float, binning: int = 1) -> Pair:
    """Stage 1 (Sec. 4.1) for both cameras, each raw frame corrected (and binned) only once
    per stream; the registration's shifts and D(t0) taken from ``stream`` where it knows
    them."""
    known = stream.known_shifts(times, params.registration_pause_after if params.register
                                else 0)
    lg, contrast_floor = gas_radiance(params, geometry)
    # The corrected frames then go through pre-processing as they are (no curve, no maps).
    corrected = [
        stream.corrected_frames(cam, frames, times,
                                lambda f, curve=curve, maps=maps: _correct(f, curve, maps,
                                                                           binning))
        for cam, (frames, curve, maps) in enumerate((
            (left, geometry.curve_left, geometry.maps_left),
            (right, geometry.curve_right, geometry.maps_right)))
    ]
    # D(t0) of the previous triple's D(t1) (:meth:`ChainState.exchange_differences`),
    # looked up once this triple's D(t1) are computed and shared; the differences depend
    # on these settings too.
    settings = (lg, contrast_floor, params.denoise_lambda)
    pl, pr = preprocess_stereo(
        corrected[0], corrected[1], scale=scale, register=params.register,
        denoise_lambda=params.denoise_lambda,
        shift01=tuple(k[0][0] if k[0] else None for k in known),  # type: ignore[arg-type]
        shift12=tuple(k[1][0] if k[1] else None for k in known),  # type: ignore[arg-type]
        max_shift_px=params.max_jitter_px, gas_radiance=lg, min_contrast=contrast_floor,
        diff0=lambda seconds: stream.exchange_differences(times, seconds, settings),
    )
    pl, pr = stream.remember_shifts(times, known, (pl, pr))
    return pl, pr
