"""The exact mass flux through a curtain of viewing rays, from a simulator's flux moment.

A curtain (:mod:`processing.emission.curtains`) is the ruled surface P(u, Z) = Z r(u) / s of
the viewing rays through an image segment (r = (x - x0, y - y0, s), d_z = 1). The flux of a
mass concentration c (kg/m^3) with velocity V through it is

    Q = int int c V . (dP/du x dP/dZ) du dZ = sum_i (M_i . n) |e_perp,i| / s   [kg/s]

per one-pixel strip i, with n the curtain's unit normal, e_perp,i = e - (e . r^_i) r^_i as in
:func:`processing.emission.curtains.strip_widths`, and the flux moment of the ray

    M_i = integral c V Z dl                                                [kg/s]

along the ray (dl = |r| / s dZ). The simulator's renderer integrates M along every pixel's
ray (:func:`processing.synthetic.render.column_integrals`), so this is exact up to the ray
marching's quadrature: it needs no segmentation, no depth and no NECL, and it counts gas
below the detection limit too. The measured rate, sigma_i (V_i . n) Z_i / s |e_perp,i|,
equals it when V and Z do not vary along the ray.
"""

from __future__ import annotations

import numpy as np

from processing.emission.curtains import Curtain, curtain_normal, sample_nearest, strip_widths


def true_curtain_flux(curtain: Curtain, flux_moment_kg_s: np.ndarray, *,
                      principal_point: tuple[float, float], camera_constant: float) -> float:
    """Exact mass flux (kg/s) through ``curtain`` (module docstring).

    Parameters
    ----------
    curtain : Curtain
        Segment in the left image, px; oriented as for the measured flux.
    flux_moment_kg_s : ndarray, shape (H, W, 3)
        M = integral c V Z dl per pixel (left camera frame), kg/s.
    principal_point, camera_constant
        (x0, y0) and s of the left camera, px.

    Returns
    -------
    float
        Q in kg/s (positive: gas crossing along the curtain's normal).
    """
    pts = curtain.samples()
    m = sample_nearest(np.asarray(flux_moment_kg_s, np.float64), pts)
    n = curtain_normal(curtain, principal_point, camera_constant)
    # strip_widths with Z = 1 is |e_perp,i| times the sample spacing over s.
    w = strip_widths(curtain, np.ones(len(pts)), principal_point, camera_constant)
    return float(np.sum((m @ n) * w))
