"""Joint disparity and disparity change given the optical flow (paper Sec. 4.3, Eq. 6).

With the left optical flow w = (u, v) between t0 and t1 already known (Eq. 5), the
disparity d and the disparity change d' of the left view minimise

    E_SF(d, d') = integral gamma1 psi(|grad d|^2) + gamma2 psi(|grad d'|^2)
                           + psi(|E1|^2) + psi(|E3|^2) + psi(|E4|^2)

with psi(s^2) = sqrt(s^2 + eps^2) and the data terms of Eq. 3a, 3c, 3d.

Sign convention (rectified pair, right camera at +b along the X axis): a point seen at
x in the left image is seen at ``x_R = x - d`` in the right image, so d = s b / Z > 0 for
a point in front of the cameras and Eq. 4 applies exactly as printed. The paper writes
``x_R = x_L + p_L`` with p_L = (d_L, 0); our d is the same quantity with the usual
positive sign (Middlebury: "x_right = x_left - d"; OpenCV StereoSGBM returns it too).
The data terms then read, at the left pixel x = (x, y):

    E1 = I_R(x - d, y, t0) - I_L(x, y, t0)                         (Eq. 3a)
    E3 = I_R(x + u - d - d', y + v, t1) - I_R(x - d, y, t0)        (Eq. 3c)
    E4 = I_R(x + u - d - d', y + v, t1) - I_L(x + u, y + v, t1)    (Eq. 3d)

Numerics are those of the flow solver (:mod:`processing.optical_flow`) and share its
building blocks: a coarse-to-fine pyramid (:mod:`processing.pyramid`) on which d, d' and w
are resampled with disparities scaled by the width ratio; at each level, outer warps
re-sample the right images at the current disparities; inner fixed-point iterations
freeze ("lag") the psi' weights, and the linear system in (d, d') - a 2x2 block per pixel
plus two diffusion terms with their own weights gamma1 psi'_d and gamma2 psi'_d' - is
solved with the compact red-black SOR of :mod:`processing.redblack`. Unlike the flow, the
images are sampled with a Catmull-Rom cubic (:func:`processing.derivatives.
warp_dx_catmull_rom`): OpenCV's cubic biases fractional shifts by up to 0.04 px, which would
go straight into d' and hence into V_Z (Eq. 4).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from processing import derivatives, pyramid, redblack
from processing.validation import (
    MIN_IMAGE_SIZE,
    as_float_image,
    as_flow_field,
    check_positive,
    check_same_shape,
)


@numba.njit(cache=True, fastmath=True)
def disparity_data_terms(
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
    a11, a12, a22, r1, r2 : ndarray, shape (H, W), float32
        Outputs.
    """
    h, w = e1.shape
    # float32 constants: a float64 scalar would promote each pixel's arithmetic to
    # float64 and halve the SIMD width (see processing.optical_flow).
    e2 = np.float32(eps * eps)
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
            p3[x] = rm3[x] / np.sqrt(l3 * l3 + e2)
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


