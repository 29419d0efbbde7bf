"""Per-pixel kernels of the joint disparity solver (paper Eq. 3a, 3c, 3d and Eq. 6).

Separate from :mod:`processing.stereo.joint` (the solver) so that each module keeps one job:
these kernels evaluate the data terms at the current warp and linearise them, and drop
the terms that sample blanked pixels; the solver drives the warps, the lagged iterations
and the pyramid. Sign convention and
notation as in :mod:`processing.stereo.joint` (``x_R = x_L - d``).
"""

from __future__ import annotations

import numba
import numpy as np

from processing.solvers import derivatives, pyramid


@numba.njit(cache=True, error_model="numpy")
def data_terms(
    e1: np.ndarray,
    e3: np.ndarray,
    e4: np.ndarray,
    g0: np.ndarray,
    g1: np.ndarray,
    m1: np.ndarray,
    m3: np.ndarray,
    m4: np.ndarray,
    d: np.ndarray,
    dp: np.ndarray,
    d0: np.ndarray,
    dp0: np.ndarray,
    eps: float,
    w3: float,
    a11: np.ndarray,
    a12: np.ndarray,
    a22: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
) -> None:
    """Linearised data terms E1, E3, E4 of Eq. 6 with lagged psi' weights, per pixel.

    Around the warp (d0, dp0), with increments dd = d - d0 and ddp = dp - dp0, and
    ``g0`` = dI_R/dx at (x - d0, t0), ``g1`` = dI_R/dx at (x + u - d0 - dp0, y + v, t1)::

        E1 ~ e1 - g0 dd
        E3 ~ e3 + (g0 - g1) dd - g1 ddp
        E4 ~ e4 - g1 dd - g1 ddp

    Each term k with coefficient vector c_k adds psi'_k c_k c_k^T to the 2x2 block and
    psi'_k (c_k . x0 - e_k) c_k to the right-hand side, in the unknown x = (d, d').

    Parameters
    ----------
    e1, e3, e4 : ndarray, shape (H, W), float32
        Data terms evaluated at the warp (d0, dp0).
    g0, g1 : ndarray, shape (H, W), float32
        Horizontal derivatives of the right image at t0 and t1 at the warped positions.
    m1, m3, m4 : ndarray, shape (H, W), float32
        1 where every sample of E1, E3, E4 lies inside its image, else 0 (no data term).
    d, dp : ndarray, shape (H, W), float32
        Current disparity and disparity change (for the lagged weights).
    d0, dp0 : ndarray, shape (H, W), float32
        Disparity and disparity change used for the warp.
    eps : float
        Charbonnier epsilon.
    w3 : float
        Weight of E3 (1 in the paper's Eq. 6; see
        :func:`processing.stereo.joint.joint_disparity`'s ``right_temporal_weight``).
    a11, a12, a22, r1, r2 : ndarray, shape (H, W), float32
        Outputs.
    """
    h, w = e1.shape
    # float32 constants: a float64 scalar would promote each pixel's arithmetic to
    # float64 and halve the SIMD width (see processing.flow.brox).
    e2 = np.float32(eps * eps)
    k3 = np.float32(w3)
    p1 = np.empty(w, np.float32)
    p3 = np.empty(w, np.float32)
    p4 = np.empty(w, np.float32)
    for y in range(h):
        # Row views and two passes (robust weights, then coefficients) keep the inner
        # loops on one index with few pointers, so that LLVM vectorises them.
        re1, re3, re4 = e1[y], e3[y], e4[y]
        rg0, rg1 = g0[y], g1[y]
        rm1, rm3, rm4 = m1[y], m3[y], m4[y]
        rd, rdp, rd0, rdp0 = d[y], dp[y], d0[y], dp0[y]
        for x in range(w):
            dd = rd[x] - rd0[x]
            ddp = rdp[x] - rdp0[x]
            a = rg0[x]
            b = rg1[x]
            l1 = re1[x] - a * dd
            l3 = re3[x] + (a - b) * dd - b * ddp
            l4 = re4[x] - b * (dd + ddp)
            p1[x] = rm1[x] / np.sqrt(l1 * l1 + e2)
            p3[x] = k3 * rm3[x] / np.sqrt(l3 * l3 + e2)
            p4[x] = rm4[x] / np.sqrt(l4 * l4 + e2)
        o11, o12, o22, o1, o2 = a11[y], a12[y], a22[y], r1[y], r2[y]
        for x in range(w):
            a = rg0[x]
            b = rg1[x]
            c = a - b
            q1 = p1[x]
            q3 = p3[x]
            q4 = p4[x]
            bb = b * b
            c11 = q1 * a * a + q3 * c * c + q4 * bb
            c12 = q4 * bb - q3 * c * b
            c22 = (q3 + q4) * bb
            o11[x] = c11
            o12[x] = c12
            o22[x] = c22
            o1[x] = (c11 * rd0[x] + c12 * rdp0[x]
                     - (-q1 * re1[x] * a + q3 * re3[x] * c - q4 * re4[x] * b))
            o2[x] = c12 * rd0[x] + c22 * rdp0[x] + (q3 * re3[x] + q4 * re4[x]) * b


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def split_residuals(
    il0: np.ndarray,
    l0x: np.ndarray,
    il1: np.ndarray,
    ir0: np.ndarray,
    ir1: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    dp: np.ndarray,
    ok_left: np.ndarray,
    ok_right: np.ndarray,
    inputs: np.ndarray,
) -> None:
    """Data terms E1, E3, E4 (Eq. 3) at the current warp, with derivatives and masks,
    written straight into compact red-black form.

    Each pixel samples, with the Catmull-Rom cubic and the exact x-derivative of the
    interpolant (:func:`processing.solvers.derivatives.catmull_rom_dx_at`),
    ``r0`` = I_R(x - d, y, t0), ``r1`` = I_R(x + u - d - d', y + v, t1) and
    ``l1`` = I_L(x + u, y + v, t1). The derivative of each warped right image is averaged
    with that of the image it should match (Brox's symmetric linearisation, as in the
    flow solver). A mask is 1 where every sample of its term lies inside the image and,
    where the depth gate blanked pixels, on a usable pixel
    (:func:`usable_maps`; E1 samples I_L(x) and r0, E3 r0 and r1, E4 r1 and l1).

    Parameters
    ----------
    il0, l0x : ndarray, shape (H, W), float32
        I_L(t0) and its x-derivative.
    il1, ir0, ir1 : ndarray, shape (H + 4, W + 4), float32
        I_L(t1), I_R(t0), I_R(t1), padded for the samplers
        (:func:`processing.solvers.derivatives.pad_for_sampling`).
    u, v : ndarray, shape (H, W), float32
        The left flow (Eq. 5), px.
    d, dp : ndarray, shape (H, W), float32
        Disparity and disparity change of the warp, px.
    ok_left, ok_right : ndarray, float32
        Usable maps (H, W) of the left and right view; empty (0, 0) arrays when nothing
        was blanked.
    inputs : ndarray, shape (N_INPUTS, 2, H+2, W2+2), float32
        Receives, per colour, e1, e3, e4, g0, g1, m1, m3, m4 (:func:`data_terms`).
    """
    h, w = il0.shape
    wm = np.float32(w - 1)
    hm = np.float32(h - 1)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    half = np.float32(0.5)
    blanked = ok_left.size > 0
    for y in range(h):
        fyr = np.float32(y)
        # Column x goes to compact column x // 2 + 1 of colour (x + y) & 1: even columns
        # to one colour's row, odd ones to the other's.
        even = inputs[:, y & 1, y + 1, 1:]
        odd = inputs[:, 1 - (y & 1), y + 1, 1:]
        for x in range(w):
            o = even if (x & 1) == 0 else odd
            j = x >> 1
            fx = np.float32(x) + u[y, x]
            fy = fyr + v[y, x]
            p0 = np.float32(x) - d[y, x]
            p1 = fx - d[y, x] - dp[y, x]
            b1, b1x = derivatives.catmull_rom_dx_at(il1, fx, fy)
            c0, c0x = derivatives.catmull_rom_dx_on_row(ir0, p0, y)
            c1, c1x = derivatives.catmull_rom_dx_at(ir1, p1, fy)
            in_l1 = one if (fx >= zero and fx <= wm and fy >= zero and fy <= hm) else zero
            in0 = one if (p0 >= zero and p0 <= wm) else zero
            in1 = one if (p1 >= zero and p1 <= wm and fy >= zero and fy <= hm) else zero
            m1 = in0
            m3 = in0 * in1
            m4 = in1 * in_l1
            if blanked:
                l0 = ok_left[y, x]
                l1 = pyramid.usable_at(ok_left, fx, fy)
                r0 = pyramid.usable_at(ok_right, p0, fyr)
                r1 = pyramid.usable_at(ok_right, p1, fy)
                m1 *= l0 * r0
                m3 *= r0 * r1
                m4 *= r1 * l1
            a0 = il0[y, x]
            o[0, j] = c0 - a0
            o[1, j] = c1 - c0
            o[2, j] = c1 - b1
            o[3, j] = half * (c0x + l0x[y, x])
            o[4, j] = half * (c1x + b1x)
            o[5, j] = m1
            o[6, j] = m3
            o[7, j] = m4


def usable_maps(blanked: tuple[np.ndarray, np.ndarray], shape: tuple[int, int],
                margin_px: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Float32 (left, right) maps of one pyramid level: 1 where the image carries
    information, 0 on blanked pixels and within ``margin_px`` (level px) of them.

    Blanked pixels (the depth gate's, :mod:`processing.preprocess.depth_gate`) hold a constant "no
    change" in both differential images; their border is a static edge that matches with
    w = 0 and d' = 0, and through the smoothness of d' (gamma2) it pulled the gas's d' -
    nearly constant over the image - towards 0 (measured: -0.02 px for -0.22 px, V_Z 0.1
    for 0.9 m/s). The margin covers the pre-smoothing and the derivative stencils; a
    coarse pixel is unusable when any fine pixel under it is blanked.

    Parameters
    ----------
    blanked : (ndarray, ndarray), shape (H, W), bool
        Blanked pixels of the left and the right view (same for t0 and t1).
    shape : (int, int)
        The level's (rows, cols).
    margin_px : int
        Extra unusable border at the level's resolution, px.
    """
    return (pyramid.usable_map(blanked[0], shape, margin_px),
            pyramid.usable_map(blanked[1], shape, margin_px))
