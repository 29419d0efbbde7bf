"""Variational optical flow after Brox et al. (ECCV 2004), as used by the paper (Eq. 5).

The flow w = (u, v) between two images I0 and I1 minimises

    E_OF(w) = integral psi(|E2|^2) + beta psi(|grad E2|^2) + alpha psi(|grad u|^2 + |grad v|^2)

with E2 = I1(x + w) - I0(x) (brightness constancy, paper Eq. 3b), its spatial gradient
(gradient constancy) and psi(s^2) = sqrt(s^2 + eps^2) (Charbonnier). Numerics follow Brox
et al.: coarse-to-fine warping over a pyramid, and at every level nested fixed-point
iterations - the outer ones re-warp I1 with the current flow, the inner ones freeze
("lag") the non-linear psi' weights and solve the resulting linear system in the flow
increment with red-black SOR (:mod:`processing.solvers.redblack`).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from processing.solvers import derivatives, lagged, pyramid, redblack, variational
from processing.validation import (
    MIN_IMAGE_SIZE,
    as_float_image,
    as_flow_field,
    check_positive,
    check_same_shape,
)


@numba.njit(cache=True, error_model="numpy")
def _compact_data_terms(
    iz: np.ndarray,
    ix: np.ndarray,
    iy: np.ndarray,
    ixz: np.ndarray,
    iyz: np.ndarray,
    ixx: np.ndarray,
    ixy: np.ndarray,
    iyy: np.ndarray,
    valid: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    u0: np.ndarray,
    v0: np.ndarray,
    beta: float,
    eps: float,
    coef: np.ndarray,
    a11: np.ndarray,
    a22: np.ndarray,
) -> None:
    """Linearised data terms of Eq. 5 with lagged psi' weights, one colour, compact layout.

    Linearising E2 around the warp (u0, v0) gives E2 ~ iz + ix du + iy dv and its
    gradient ~ (ixz + ixx du + ixy dv, iyz + ixy du + iyy dv), with (du, dv) = (u - u0,
    v - v0) the current increment. The Euler-Lagrange data part in the unknown (u, v) is
    then the 2x2 block [[a11, a12], [a12, a22]] (u, v)^T = (r1, r2)^T.

    Parameters
    ----------
    iz, ix, iy : ndarray, shape (H+2, W2+2), float32
        Temporal difference I1(x + w0) - I0 and the spatial derivatives.
    ixz, iyz, ixx, ixy, iyy : ndarray, shape (H+2, W2+2), float32
        Temporal differences of the gradient and the second derivatives.
    valid : ndarray, shape (H+2, W2+2), float32
        1 where the warped sample fell inside the image, 0 elsewhere (no data term).
    u, v, u0, v0 : ndarray, shape (H+2, W2+2), float32
        Current flow (for the lagged weights) and the flow used for the warp.
    beta, eps : float
        Gradient-constancy weight and Charbonnier epsilon.
    coef : ndarray, shape (13, H+2, W2+2), float32
        Receives A12, R1, R2 (see :mod:`processing.solvers.redblack`).
    a11, a22 : ndarray, shape (H+2, W2+2), float32
        Receive the data diagonals; :func:`processing.solvers.lagged.finish_diagonals` adds
        the smoothness.
    """
    rows, w = iz.shape
    e2 = np.float32(eps * eps)
    bt = np.float32(beta)
    pd = np.empty(w, np.float32)
    pg = np.empty(w, np.float32)
    for y in range(rows):
        rz, rx, ry = iz[y], ix[y], iy[y]
        rxz, ryz = ixz[y], iyz[y]
        rxx, rxy, ryy = ixx[y], ixy[y], iyy[y]
        rv = valid[y]
        ru, rvv, ru0, rv0 = u[y], v[y], u0[y], v0[y]
        for x in range(w):
            du = ru[x] - ru0[x]
            dv = rvv[x] - rv0[x]
            e = rz[x] + rx[x] * du + ry[x] * dv
            ex = rxz[x] + rxx[x] * du + rxy[x] * dv
            ey = ryz[x] + rxy[x] * du + ryy[x] * dv
            pd[x] = rv[x] / np.sqrt(e * e + e2)
            pg[x] = bt * rv[x] / np.sqrt(ex * ex + ey * ey + e2)
        o11, o22 = a11[y], a22[y]
        o12, o1, o2 = coef[redblack.A12, y], coef[redblack.R1, y], coef[redblack.R2, y]
        for x in range(w):
            gx = rx[x]
            gy = ry[x]
            hxx = rxx[x]
            hxy = rxy[x]
            hyy = ryy[x]
            d = pd[x]
            g = pg[x]
            c11 = d * gx * gx + g * (hxx * hxx + hxy * hxy)
            c12 = d * gx * gy + g * (hxx * hxy + hxy * hyy)
            c22 = d * gy * gy + g * (hxy * hxy + hyy * hyy)
            o11[x] = c11
            o12[x] = c12
            o22[x] = c22
            z = rz[x]
            o1[x] = c11 * ru0[x] + c12 * rv0[x] - (d * gx * z + g * (hxx * rxz[x] + hxy * ryz[x]))
            o2[x] = c12 * ru0[x] + c22 * rv0[x] - (d * gy * z + g * (hxy * rxz[x] + hyy * ryz[x]))


class _FlowTerms(NamedTuple):
    """Parameters of the data terms of Eq. 5 (selects them in the shared lagged loop)."""

    beta: float


@lagged.implement(lagged.data_terms, _FlowTerms)
def _flow_data_terms(terms: _FlowTerms, ws: variational.Workspace, c: int, eps: float) -> None:
    """Data terms of Eq. 5 at the pixels of colour ``c``: :func:`_compact_data_terms` on the
    nine split inputs (iz, ix, iy, ixz, iyz, ixx, ixy, iyy, valid)."""
    ins = ws.inputs
    _compact_data_terms(ins[0, c], ins[1, c], ins[2, c], ins[3, c], ins[4, c], ins[5, c],
                        ins[6, c], ins[7, c], ins[8, c], ws.x1[c], ws.x2[c], ws.x1_0[c],
                        ws.x2_0[c], terms.beta, eps, ws.coefs[c], ws.a11[c], ws.a22[c])


@lagged.implement(lagged.after_solve, _FlowTerms)
def _flow_after_solve(terms: _FlowTerms, ws: variational.Workspace) -> None:
    """Nothing: the flow is the plain lagged solution of Eq. 5."""


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _split_flow_inputs(
    i0: np.ndarray,
    i1w: np.ndarray,
    d0: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    d1: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    u: np.ndarray,
    v: np.ndarray,
    inputs: np.ndarray,
) -> None:
    """The nine data-term inputs of one warp, written straight into compact form.

    Parameters
    ----------
    i0, i1w : ndarray, shape (H, W), float32
        I0 and I1 warped by the current flow, I1(x + w).
    d0, d1 : tuple of 5 ndarray, shape (H, W), float32
        (d/dx, d/dy, d2/dx2, d2/dxdy, d2/dy2) of I0 and of I1(x + w). Averaging each pair
        makes the linearisation symmetric and markedly more accurate (Brox et al.).
    u, v : ndarray, shape (H, W), float32
        The flow of the warp, px (a sample outside the image has no data term).
    inputs : ndarray, shape (N_INPUTS, 2, H+2, W2+2), float32
        Receives, per colour, iz, ix, iy, ixz, iyz, ixx, ixy, iyy and the valid mask
        (:func:`_compact_data_terms`).
    """
    h, w = i0.shape
    half = np.float32(0.5)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    wm = np.float32(w - 1)
    hm = np.float32(h - 1)
    a0x, a0y, a0xx, a0xy, a0yy = d0
    a1x, a1y, a1xx, a1xy, a1yy = d1
    for y in range(h):
        fy = np.float32(y)
        ra, rb = (a0x[y], a0y[y], a0xx[y], a0xy[y], a0yy[y]), (a1x[y], a1y[y], a1xx[y],
                                                               a1xy[y], a1yy[y])
        r0, r1, ru, rv = i0[y], i1w[y], u[y], v[y]
        # Column x of row y has colour (x + y) & 1 and compact column x // 2 + 1: the even
        # columns go to one colour's row, the odd ones to the other's, both contiguous.
        even = inputs[:, y & 1, y + 1, 1:]
        odd = inputs[:, 1 - (y & 1), y + 1, 1:]
        for x in range(w):
            o = even if (x & 1) == 0 else odd
            j = x >> 1
            mx = np.float32(x) + ru[x]
            my = fy + rv[x]
            o[0, j] = r1[x] - r0[x]
            o[1, j] = half * (rb[0][x] + ra[0][x])
            o[2, j] = half * (rb[1][x] + ra[1][x])
            o[3, j] = rb[0][x] - ra[0][x]
            o[4, j] = rb[1][x] - ra[1][x]
            o[5, j] = half * (rb[2][x] + ra[2][x])
            o[6, j] = half * (rb[3][x] + ra[3][x])
            o[7, j] = half * (rb[4][x] + ra[4][x])
            inside = mx >= zero and mx <= wm and my >= zero and my <= hm
            o[8, j] = one if inside else zero


@numba.njit(cache=True, error_model="numpy")
def _drop_blanked_terms(usable: np.ndarray, u: np.ndarray, v: np.ndarray,
                        inputs: np.ndarray) -> None:
    """Drop the data term (the valid plane of ``inputs``, :func:`_split_flow_inputs`) of
    every pixel that is, or whose warped sample x + w lands on (nearest pixel), unusable.

    ``usable`` (H, W) float32: 0 where the depth gate blanked the differential images
    (:func:`processing.solvers.pyramid.usable_map`). A blanked region holds a constant
    "no change" whose border is an edge that is not the gas's: matched, it holds the
    flow beside it (the joint solver drops such terms too).
    """
    h, w = usable.shape
    for y in range(h):
        for x in range(w):
            if usable[y, x] == 0 or pyramid.usable_at(usable, x + u[y, x], y + v[y, x]) == 0:
                inputs[8, (x + y) & 1, y + 1, (x >> 1) + 1] = 0


def _derivatives(image: np.ndarray) -> tuple[np.ndarray, ...]:
    """(d/dx, d/dy, d2/dx2, d2/dxdy, d2/dy2) of ``image`` (H, W) float32, 5-tap stencils."""
    ix, iy = derivatives.dx(image), derivatives.dy(image)
    return ix, iy, derivatives.dx(ix), derivatives.dy(ix), derivatives.dy(iy)


def _level_flow(
    i0: np.ndarray,
    i1: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    *,
    alpha: float,
    beta: float,
    eps: float,
    n_warps: int,
    n_inner: int,
    n_sor: int,
    omega: float,
    usable: np.ndarray | None = None,
) -> None:
    """Refine (u, v) in place at one pyramid level (outer warps x lagged FP x SOR);
    ``usable`` (None: all) drops the data terms on blanked pixels (:func:`_drop_blanked_terms`)."""
    xx, yy = derivatives.pixel_grid(i0.shape)
    d0 = _derivatives(i0)
    ws = variational.workspace(i0.shape)
    for _ in range(n_warps):
        # Derivatives of the warped frame (one remap instead of six).
        i1w = derivatives.warp(i1, xx + u, yy + v)
        _split_flow_inputs(i0, i1w, d0, _derivatives(i1w), u, v, ws.inputs)
        if usable is not None:
            _drop_blanked_terms(usable, u, v, ws.inputs)
        # One penaliser for both components: Eq. 5 penalises |grad u|^2 + |grad v|^2 jointly.
        lagged.lagged_iterations(_FlowTerms(beta), u, v, ws, (alpha, alpha), True, eps,
                                 n_inner, n_sor, omega)


def brox_optical_flow(
    image0: np.ndarray,
    image1: np.ndarray,
    *,
    alpha: float = 0.05,
    beta: float = 0.1,
    eps: float = 0.001,
    pyramid_factor: float = 0.75,
    min_level_size: int = 12,
    n_warps: int = 1,
    n_inner: int = 4,
    n_sor: int = 12,
    omega: float = 1.99,
    presmooth_sigma: float = 0.6,
    initial_flow: np.ndarray | None = None,
    n_levels: int | None = None,
    pyramid_cache: variational.PyramidCache | None = None,
    blanked: np.ndarray | None = None,
) -> np.ndarray:
    """Optical flow from ``image0`` to ``image1`` by minimising the paper's Eq. 5.

    Parameters
    ----------
    image0, image1 : ndarray, shape (H, W), floating point
        The two frames (I(t0) and I(t1)), intensities scaled to [0, 1]: alpha and beta are
        calibrated for that range (the Charbonnier data term scales with it). H, W >= 8.
    alpha : float
        Smoothness weight (paper: 0.05).
    beta : float
        Gradient-constancy weight (paper: 0.1).
    eps : float
        Charbonnier epsilon of psi(s^2) = sqrt(s^2 + eps^2) (paper: 0.001).
    pyramid_factor : float
        Down-sampling factor between pyramid levels, in (0, 1).
    min_level_size : int
        The coarsest level keeps min(H, W) >= this (px).
    n_warps : int
        Outer fixed-point iterations (re-warps) per level.
    n_inner : int
        Inner fixed-point iterations per warp (lagged psi' weights).
    n_sor : int
        Red-black SOR iterations per inner iteration.
    omega : float
        SOR relaxation factor in (0, 2). The smoothness-dominated system converges slowly
        for moderate factors: on Middlebury, 1.99 with 4 x 12 iterations comes within
        ~0.03 px AEE of the fully converged solution, 1.8 stays ~0.2 px away. (5 x 10
        gained 0.004-0.009 px AEE for 4 % more time.)
    presmooth_sigma : float
        Gaussian pre-smoothing of both images in px (0 disables).
    initial_flow : ndarray, shape (H, W, 2), optional
        Initial flow in px (e.g. the previous frame's result for a warm start). It is
        resampled to the coarsest level used and refined from there.
    n_levels : int, optional
        Use only the finest ``n_levels`` pyramid levels (default: all down to
        ``min_level_size``). A warm start from the previous frame's flow is already close
        and needs no coarse levels.
    pyramid_cache : PyramidCache, optional
        Shares the images' pyramids with other solver calls on the same image objects
        (:class:`processing.solvers.variational.PyramidCache`).
    blanked : ndarray, shape (H, W), bool, optional
        Pixels the gates set to "no change" in both images: no data term on them,
        nor where a pixel's warped sample lands on them (the smoothness fills them in).

    Returns
    -------
    ndarray, shape (H, W, 2), float32
        Flow in px: [..., 0] = u (along x, to the right), [..., 1] = v (along y, down), so
        that image1(x + u, y + v) ~ image0(x, y).

    Raises
    ------
    ValueError
        Non-2-D, integer, mismatched, too small or non-finite images; invalid parameters.

    References
    ----------
    T. Brox, A. Bruhn, N. Papenberg, J. Weickert, "High accuracy optical flow estimation
    based on a theory for warping", ECCV 2004; Rangel et al., WACV 2020, Eq. 5.
    """
    i0 = as_float_image(image0, "image0", min_size=MIN_IMAGE_SIZE)
    i1 = as_float_image(image1, "image1", min_size=MIN_IMAGE_SIZE)
    check_same_shape(i0, i1, "image0", "image1")
    check_positive(alpha, "alpha")
    check_positive(beta, "beta", allow_zero=True)
    variational.check_options(eps=eps, pyramid_factor=pyramid_factor, omega=omega,
                              presmooth_sigma=presmooth_sigma, n_levels=n_levels,
                              n_warps=n_warps, n_inner=n_inner, n_sor=n_sor,
                              min_level_size=min_level_size)
    init = None if initial_flow is None else as_flow_field(initial_flow, i0.shape, "initial_flow")
    if blanked is not None and np.shape(blanked) != i0.shape:
        raise ValueError(f"blanked must have the images' shape {i0.shape}, "
                         f"got {np.shape(blanked)}")
    shapes, (p0, p1) = variational.build_pyramids(
        (i0, i1), pyramid_factor=pyramid_factor, min_level_size=min_level_size,
        presmooth_sigma=presmooth_sigma, n_levels=n_levels, cache=pyramid_cache)
    flow = np.zeros((*shapes[-1], 2), np.float32) if init is None else init

    def solve_level(level: int, fields: variational.Fields) -> variational.Fields:
        u = np.ascontiguousarray(fields[0][..., 0])
        v = np.ascontiguousarray(fields[0][..., 1])
        usable = None if blanked is None else pyramid.usable_map(blanked, shapes[level])
        _level_flow(p0[level], p1[level], u, v, alpha=alpha, beta=beta, eps=eps,
                    n_warps=n_warps, n_inner=n_inner, n_sor=n_sor, omega=omega, usable=usable)
        return (np.stack([u, v], axis=-1),)

    return variational.coarse_to_fine(shapes, (flow,), solve_level)[0]