@numba.njit(cache=True)
def _lagged_iterations(
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
    gamma1: float,
    gamma2: float,
    eps: float,
    n_inner: int,
    n_sor: int,
    omega: float,
) -> None:
    """Inner fixed-point iterations of one warp: lag psi', solve by SOR; (d, dp) in place.

    As for the flow (:func:`processing.optical_flow._lagged_iterations`), everything stays
    in compact red-black layout for the whole warp: the per-pixel inputs are split once,
    psi', edge weights and data terms are computed per colour (the data-term kernel is
    purely per pixel, so it runs on compact arrays unchanged), and the unknowns are merged
    back only at the end. This avoids scattering 13 full-grid planes every iteration.
    """
    h, w = d.shape
    ins = [redblack.split_new(a) for a in (e1, e3, e4, g0, g1, m1, m3, m4)]
    dr, db = redblack.split_new(d)
    pr, pb = redblack.split_new(dp)
    d0 = (dr.copy(), db.copy())
    dp0 = (pr.copy(), pb.copy())
    ds = (dr, db)
    ps = (pr, pb)
    masks = redblack.border_masks(h, w)
    coefs = redblack.empty_system(h, w)
    cshape = dr.shape
    a11 = (np.zeros(cshape, np.float32), np.zeros(cshape, np.float32))
    a22 = (np.zeros(cshape, np.float32), np.zeros(cshape, np.float32))
    s2 = np.zeros(cshape, np.float32)
    psi_d = (np.zeros(cshape, np.float32), np.zeros(cshape, np.float32))
    psi_p = (np.zeros(cshape, np.float32), np.zeros(cshape, np.float32))
    for _ in range(n_inner):
        # Eq. 6 has one penaliser per field: psi(|grad d|^2) and psi(|grad d'|^2), each
        # with its own weight, so the two unknowns diffuse with different edge weights.
        redblack.lagged_psi((ds,), w, eps, s2, psi_d)
        redblack.lagged_psi((ps,), w, eps, s2, psi_p)
        for c in range(2):
            coef = coefs[c]
            redblack.compact_edge_weights(psi_d[c], psi_d[1 - c], masks[c], gamma1, c, coef,
                                          redblack.W1)
            redblack.compact_edge_weights(psi_p[c], psi_p[1 - c], masks[c], gamma2, c, coef,
                                          redblack.W2)
            disparity_data_terms(ins[0][c], ins[1][c], ins[2][c], ins[3][c], ins[4][c],
                                 ins[5][c], ins[6][c], ins[7][c], ds[c], ps[c], d0[c], dp0[c],
                                 eps, a11[c], coef[redblack.A12], a22[c], coef[redblack.R1],
                                 coef[redblack.R2])
            redblack.finish_diagonals(coef, a11[c], a22[c])
        redblack.solve_sor(coefs[0], coefs[1], dr, db, pr, pb, n_sor, omega)
    redblack.merge_field(dr, db, d)
    redblack.merge_field(pr, pb, dp)


def _level_disparity(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    dp: np.ndarray,
    *,
    gamma1: float,
    gamma2: float,
    eps: float,
    n_warps: int,
    n_inner: int,
    n_sor: int,
    omega: float,
) -> None:
    """Refine (d, dp) in place at one pyramid level (outer warps x lagged FP x SOR)."""
    xx, yy = derivatives.pixel_grid(il0.shape)
    l0x = derivatives.dx(il0)
    # Catmull-Rom warps (not OpenCV's a = -0.75 cubic, whose phase-dependent bias would
    # show up directly in d'), each with the exact x-derivative of the interpolant.
    warp_dx = derivatives.warp_dx_catmull_rom
    # The flow is fixed: I_L(x + w, t1) and its derivative are warped once per level.
    fx, fy = xx + u, yy + v
    l1w, l1wx = warp_dx(il1, fx, fy)
    m_l1 = derivatives.inside_mask(fx, fy)
    e1, e3, e4, g0, g1, m1, m3, m4 = (np.empty(il0.shape, np.float32) for _ in range(8))
    for _ in range(n_warps):
        mx0 = xx - d
        mx1 = fx - d - dp
        r0w, r0wx = warp_dx(ir0, mx0, yy)
        r1w, r1wx = warp_dx(ir1, mx1, fy)
        warp_residuals(il0, l0x, l1w, l1wx, m_l1, r0w, r0wx, r1w, r1wx, mx0, mx1, fy,
                       e1, e3, e4, g0, g1, m1, m3, m4)
        _lagged_iterations(e1, e3, e4, g0, g1, m1, m3, m4, d, dp,
                           gamma1, gamma2, eps, n_inner, n_sor, omega)


def _check_int(name: str, n: int) -> None:
    if int(n) != n or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")


