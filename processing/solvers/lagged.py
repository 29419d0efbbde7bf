"""Lagged-diffusivity building blocks of both variational solvers, in compact red-black form.

At each lagged fixed-point iteration (Brox et al. 2004) the flow solver (paper Eq. 5) and
the joint disparity solver (Eq. 6) freeze the Charbonnier weights psi'(|grad f|^2) of their
smoothness terms and turn them into edge weights of the linear system that
:mod:`processing.solvers.redblack` solves. Assembling a system on the full grid and scattering it
with :func:`processing.solvers.redblack.pack_system` costs about as much as ten SOR iterations
(stride-2 scatter of 13 planes), so the solvers keep their unknowns and inputs compact for a
whole warp and compute psi', edge weights and diagonals per colour here, with contiguous,
vectorisable row loops.
"""

from __future__ import annotations

import numba
import numpy as np

from processing.solvers import redblack
from processing.solvers.redblack import (
    INV_D1,
    INV_D2,
    W1_DOWN,
    W1_LEFT,
    W1_RIGHT,
    W1_UP,
    W2_DOWN,
    W2_LEFT,
    W2_RIGHT,
    W2_UP,
)


@numba.njit(cache=True)
def border_masks(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Edge-existence masks (4, H+2, W2+2) for red and black: left, right, up, down.

    1 where the pixel has that neighbour inside the image, 0 at image borders, in the
    halo and at padding entries (odd W), so that multiplying edge weights by the mask
    imposes Neumann boundary conditions and keeps padding entries decoupled.
    """
    shape = (4, height + 2, (width + 1) // 2 + 2)
    red = np.zeros(shape, np.float32)
    black = np.zeros(shape, np.float32)
    for y in range(height):
        for x in range(width):
            m = red if (x + y) % 2 == 0 else black
            yc = y + 1
            xc = x // 2 + 1
            m[0, yc, xc] = 1.0 if x > 0 else 0.0
            m[1, yc, xc] = 1.0 if x < width - 1 else 0.0
            m[2, yc, xc] = 1.0 if y > 0 else 0.0
            m[3, yc, xc] = 1.0 if y < height - 1 else 0.0
    return red, black


@numba.njit(cache=True)
def _fill_neumann_ghosts(red: np.ndarray, black: np.ndarray, width: int) -> None:
    """Copy border pixels into the halo neighbours that central differences read.

    After this, a centred difference at a border pixel equals half the one-sided
    difference (zero normal derivative), and no halo value is stale.
    """
    h = red.shape[0] - 2
    for yc in range(1, h + 1):
        y = yc - 1
        # Pixel x = 0 has colour y & 1; its left neighbour is column 0 of the other colour.
        own, other = (red, black) if (y & 1) == 0 else (black, red)
        other[yc, 0] = own[yc, 1]
        # Pixel x = W-1: colour (W-1+y) & 1, compact column (W-1)//2 + 1, right neighbour
        # at that column + ((W-1) & 1) in the other colour.
        xc = (width - 1) // 2 + 1
        own, other = (red, black) if ((width - 1 + y) & 1) == 0 else (black, red)
        other[yc, xc + ((width - 1) & 1)] = own[yc, xc]
    last = h
    black[0, :] = red[1, :]
    red[0, :] = black[1, :]
    black[last + 1, :] = red[last, :]
    red[last + 1, :] = black[last, :]


@numba.njit(cache=True, fastmath=True)
def _gradient_sq(own: np.ndarray, other: np.ndarray, colour: int, out: np.ndarray) -> None:
    """Add |grad f|^2 at the pixels of one colour to ``out`` (centred differences).

    ``own`` and ``other`` are the compact arrays of f for this colour and the other one,
    whose halos were filled by :func:`_fill_neumann_ghosts`.
    """
    h = own.shape[0] - 2
    n = own.shape[1] - 2
    e = n + 1
    for yc in range(1, h + 1):
        off = (yc - 1 + colour) & 1
        fl = other[yc, off:off + n]
        fr = other[yc, off + 1:off + 1 + n]
        fu = other[yc - 1, 1:e]
        fd = other[yc + 1, 1:e]
        o = out[yc, 1:e]
        for i in range(n):
            gx = np.float32(0.5) * (fr[i] - fl[i])
            gy = np.float32(0.5) * (fd[i] - fu[i])
            o[i] += gx * gx + gy * gy


@numba.njit(cache=True, fastmath=True)
def _charbonnier_prime(s2: np.ndarray, eps: float, out: np.ndarray) -> None:
    """out = 1 / sqrt(s2 + eps^2) elementwise on compact arrays (lagged psi')."""
    e2 = np.float32(eps * eps)
    h, w = s2.shape
    for y in range(h):
        a = s2[y]
        o = out[y]
        for x in range(w):
            o[x] = np.float32(1.0) / np.sqrt(a[x] + e2)


@numba.njit(cache=True)
def lagged_psi(
    fields: tuple[tuple[np.ndarray, np.ndarray], ...],
    width: int,
    eps: float,
    s2: np.ndarray,
    psi: tuple[np.ndarray, np.ndarray],
) -> None:
    """Lagged weight psi'(sum |grad f|^2) of one Charbonnier smoothness term, per colour.

    Parameters
    ----------
    fields : tuple of (red, black) pairs of compact arrays (H+2, W2+2), float32
        The fields one penaliser acts on jointly: (u, v) for the flow (Eq. 5 penalises
        |grad u|^2 + |grad v|^2 together), a single field for each of d and d' (Eq. 6 has
        one penaliser per field). Their halos are overwritten with Neumann ghost values.
    width : int
        Image width W (locates the right-border ghosts).
    eps : float
        Charbonnier epsilon.
    s2 : ndarray (H+2, W2+2), float32
        Scratch space.
    psi : (red, black) compact arrays
        Output: 1 / sqrt(sum |grad f|^2 + eps^2) at the pixels of each colour.
    """
    for f in fields:
        _fill_neumann_ghosts(f[0], f[1], width)
    for c in range(2):
        s2[:] = 0.0
        for f in fields:
            _gradient_sq(f[c], f[1 - c], c, s2)
        _charbonnier_prime(s2, eps, psi[c])


@numba.njit(cache=True, fastmath=True)
def edge_weights(
    psi_own: np.ndarray,
    psi_other: np.ndarray,
    mask: np.ndarray,
    scale: float,
    colour: int,
    coef: np.ndarray,
    plane: int,
) -> None:
    """Write the four edge weights of one colour into ``coef[plane:plane + 4]``.

    Weight = ``scale`` * mean of the two pixels' psi' * edge mask (Neumann borders).
    ``plane`` is :data:`processing.solvers.redblack.W1` or :data:`~processing.solvers.redblack.W2`.
    """
    h = psi_own.shape[0] - 2
    n = psi_own.shape[1] - 2
    e = n + 1
    half = np.float32(0.5 * scale)
    for yc in range(1, h + 1):
        off = (yc - 1 + colour) & 1
        p = psi_own[yc, 1:e]
        pl = psi_other[yc, off:off + n]
        pr = psi_other[yc, off + 1:off + 1 + n]
        pu = psi_other[yc - 1, 1:e]
        pd = psi_other[yc + 1, 1:e]
        ml, mr, mu, md = mask[0, yc, 1:e], mask[1, yc, 1:e], mask[2, yc, 1:e], mask[3, yc, 1:e]
        wl = coef[plane, yc, 1:e]
        wr = coef[plane + 1, yc, 1:e]
        wu = coef[plane + 2, yc, 1:e]
        wd = coef[plane + 3, yc, 1:e]
        for i in range(n):
            wl[i] = half * (p[i] + pl[i]) * ml[i]
            wr[i] = half * (p[i] + pr[i]) * mr[i]
            wu[i] = half * (p[i] + pu[i]) * mu[i]
            wd[i] = half * (p[i] + pd[i]) * md[i]


@numba.njit(cache=True, fastmath=True)
def finish_diagonals(coef: np.ndarray, a11: np.ndarray, a22: np.ndarray) -> None:
    """Store 1 / (A11 + sum w1) and 1 / (A22 + sum w2) in the INV_D planes of ``coef``.

    ``a11``, ``a22`` are compact (H+2, W2+2). A zero diagonal (padding entries, or a
    pixel with neither data nor neighbours) gets 0, which freezes that unknown instead of
    producing inf.
    """
    h = coef.shape[1]
    w = coef.shape[2]
    for y in range(h):
        i1 = coef[INV_D1, y]
        i2 = coef[INV_D2, y]
        b11 = a11[y]
        b22 = a22[y]
        wl1, wr1, wu1, wd1 = coef[W1_LEFT, y], coef[W1_RIGHT, y], coef[W1_UP, y], coef[W1_DOWN, y]
        wl2, wr2, wu2, wd2 = coef[W2_LEFT, y], coef[W2_RIGHT, y], coef[W2_UP, y], coef[W2_DOWN, y]
        for x in range(w):
            d1 = b11[x] + wl1[x] + wr1[x] + wu1[x] + wd1[x]
            d2 = b22[x] + wl2[x] + wr2[x] + wu2[x] + wd2[x]
            i1[x] = np.float32(1.0) / d1 if d1 > 0 else np.float32(0.0)
            i2[x] = np.float32(1.0) / d2 if d2 > 0 else np.float32(0.0)


@numba.njit(cache=True)
def begin_warp(
    full: tuple[np.ndarray, ...],
    ins: np.ndarray,
    x1_full: np.ndarray,
    x2_full: np.ndarray,
    x1: tuple[np.ndarray, np.ndarray],
    x2: tuple[np.ndarray, np.ndarray],
    x1_0: tuple[np.ndarray, np.ndarray],
    x2_0: tuple[np.ndarray, np.ndarray],
) -> None:
    """Split a warp's full-grid inputs and both unknowns into compact form, once per warp.

    ``full[k]`` goes to ``ins[k]`` (red, black); the unknowns to ``x1``, ``x2`` and their
    values at the warp (for the increments of the linearised data terms) to ``x1_0``,
    ``x2_0``.
    """
    for k in range(len(full)):
        redblack.split_field(full[k], ins[k, 0], ins[k, 1])
    redblack.split_field(x1_full, x1[0], x1[1])
    redblack.split_field(x2_full, x2[0], x2[1])
    for c in range(2):
        x1_0[c][:] = x1[c]
        x2_0[c][:] = x2[c]
