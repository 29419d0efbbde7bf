"""Per-pixel kernels of the joint disparity solver (paper Eq. 3a, 3c, 3d and Eq. 6).

Separate from :mod:`processing.stereo.joint` (the solver) so that each module keeps one job:
these kernels evaluate the data terms at the current warp and linearise them, and drop
the terms that sample blanked pixels; the solver drives the warps, the lagged iterations
and the pyramid. Sign convention and
notation as in :mod:`processing.stereo.joint` (``x_R = x_L - d``).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np


@numba.njit(cache=True, fastmath=True)
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


@numba.njit(cache=True, fastmath=True)
def warp_residuals(
    il0: np.ndarray,
    l0x: np.ndarray,
    l1w: np.ndarray,
    l1wx: np.ndarray,
    m_l1: np.ndarray,
    r0w: np.ndarray,
    r0wx: np.ndarray,
    r1w: np.ndarray,
    r1wx: np.ndarray,
    mx0: np.ndarray,
    mx1: np.ndarray,
    my1: np.ndarray,
    e1: np.ndarray,
    e3: np.ndarray,
    e4: np.ndarray,
    g0: np.ndarray,
    g1: np.ndarray,
    m1: np.ndarray,
    m3: np.ndarray,
    m4: np.ndarray,
) -> None:
    """Data terms E1, E3, E4 (Eq. 3) at the current warp, derivatives and masks, per pixel.

    Inputs are the warped images (``r0w`` = I_R(x - d, t0), ``r1w`` = I_R(x + u - d - d',
    y + v, t1), ``l1w`` = I_L(x + w, t1)) with their x-derivatives, the sample positions
    and ``m_l1`` (1 where x + w is inside). The derivative of each warped right image is
    averaged with that of the image it should match (Brox's symmetric linearisation, as
    in the flow solver). A mask is 1 where every sample of that term lies inside.
    """
    h, w = il0.shape
    wm = np.float32(w - 1)
    hm = np.float32(h - 1)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    half = np.float32(0.5)
    for y in range(h):
        a0, a0x, b1, b1x, ml = il0[y], l0x[y], l1w[y], l1wx[y], m_l1[y]
        c0, c0x, c1, c1x = r0w[y], r0wx[y], r1w[y], r1wx[y]
        p0, p1, q1 = mx0[y], mx1[y], my1[y]
        o1, o3, o4, og0, og1 = e1[y], e3[y], e4[y], g0[y], g1[y]
        om1, om3, om4 = m1[y], m3[y], m4[y]
        for x in range(w):
            in0 = one if (p0[x] >= zero and p0[x] <= wm) else zero
            in1 = one if (p1[x] >= zero and p1[x] <= wm and q1[x] >= zero
                          and q1[x] <= hm) else zero
            o1[x] = c0[x] - a0[x]
            o3[x] = c1[x] - c0[x]
            o4[x] = c1[x] - b1[x]
            og0[x] = half * (c0x[x] + a0x[x])
            og1[x] = half * (c1x[x] + b1x[x])
            om1[x] = in0
            om3[x] = in0 * in1
            om4[x] = in1 * ml[x]


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
    k = 2 * margin_px + 1
    kernel = np.ones((k, k), np.uint8)
    out = []
    for b in blanked:
        frac = cv2.resize(b.astype(np.float32), (shape[1], shape[0]),
                          interpolation=cv2.INTER_AREA)
        bad = cv2.dilate((frac > 1e-3).astype(np.uint8), kernel)
        out.append(np.ascontiguousarray(1.0 - bad, dtype=np.float32))
    return out[0], out[1]


def _sample_nearest(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``a`` at the rounded positions (x, y), clamped to the image (outside is masked by
    the inside tests of the data terms anyway)."""
    h, w = a.shape
    xi = np.clip(np.rint(x), 0, w - 1).astype(np.intp)
    yi = np.clip(np.rint(y), 0, h - 1).astype(np.intp)
    return a[yi, xi]


def drop_blanked_terms(usable: tuple[np.ndarray, np.ndarray], rows: np.ndarray,
                       flow_pos: tuple[np.ndarray, np.ndarray], mx0: np.ndarray,
                       mx1: np.ndarray, masks: tuple[np.ndarray, np.ndarray, np.ndarray]
                       ) -> None:
    """Zero the data-term masks (m1, m3, m4) in place where a term samples a blanked pixel.

    ``rows``: the y coordinate of every pixel, (H, W); ``flow_pos``: x + w; ``mx0``,
    ``mx1``: the right images' sample columns at t0 and t1 (all px, this level).

    E1 samples I_L(x) and I_R(x - d); E3 I_R(x - d) and I_R(x + w - d - d'); E4 the latter
    and I_L(x + w) (Eq. 3a, c, d). Positions are those of the current warp.
    """
    ok_l, ok_r = usable
    fx, fy = flow_pos
    l0 = ok_l
    l1 = _sample_nearest(ok_l, fx, fy)
    r0 = _sample_nearest(ok_r, mx0, rows)
    r1 = _sample_nearest(ok_r, mx1, fy)
    m1, m3, m4 = masks
    m1 *= l0 * r0
    m3 *= r0 * r1
    m4 *= r1 * l1
