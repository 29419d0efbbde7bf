"""The first normalisation scale of a stream and the gas radiance it is measured in (Sec. 4.1).

Later triples take the scale their :class:`processing.chain.state.ChainState` tracks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from processing.calibration.radiometric import gas_radiance_and_floor
from processing.chain.parameters import ChainParameters
from processing.preprocess.differential import differential_image, radiometric_correction
from processing.stereo_geometry import StereoGeometry


def gas_radiance(params: ChainParameters,
                 geometry: StereoGeometry) -> tuple[float | None, float]:
    """(L_g, contrast floor) in radiance units for the optical-depth differential images,
    or (None, 0) when the gas temperature or the radiometric curves are not known."""
    curve = geometry.curve_left
    if params.gas_temperature_k is None or curve is None or geometry.curve_right is None:
        return None, 0.0
    return gas_radiance_and_floor(params.gas_temperature_k, curve.band_m,
                                  params.min_contrast_k)


def initial_scale(left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                  geometry: StereoGeometry, params: ChainParameters | None = None) -> float:
    """A provisional first normalisation scale: 0.999 quantile of |D(t0)| over both
    cameras, before registration (the chain takes it again from the registered, gated
    differences when that is smaller)."""
    lg, floor = gas_radiance(params or ChainParameters(), geometry)
    diffs = []
    for frames, curve in ((left, geometry.curve_left), (right, geometry.curve_right)):
        a = radiometric_correction(frames[0], curve)
        b = radiometric_correction(frames[1], curve)
        diffs.append(np.abs(differential_image(a, b, lg, floor))[::2, ::2].ravel())
    q = float(np.quantile(np.concatenate(diffs), 0.999))
    # A static scene has no difference at all; any positive scale then gives flat 0.5.
    return q if q > 0 else 1.0
