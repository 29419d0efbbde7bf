"""Gas-cell calibration of the band-averaged absorption coefficient alpha_g (Eq. 1).

Set-up: a black body behind a sealed gas cell. Frames of the cell empty (or filled with
nitrogen) give the background radiance L_0 seen through the cell's windows; frames of the
cell filled to known column densities CL_k (ppm*m = concentration x cell length) give L_k.
With the gas at the cell's temperature T_g (radiance L_g), Eq. 1 gives per fill

    tau_k = (L_k - L_g) / (L_0 - L_g),     -ln tau_k = alpha_g CL_k,

and alpha_g is the least-squares slope through the origin. Band averaging over an
unresolved line spectrum makes -ln tau grow slower than linearly at large CL (strong lines
saturate); the per-fill alphas and the residuals show it, so an engineer can calibrate over
the column densities the site will see.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GasCellFit:
    """Result of :func:`fit_alpha`.

    Attributes
    ----------
    alpha_per_ppm_m : float
        Fitted band-averaged absorption coefficient, natural log, per ppm*m.
    per_fill_alpha : tuple of float
        -ln(tau_k) / CL_k of each fill.
    transmittances : tuple of float
        tau_k of each fill.
    residual_rms : float
        RMS of -ln(tau_k) - alpha CL_k (dimensionless optical depth).
    """

    alpha_per_ppm_m: float
    per_fill_alpha: tuple[float, ...]
    transmittances: tuple[float, ...]
    residual_rms: float


def fit_alpha(column_ppm_m: Sequence[float], radiance_filled: Sequence[float],
              radiance_empty: float, gas_radiance: float) -> GasCellFit:
    """Fit alpha_g from gas-cell radiances (module docstring).

    Parameters
    ----------
    column_ppm_m : sequence of float
        Known column density of each fill, ppm*m (> 0).
    radiance_filled : sequence of float
        Mean in-band radiance L_k seen through each fill, W m^-2 sr^-1.
    radiance_empty : float
        Radiance L_0 through the empty cell, W m^-2 sr^-1.
    gas_radiance : float
        Black-body radiance L_g at the gas temperature, W m^-2 sr^-1.

    Returns
    -------
    GasCellFit

    Raises
    ------
    ValueError
        No fill, a non-positive column, no thermal contrast (L_0 = L_g), or a fill whose
        transmittance is not in (0, 1) (the cell absorbs nothing, or the black body is on
        the wrong side of the gas temperature).
    """
    cl = np.asarray(column_ppm_m, np.float64)
    L = np.asarray(radiance_filled, np.float64)
    if cl.ndim != 1 or cl.size == 0 or cl.shape != L.shape:
        raise ValueError("need one radiance per column density, at least one fill")
    if np.any(~(cl > 0)):
        raise ValueError(f"column densities must be > 0 ppm*m, got {cl.tolist()}")
    contrast = float(radiance_empty) - float(gas_radiance)
    if abs(contrast) < 1e-9:
        raise ValueError("no thermal contrast: the black body must be warmer or colder than "
                         "the gas in the cell")
    tau = (L - float(gas_radiance)) / contrast
    bad = ~((tau > 0) & (tau < 1))
    if np.any(bad):
        raise ValueError(
            "transmittance outside (0, 1) for column(s) "
            f"{cl[bad].tolist()} ppm*m (tau = {np.round(tau[bad], 5).tolist()}): check that "
            "the cell absorbs, that the empty-cell frames are right and the gas temperature")
    y = -np.log(tau)
    alpha = float(cl @ y / (cl @ cl))
    resid = y - alpha * cl
    return GasCellFit(alpha, tuple(float(v) for v in y / cl), tuple(float(t) for t in tau),
                      float(np.sqrt(np.mean(resid**2))))