def joint_disparity(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    flow: np.ndarray,
    *,
    gamma1: float = 0.05,
    gamma2: float = 0.5,
    eps: float = 0.001,
    d0: float = 0.0,
    initial_disparity: np.ndarray | None = None,
    pyramid_factor: float = 0.75,
    min_level_size: int = 12,
    n_warps: int = 2,
    n_inner: int = 3,
    n_warps_finest: int = 1,
    n_inner_finest: int = 4,
    n_sor: int = 10,
    omega: float = 1.95,
    presmooth_sigma: float = 0.6,
) -> tuple[np.ndarray, np.ndarray]:
    """Disparity d_L and disparity change d'_L of the left view by minimising Eq. 6.

    Parameters
    ----------
    il0, ir0, il1, ir1 : ndarray, shape (H, W), floating point
        Rectified differential images I_L(t0), I_R(t0), I_L(t1), I_R(t1), intensities in
        [0, 1] (gamma1, gamma2 are calibrated for that range). H, W >= 8.
    flow : ndarray, shape (H, W, 2), floating point
        Left optical flow w_L = (u, v) in px from t0 to t1 (Eq. 5,
        :func:`processing.optical_flow.brox_optical_flow`): I_L(x + w, t1) ~ I_L(x, t0).
    gamma1, gamma2 : float
        Smoothness weights of d and d' (paper: 0.05, 0.5).
    eps : float
        Charbonnier epsilon of psi(s^2) = sqrt(s^2 + eps^2) (paper: 0.001).
    d0 : float
        Minimum disparity in px used as the constant initial disparity (paper Sec. 4.3),
        scaled to every pyramid level. Ignored when ``initial_disparity`` is given.
    initial_disparity : ndarray, shape (H, W), optional
        Initial disparity field in px (e.g. an SGM estimate with its holes filled). It is
        resampled to the coarsest level and refined from there.
    pyramid_factor : float
        Down-sampling factor between pyramid levels, in (0, 1).
    min_level_size : int
        The coarsest level keeps min(H, W) >= this (px).
    n_warps : int
        Outer fixed-point iterations (re-warps of the right images) per level, except the
        finest.
    n_inner : int
        Inner fixed-point iterations per warp (lagged psi' weights), except at the finest
        level. The coarse levels make the large corrections (the whole d - d0 and d'),
        and one linearisation per level was not enough there: on a textured plane
        receding at 1.5 m/s, started 22 px short (d0 = 60 px), 1 x 5 iterations per level
        left a d' bias of 0.24 px, 2 x 3 left 0.02 px.
    n_warps_finest, n_inner_finest : int
        The same at the finest level, where only a fraction of a pixel remains: 1 x 4
        instead of 2 x 3 raised the d' bias in that case from 0.022 to 0.028 px (<= 0.009
        px on 9 other moving planes) and saves about a fifth of the run time.
    n_sor : int
        Red-black SOR iterations per inner iteration.
    omega : float
        SOR relaxation factor in (0, 2). Higher than the flow solver's 1.8: the lagged
        smoothness weights gamma psi' reach gamma / eps (500 for d' at the paper's
        values) where a field is flat, which makes the system stiff and its smooth error
        modes slow; the optimal SOR factor of such a Laplacian-dominated system is close
        to 2 (1.95 cut the d' bias on a moving textured plane from 0.43 px to 0.02 px at
        equal cost).
    presmooth_sigma : float
        Gaussian pre-smoothing of the four images in px (0 disables).

    Returns
    -------
    d : ndarray, shape (H, W), float32
        Disparity in px at t0: the point seen at x in the left image is seen at
        ``x - d`` in the right image (d > 0 in front of the cameras, Eq. 4).
    d_change : ndarray, shape (H, W), float32
        Disparity change d' in px from t0 to t1 along the flow: the disparity of the same
        point at t1 (seen at x + w in the left image) is d + d'.

    Raises
    ------
    ValueError
        Non-2-D, integer, mismatched, too small or non-finite images or flow; invalid
        parameters.

    References
    ----------
    J. Rangel, R. Schmoll, A. Kroll, "On scene flow computation of gas structures with
    optical gas imaging cameras", WACV 2020, Eq. 3, 6.
    """
    images = [
        as_float_image(a, n, min_size=MIN_IMAGE_SIZE)
        for a, n in ((il0, "il0"), (ir0, "ir0"), (il1, "il1"), (ir1, "ir1"))
    ]
    for img, name in zip(images[1:], ("ir0", "il1", "ir1"), strict=True):
        check_same_shape(images[0], img, "il0", name)
    shape = images[0].shape
    w_full = as_flow_field(flow, shape, "flow")
    check_positive(gamma1, "gamma1")
    check_positive(gamma2, "gamma2")
    check_positive(eps, "eps")
    check_positive(presmooth_sigma, "presmooth_sigma", allow_zero=True)
    if not np.isfinite(float(d0)):
        raise ValueError(f"d0 must be a finite number of pixels, got {d0!r}")
    if not 0.0 < pyramid_factor < 1.0:
        raise ValueError(f"pyramid_factor must be in (0, 1), got {pyramid_factor!r}")
    if not 0.0 < omega < 2.0:
        raise ValueError(f"omega must be in (0, 2), got {omega!r}")
    for name, n in (("n_warps", n_warps), ("n_inner", n_inner), ("n_sor", n_sor),
                    ("n_warps_finest", n_warps_finest), ("n_inner_finest", n_inner_finest),
                    ("min_level_size", min_level_size)):
        _check_int(name, n)
    init = None
    if initial_disparity is not None:
        init = as_float_image(initial_disparity, "initial_disparity")
        check_same_shape(images[0], init, "il0", "initial_disparity")

    if presmooth_sigma > 0:
        images = [cv2.GaussianBlur(a, (0, 0), presmooth_sigma, borderType=cv2.BORDER_REFLECT)
                  for a in images]
    shapes = pyramid.pyramid_shapes(shape, pyramid_factor, min(min_level_size, min(shape)))
    pyrs = [pyramid.image_pyramid(a, shapes) for a in images]

    coarsest = shapes[-1]
    if init is None:
        d = np.full(coarsest, np.float32(d0) * np.float32(coarsest[1] / shape[1]), np.float32)
    else:
        # Area averaging, not point sampling: an SGM estimate carries speckles and filled
        # holes that a bilinear sample of a few pixels would pass on to the coarsest level.
        d = cv2.resize(init, (coarsest[1], coarsest[0]), interpolation=cv2.INTER_AREA)
        d = np.ascontiguousarray(d * np.float32(coarsest[1] / shape[1]), dtype=np.float32)
    dp = np.zeros(coarsest, np.float32)
    for level in range(len(shapes) - 1, -1, -1):
        lshape = shapes[level]
        if d.shape != lshape:
            # A disparity is horizontal: resize_field scales a 2-D field by the width ratio.
            d = pyramid.resize_field(d, lshape, is_motion=True)
            dp = pyramid.resize_field(dp, lshape, is_motion=True)
        wl = w_full if lshape == shape else pyramid.resize_field(w_full, lshape, is_motion=True)
        u = np.ascontiguousarray(wl[..., 0])
        v = np.ascontiguousarray(wl[..., 1])
        il0_l, ir0_l, il1_l, ir1_l = (p[level] for p in pyrs)
        finest = level == 0
        _level_disparity(il0_l, ir0_l, il1_l, ir1_l, u, v, d, dp, gamma1=gamma1,
                         gamma2=gamma2, eps=eps,
                         n_warps=n_warps_finest if finest else n_warps,
                         n_inner=n_inner_finest if finest else n_inner,
                         n_sor=n_sor, omega=omega)
    return d.astype(np.float32, copy=False), dp.astype(np.float32, copy=False)
