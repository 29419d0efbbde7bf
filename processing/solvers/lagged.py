"""Lagged-diffusivity building blocks of both variational solvers, in compact red-black form.

At each lagged fixed-point iteration (Brox et al. 2004) the flow solver (paper Eq. 5) and
the joint disparity solver (Eq. 6) freeze the Charbonnier weights psi'(|grad f|^2) of their
smoothness terms and turn them into edge weights of the linear system that
:mod:`processing.solvers.redblack` solves. Assembling a system on the full grid and scattering it
into the compact layout costs about as much as ten SOR iterations (stride-2 scatter of 13
planes), so the solvers keep their unknowns and inputs compact for a
whole warp and compute psi', edge weights and diagonals per colour here, with contiguous,
vectorisable row loops. :func:`lagged_iterations` is the inner loop of one warp for both
solvers; each brings its own data terms (:func:`data_terms`, :func:`after_solve`).

No kernel compiled into :func:`lagged_iterations` (these, the SOR sweeps, both solvers'
data terms) uses ``fastmath``: compiled fresh together with the skeleton it gave other
rounding than the same kernels loaded from numba's cache, so the first run after a code
change read other numbers than every later one (docs/design.md,
tests/test_compile_determinism.py).
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numba.core import types
from numba.extending import overload

from processing.solvers import redblack
from processing.solvers.redblack import (
    INV_D1,
    INV_D2,
    W1_DOWN,
    W1_LEFT,
    W1_RIGHT,
    W1_UP,
)

#: The level's :class:`processing.solvers.variational.Workspace` (a NamedTuple of compact
#: arrays; that module builds on this one, hence no import).
Workspace = tuple


@numba.njit(cache=True, error_model="numpy")
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


@numba.njit(cache=True, error_model="numpy")
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


@numba.njit(cache=True, error_model="numpy")
def _charbonnier_prime(s2: np.ndarray, eps: float, out: np.ndarray) -> None:
    """out = 1 / sqrt(s2 + eps^2) elementwise on compact arrays (lagged psi')."""
    e2 = np.float32(eps * eps)
    h, w = s2.shape
    for y in range(h):
        a = s2[y]
        o = out[y]
        for x in range(w):
            o[x] = np.float32(1.0) / np.sqrt(a[x] + e2)


@numba.njit(cache=True, error_model="numpy")
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


@numba.njit(cache=True, error_model="numpy")
def edge_weights(
    psi_own: np.ndarray,
    psi_other: np.ndarray,
    width: int,
    scale: float,
    colour: int,
    coef: np.ndarray,
    plane: int,
) -> None:
    """Write the four edge weights of one colour into ``coef[plane:plane + 4]``.

    Weight = ``scale`` * mean of the two pixels' psi', and 0 for an edge that leaves the
    image (Neumann borders) and at padding entries (odd W), which keeps those decoupled.
    ``width`` is the image width W; ``plane`` is :data:`processing.solvers.redblack.W1` or
    :data:`~processing.solvers.redblack.W2`.
    """
    h = psi_own.shape[0] - 2
    n = psi_own.shape[1] - 2
    e = n + 1
    half = np.float32(0.5 * scale)
    zero = np.float32(0.0)
    for yc in range(1, h + 1):
        y = yc - 1
        # The row's column parity: its first pixel's x, and where its left neighbours sit.
        off = (y + colour) & 1
        count = redblack.row_pixels(colour, y, width)
        up = np.float32(1.0) if y > 0 else zero
        down = np.float32(1.0) if y < h - 1 else zero
        p = psi_own[yc, 1:e]
        pl = psi_other[yc, off:off + n]
        pr = psi_other[yc, off + 1:off + 1 + n]
        pu = psi_other[yc - 1, 1:e]
        pd = psi_other[yc + 1, 1:e]
        wl = coef[plane, yc, 1:e]
        wr = coef[plane + 1, yc, 1:e]
        wu = coef[plane + 2, yc, 1:e]
        wd = coef[plane + 3, yc, 1:e]
        for i in range(count):
            wl[i] = half * (p[i] + pl[i])
            wr[i] = half * (p[i] + pr[i])
            wu[i] = half * (p[i] + pu[i]) * up
            wd[i] = half * (p[i] + pd[i]) * down
        if off == 0:
            wl[0] = zero  # x = 0 has no left neighbour
        if off + 2 * (count - 1) == width - 1:
            wr[count - 1] = zero  # x = W - 1 has no right neighbour
        for i in range(count, n):
            wl[i] = zero
            wr[i] = zero
            wu[i] = zero
            wd[i] = zero


@numba.njit(cache=True, error_model="numpy")
def finish_diagonals(coef: np.ndarray, a11: np.ndarray, a22: np.ndarray, w2: int) -> None:
    """Store 1 / (A11 + sum w1) and 1 / (A22 + sum w2) in the INV_D planes of ``coef``.

    ``a11``, ``a22`` are compact (H+2, W2+2); ``w2`` is the first edge-weight plane of
    unknown 2 (:data:`processing.solvers.redblack.W2`, or ``W1`` for a joint penaliser). A
    zero diagonal (padding entries, or a pixel with neither data nor neighbours) gets 0,
    which freezes that unknown instead of producing inf.
    """
    h = coef.shape[1]
    w = coef.shape[2]
    for y in range(h):
        i1 = coef[INV_D1, y]
        i2 = coef[INV_D2, y]
        b11 = a11[y]
        b22 = a22[y]
        wl1, wr1, wu1, wd1 = coef[W1_LEFT, y], coef[W1_RIGHT, y], coef[W1_UP, y], coef[W1_DOWN, y]
        wl2, wr2, wu2, wd2 = coef[w2, y], coef[w2 + 1, y], coef[w2 + 2, y], coef[w2 + 3, y]
        for x in range(w):
            d1 = b11[x] + wl1[x] + wr1[x] + wu1[x] + wd1[x]
            d2 = b22[x] + wl2[x] + wr2[x] + wu2[x] + wd2[x]
            i1[x] = np.float32(1.0) / d1 if d1 > 0 else np.float32(0.0)
            i2[x] = np.float32(1.0) / d2 if d2 > 0 else np.float32(0.0)


@numba.njit(cache=True, error_model="numpy")
def begin_warp(x1_full: np.ndarray, x2_full: np.ndarray, ws: Workspace) -> None:
    """Split both unknowns into compact form, once per warp.

    The unknowns go to ``ws.x1``, ``ws.x2`` and their values at the warp (for the
    increments of the linearised data terms) to ``ws.x1_0``, ``ws.x2_0``. The data-term
    inputs are written in compact form by each solver's own kernel: pixel (y, x) is
    entry (y + 1, x // 2 + 1) of colour (x + y) & 1.
    """
    redblack.split_field(x1_full, ws.x1[0], ws.x1[1])
    redblack.split_field(x2_full, ws.x2[0], ws.x2[1])
    for c in range(2):
        _copy(ws.x1[c], ws.x1_0[c])
        _copy(ws.x2[c], ws.x2_0[c])


@numba.njit(cache=True, error_model="numpy")
def _copy(src: np.ndarray, dst: np.ndarray) -> None:
    """dst[:] = src for two C-contiguous arrays of one shape (numba's 2-D slice assignment
    took 40 us for a 242 x 162 array, this 2 us)."""
    s = src.ravel()
    d = dst.ravel()
    for i in range(s.shape[0]):
        d[i] = s[i]


# The two problem-specific steps of :func:`lagged_iterations`. Each solver implements them
# for the type of its ``terms`` (a NamedTuple of its data-term parameters, :func:`implement`)
# and numba picks the implementation when it compiles the skeleton for that type. Not a
# kernel argument or a closure over one: numba keys the on-disk cache of such a function by
# the kernel object, which is new in every process, so the skeleton compiled again at every
# start (measured with numba 0.68: a cache miss and a new cache file per process).


def data_terms(terms: tuple, ws: Workspace, colour: int, eps: float) -> None:
    """Linearised data terms at the pixels of ``colour``, with lagged psi' weights.

    Reads ``ws.inputs[:, colour]``, the unknowns ``ws.x1``, ``ws.x2`` and their values at
    the warp ``ws.x1_0``, ``ws.x2_0``; writes the data diagonals ``ws.a11[colour]``,
    ``ws.a22[colour]`` and the planes A12, R1, R2 of ``ws.coefs[colour]``
    (:mod:`processing.solvers.redblack`). Compiled code only; see :func:`implement`.
    """
    raise TypeError(f"data_terms of {type(terms).__name__} run in compiled code only")


def after_solve(terms: tuple, ws: Workspace) -> None:
    """A problem's own update of ``ws.x1``, ``ws.x2`` after each SOR solve (or none).

    Compiled code only; see :func:`implement`.
    """
    raise TypeError(f"after_solve of {type(terms).__name__} runs in compiled code only")


def implement(hook: Callable[..., None], terms_type: type) -> Callable[[Callable], Callable]:
    """Decorator: the decorated function is ``hook`` for terms of type ``terms_type``.

    ``hook`` is :func:`data_terms` or :func:`after_solve`; the decorated function has the
    hook's parameters and is compiled by numba where :func:`lagged_iterations` calls it.
    """
    def register(impl: Callable) -> Callable:
        def select(terms: types.Type, *args: types.Type) -> Callable | None:
            if isinstance(terms, types.BaseNamedTuple) and terms.instance_class is terms_type:
                return impl
            return None

        overload(hook, strict=False)(select)
        return impl

    return register


@numba.njit(cache=True, error_model="numpy")
def lagged_iterations(
    terms: tuple,
    x1_full: np.ndarray,
    x2_full: np.ndarray,
    ws: Workspace,
    weights: tuple[float, float],
    joint: bool,
    eps: float,
    n_inner: int,
    n_sor: int,
    omega: float,
) -> None:
    """Inner fixed-point iterations of one warp: lag psi', solve by SOR; x1, x2 in place.

    Everything stays in compact red-black layout for the whole warp: the caller has
    written the data-term inputs into ``ws.inputs`` (compact, per colour), psi', edge
    weights and data terms are computed per colour, and the unknowns are merged back only
    at the end.

    Parameters
    ----------
    terms : NamedTuple
        The problem's data-term parameters; its type selects the :func:`data_terms` and
        :func:`after_solve` of that problem.
    x1_full, x2_full : ndarray, shape (H, W), float32
        The two unknowns, refined in place.
    ws : Workspace
        The level's compact arrays (:class:`processing.solvers.variational.Workspace`).
    weights : (float, float)
        Smoothness weights of the two unknowns (alpha, alpha for Eq. 5; gamma1, gamma2
        for Eq. 6).
    joint : bool
        True: one penaliser psi(|grad x1|^2 + |grad x2|^2) for both unknowns (Eq. 5);
        False: one per unknown, psi(|grad x1|^2) and psi(|grad x2|^2) (Eq. 6).
    eps : float
        Charbonnier epsilon.
    n_inner, n_sor : int
        Lagged fixed-point iterations, SOR iterations per fixed-point iteration.
    omega : float
        SOR relaxation factor in (0, 2).
    """
    w = x1_full.shape[1]
    begin_warp(x1_full, x2_full, ws)
    for _ in range(n_inner):
        if joint:
            lagged_psi((ws.x1, ws.x2), w, eps, ws.s2, ws.psi1)
        else:
            lagged_psi((ws.x1,), w, eps, ws.s2, ws.psi1)
            lagged_psi((ws.x2,), w, eps, ws.s2, ws.psi2)
        for c in range(2):
            coef = ws.coefs[c]
            edge_weights(ws.psi1[c], ws.psi1[1 - c], w, weights[0], c, coef,
                         redblack.W1)
            if not joint:  # a joint penaliser's unknowns share the W1 planes
                edge_weights(ws.psi2[c], ws.psi2[1 - c], w, weights[1], c, coef,
                             redblack.W2)
            data_terms(terms, ws, c, eps)
            finish_diagonals(coef, ws.a11[c], ws.a22[c], redblack.W1 if joint else redblack.W2)
        redblack.solve_sor(ws.coefs[0], ws.coefs[1], ws.x1[0], ws.x1[1], ws.x2[0], ws.x2[1],
                           n_sor, omega, joint)
        after_solve(terms, ws)
    redblack.merge_field(ws.x1[0], ws.x1[1], x1_full)
    redblack.merge_field(ws.x2[0], ws.x2[1], x2_full)
