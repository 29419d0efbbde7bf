"""The constant-mode step of the joint disparity solver (beyond the paper, Eq. 6 unchanged).

After every SOR solve, d and d' are shifted by the constants that minimise the linearised
energy: the smooth error modes that SOR damps slowest are removed at once. It changes only
how fast the solver reaches the minimum of Eq. 6, not the minimum.
"""

from __future__ import annotations

import numba
import numpy as np

from processing.solvers import redblack

#: Largest offset of d or d' in one constant-mode step, px (of the level).
MAX_CONSTANT_STEP_PX = 0.5


@numba.njit(cache=True, error_model="numpy")
def constant_mode_step(
    coefs: tuple[np.ndarray, np.ndarray],
    a11: tuple[np.ndarray, np.ndarray],
    a22: tuple[np.ndarray, np.ndarray],
    ds: tuple[np.ndarray, np.ndarray],
    ps: tuple[np.ndarray, np.ndarray],
) -> None:
    """Add to d and d' the constant offsets that minimise the lagged quadratic energy.

    The smoothness terms of Eq. 6 do not change when a constant is added to d or d', so
    over those two directions the linearised energy is the data terms' alone, and its
    minimum is the solution of the 2x2 system of the summed equations::

        [sum A11  sum A12] [delta_d ]   [sum (r1 - A11 d - A12 d')]
        [sum A12  sum A22] [delta_d'] = [sum (r2 - A12 d - A22 d')]

    (the edge weights are symmetric, so the diffusion parts of the equations sum to zero).
    Red-black SOR removes that error mode slowest of all: d' is stiffly smooth (gamma2
    psi' reaches gamma2 / eps) and constrained by data only on the gas, so the field kept
    much of its starting value (measured on a field scene: -0.28, -0.31, -0.34 px from
    starts 0, -0.28, -0.5; on a plane textured over a tenth of the image 0.77 px for
    1.19 px). d and d' are shifted together: a d' step alone, with d off by a pixel where
    the gas's texture was blanked, moved d' the wrong way.

    Parameters
    ----------
    coefs : (ndarray, ndarray), shape (13, H+2, W2+2)
        The colours' systems (planes of :mod:`processing.solvers.redblack`; A12, R1, R2 are read).
    a11, a22 : (ndarray, ndarray), shape (H+2, W2+2)
        Data parts of the diagonals.
    ds, ps : (ndarray, ndarray), shape (H+2, W2+2)
        d and d' in compact layout, updated in place (interior only; the halo stays 0).
    """
    s11 = s12 = s22 = b1 = b2 = 0.0
    for c in range(2):
        coef = coefs[c]
        h = coef.shape[1] - 1
        w = coef.shape[2] - 1
        for y in range(1, h):
            ra11, ra22, dv, pv = a11[c][y], a22[c][y], ds[c][y], ps[c][y]
            ra12, rr1, rr2 = coef[redblack.A12, y], coef[redblack.R1, y], coef[redblack.R2, y]
            for x in range(1, w):
                s11 += ra11[x]
                s12 += ra12[x]
                s22 += ra22[x]
                b1 += rr1[x] - ra11[x] * dv[x] - ra12[x] * pv[x]
                b2 += rr2[x] - ra12[x] * dv[x] - ra22[x] * pv[x]
    det = s11 * s22 - s12 * s12
    if s11 <= 0.0 or s22 <= 0.0 or det <= 1e-3 * s11 * s22:
        return  # no data at all, or d and d' not separable: nothing to fix
    # No further than the linearisation holds (the data terms are linear in d, d' about
    # the warp only within about a pixel); a far minimum is reached over several steps.
    delta_d = min(max((s22 * b1 - s12 * b2) / det, -MAX_CONSTANT_STEP_PX), MAX_CONSTANT_STEP_PX)
    delta_p = min(max((s11 * b2 - s12 * b1) / det, -MAX_CONSTANT_STEP_PX), MAX_CONSTANT_STEP_PX)
    fd = np.float32(delta_d)
    fp = np.float32(delta_p)
    for c in range(2):
        h = ds[c].shape[0] - 1
        w = ds[c].shape[1] - 1
        for y in range(1, h):
            for x in range(1, w):
                ds[c][y, x] += fd
                ps[c][y, x] += fp
