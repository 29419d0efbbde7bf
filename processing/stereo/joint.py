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

Numerics are those of the flow solver (:mod:`processing.flow.brox`) and share its
building blocks: a coarse-to-fine pyramid (:mod:`processing.solvers.pyramid`) on which d, d' and w
are resampled with disparities scaled by the width ratio; at each level, outer warps
re-sample the right images at the current disparities; inner fixed-point iterations
freeze ("lag") the psi' weights, and the linear system in (d, d') - a 2x2 block per pixel
plus two diffusion terms with their own weights gamma1 psi'_d and gamma2 psi'_d' - is
solved with the compact red-black SOR of :mod:`processing.solvers.redblack`. Unlike the flow, the
images are sampled with a Catmull-Rom cubic (:func:`processing.solvers.derivatives.
warp_dx_catmull_rom`): OpenCV's cubic biases fractional shifts by up to 0.04 px, which would
go straight into d' and hence into V_Z (Eq. 4).
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from processing.solvers import derivatives, lagged, pyramid, redblack, variational
from processing.stereo import terms as disparity_terms
from processing.stereo.constant_mode import constant_mode_step
from processing.validation import (
    MIN_IMAGE_SIZE,
    as_float_image,
    as_flow_field,
    check_positive,
    check_same_shape,
)

#: The usable maps of a level where the depth gate blanked nothing.
_NOTHING_BLANKED = np.zeros((0, 0), np.float32)


class _DisparityTerms(NamedTuple):
    """Parameters of the data terms of Eq. 6 (select them in the shared lagged loop)."""

    right_temporal_weight: float
    constant_mode: bool


@lagged.implement(lagged.data_terms, _DisparityTerms)
def _disparity_data_terms(terms: _DisparityTerms, ws: variational.Workspace, c: int,
                          eps: float) -> None:
    """Data terms E1, E3, E4 of Eq. 6 at the pixels of colour ``c`` on the eight split
    inputs (e1, e3, e4, g0, g1, m1, m3, m4); the kernel is purely per pixel, so it runs on
    compact arrays unchanged (:func:`processing.stereo.terms.data_terms`)."""
    ins, coef = ws.inputs, ws.coefs[c]
    disparity_terms.data_terms(
        ins[0, c], ins[1, c], ins[2, c], ins[3, c], ins[4, c], ins[5, c], ins[6, c], ins[7, c],
        ws.x1[c], ws.x2[c], ws.x1_0[c], ws.x2_0[c], eps, terms.right_temporal_weight,
        ws.a11[c], coef[redblack.A12], ws.a22[c], coef[redblack.R1], coef[redblack.R2])


@lagged.implement(lagged.after_solve, _DisparityTerms)
def _disparity_after_solve(terms: _DisparityTerms, ws: variational.Workspace) -> None:
    """The constant-mode step of d and d' (:func:`constant_mode_step`) when enabled."""
    if terms.constant_mode:
        constant_mode_step(ws.coefs, ws.a11, ws.a22, ws.x1, ws.x2)


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
    constant_mode: bool = True,
    right_temporal_weight: float = 1.0,
    usable: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """Refine (d, dp) in place at one pyramid level (outer warps x lagged FP x SOR).

    ``usable``: (left, right) float32 maps, 1 where the image carries information, 0 where
    it was blanked (:func:`processing.stereo.terms.usable_maps`); a data term with a
    sample on a blanked pixel is dropped."""
    l0x = derivatives.dx(il0)
    ws = variational.workspace(il0.shape)
    ok_left, ok_right = (_NOTHING_BLANKED, _NOTHING_BLANKED) if usable is None else usable
    pl1, pr0, pr1 = (derivatives.pad_for_sampling(a) for a in (il1, ir0, ir1))
    for _ in range(n_warps):
        # Catmull-Rom samples (not OpenCV's a = -0.75 cubic, whose phase-dependent bias
        # would show up directly in d'), each with the exact x-derivative of the
        # interpolant, straight into the solver's compact inputs.
        disparity_terms.split_residuals(il0, l0x, pl1, pr0, pr1, u, v, d, dp, ok_left,
                                        ok_right, ws.inputs)
        # Eq. 6 has one penaliser per field, psi(|grad d|^2) and psi(|grad d'|^2), each with
        # its own weight, so the two unknowns diffuse with different edge weights.
        lagged.lagged_iterations(_DisparityTerms(right_temporal_weight, constant_mode), d, dp,
                                 ws, (gamma1, gamma2), False, eps, n_inner, n_sor, omega)


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
    initial_change: np.ndarray | None = None,
    n_levels: int | None = None,
    pyramid_factor: float = 0.75,
    min_level_size: int = 12,
    n_warps: int = 2,
    n_inner: int = 3,
    n_warps_finest: int = 1,
    n_inner_finest: int = 4,
    n_sor: int = 10,
    omega: float = 1.95,
    presmooth_sigma: float = 0.6,
    finest_level: int = 0,
    constant_mode: bool = True,
    right_temporal_weight: float = 1.0,
    blanked: tuple[np.ndarray, np.ndarray] | None = None,
    pyramid_cache: variational.PyramidCache | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Disparity d_L and disparity change d'_L of the left view by minimising Eq. 6.

    Parameters
    ----------
    il0, ir0, il1, ir1 : ndarray, shape (H, W), floating point
        Rectified differential images I_L(t0), I_R(t0), I_L(t1), I_R(t1), intensities in
        [0, 1] (gamma1, gamma2 are calibrated for that range). H, W >= 8.
    flow : ndarray, shape (H, W, 2), floating point
        Left optical flow w_L = (u, v) in px from t0 to t1 (Eq. 5,
        :func:`processing.flow.brox.brox_optical_flow`): I_L(x + w, t1) ~ I_L(x, t0).
    gamma1, gamma2 : float
        Smoothness weights of d and d' (paper: 0.05, 0.5).
    eps : float
        Charbonnier epsilon of psi(s^2) = sqrt(s^2 + eps^2) (paper: 0.001).
    d0 : float
        Minimum disparity in px used as the constant initial disparity (paper Sec. 4.3),
        scaled to every pyramid level. Ignored when ``initial_disparity`` is given.
    initial_disparity : ndarray, shape (H, W), optional
        Initial disparity field in px (e.g. an SGM estimate with its holes filled). It is
        resampled to the coarsest level used and refined from there.
    initial_change : ndarray, shape (H, W), optional
        Initial disparity change d' in px (default 0), resampled like the disparity.
    n_levels : int, optional
        Use only the finest ``n_levels`` pyramid levels (default: all down to
        ``min_level_size``). A warm start from the previous frame is already close and
        needs no coarse levels.
    pyramid_factor : float
        Down-sampling factor between pyramid levels, in (0, 1).
    min_level_size : int
        The coarsest level keeps min(H, W) >= this (px).
    n_warps : int
        Outer fixed-point iterations (re-warps of the right images) per level, except the
        finest.
    n_inner : int
        Inner fixed-point iterations per warp (lagged psi' weights), except at the finest
        level: the coarse levels make the large corrections (the whole d - d0 and d'),
        where one linearisation per level is not enough (docs/solver-choices.md).
    n_warps_finest, n_inner_finest : int
        The same at the finest level, where only a fraction of a pixel remains.
    n_sor : int
        Red-black SOR iterations per inner iteration.
    omega : float
        SOR relaxation factor in (0, 2). Higher than the flow solver's 1.8: the lagged
        smoothness weights gamma psi' reach gamma / eps where a field is flat, a stiff,
        Laplacian-dominated system whose optimal SOR factor is close to 2.
    presmooth_sigma : float
        Gaussian pre-smoothing of the four images in px (0 disables).
    finest_level : int
        The finest pyramid level solved, 0 (default) for the images' own size. Above 0 the
        fields of that level are interpolated to the images' size (bilinear, values scaled
        to its px) without solving the finer levels: d and d' are smooth fields (gamma1,
        gamma2), and on a warm start the finest level moved them by hundredths of a pixel
        at a third of the solver's time (docs/performance.md). ``n_warps_finest`` and
        ``n_inner_finest`` still mean level 0, so they do not apply then.
    constant_mode : bool
        After every SOR solve, shift d and d' by the constants that minimise the
        linearised energy (:func:`constant_mode_step`; beyond the paper: it changes only
        how fast the solver gets to the minimum of Eq. 6, not the minimum). False
        reproduces the plain solver.
    right_temporal_weight : float
        Weight of E3 (Eq. 3c, the right camera's brightness constancy from t0 to t1),
        >= 0; 1 is the paper's Eq. 6. E3 is the only term through which an error of the
        given flow reaches d' (its residual vanishes where d' takes up the flow's
        horizontal error; E1 and E4 measure d and d + d' directly), but it is also what
        keeps d' off the background's 0 where the gas is seen against texture.
    blanked : (ndarray, ndarray), shape (H, W), bool, optional
        Pixels of the left and the right view that were blanked to "no change" in both
        differential images (the depth gate's). Data terms that sample them or their
        border are dropped, so d and d' there come from the smoothness terms alone
        (:func:`processing.stereo.terms.usable_maps`).
    pyramid_cache : PyramidCache, optional
        Shares the images' pyramids with other solver calls on the same image objects
        (:class:`processing.solvers.variational.PyramidCache`): the flow's of I_L(t0) and
        I_L(t1).

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
    images, w_full, init = _checked_inputs(
        (il0, ir0, il1, ir1), flow, initial_disparity, blanked, gamma1=gamma1, gamma2=gamma2,
        right_temporal_weight=right_temporal_weight, d0=d0)
    variational.check_options(eps=eps, pyramid_factor=pyramid_factor, omega=omega,
                              presmooth_sigma=presmooth_sigma, n_levels=n_levels,
                              n_warps=n_warps, n_inner=n_inner, n_sor=n_sor,
                              n_warps_finest=n_warps_finest, n_inner_finest=n_inner_finest,
                              min_level_size=min_level_size)
    shape = images[0].shape
    shapes, pyrs = variational.build_pyramids(
        images, pyramid_factor=pyramid_factor, min_level_size=min_level_size,
        presmooth_sigma=presmooth_sigma, n_levels=n_levels, cache=pyramid_cache)
    if isinstance(finest_level, bool) or not isinstance(finest_level, int) \
            or not 0 <= finest_level < len(shapes):
        raise ValueError(f"finest_level must be an integer in [0, {len(shapes) - 1}] (the "
                         f"pyramid's levels), got {finest_level!r}")

    d, dp = _initial_fields(images[0], shapes[-1], d0, init, initial_change)

    def solve_level(level: int, fields: variational.Fields) -> variational.Fields:
        if level < finest_level:
            return fields  # already interpolated to this level by coarse_to_fine
        lshape = shapes[level]
        wl = w_full if lshape == shape else pyramid.resize_field(w_full, lshape, is_motion=True)
        u = np.ascontiguousarray(wl[..., 0])
        v = np.ascontiguousarray(wl[..., 1])
        dl, dpl = (np.array(f, np.float32, copy=True) for f in fields)
        finest = level == 0
        usable = None if blanked is None else disparity_terms.usable_maps(blanked, lshape)
        _level_disparity(*(p[level] for p in pyrs), u, v, dl, dpl, gamma1=gamma1,
                         gamma2=gamma2, eps=eps,
                         n_warps=n_warps_finest if finest else n_warps,
                         n_inner=n_inner_finest if finest else n_inner,
                         n_sor=n_sor, omega=omega, constant_mode=constant_mode,
                         right_temporal_weight=right_temporal_weight, usable=usable)
        return dl, dpl

    d, dp = variational.coarse_to_fine(shapes, (d, dp), solve_level)
    return d, dp


def _checked_inputs(frames: tuple[np.ndarray, ...], flow: np.ndarray,
                    initial_disparity: np.ndarray | None,
                    blanked: tuple[np.ndarray, np.ndarray] | None, *, gamma1: float,
                    gamma2: float, right_temporal_weight: float, d0: float
                    ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray | None]:
    """The four images as float32, the flow and the initial disparity, checked."""
    images = [
        as_float_image(a, n, min_size=MIN_IMAGE_SIZE)
        for a, n in zip(frames, ("il0", "ir0", "il1", "ir1"), strict=True)
    ]
    for img, name in zip(images[1:], ("ir0", "il1", "ir1"), strict=True):
        check_same_shape(images[0], img, "il0", name)
    shape = images[0].shape
    w_full = as_flow_field(flow, shape, "flow")
    check_positive(gamma1, "gamma1")
    check_positive(gamma2, "gamma2")
    check_positive(right_temporal_weight, "right_temporal_weight", allow_zero=True)
    if not np.isfinite(float(d0)):
        raise ValueError(f"d0 must be a finite number of pixels, got {d0!r}")
    if blanked is not None:
        for b, name in zip(blanked, ("blanked left", "blanked right"), strict=True):
            if np.shape(b) != shape:
                raise ValueError(f"{name}: shape {np.shape(b)}, expected {shape}")
    init = None
    if initial_disparity is not None:
        init = as_float_image(initial_disparity, "initial_disparity")
        check_same_shape(images[0], init, "il0", "initial_disparity")
    return images, w_full, init


def _initial_fields(il0: np.ndarray, coarsest: tuple[int, int], d0: float,
                    init: np.ndarray | None, initial_change: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """d and d' to start from: the constant d0 or the given disparity at the coarsest level
    (scaled by the width ratio), the given d' or 0."""
    shape = il0.shape
    if init is None:
        d = np.full(coarsest, np.float32(d0) * np.float32(coarsest[1] / shape[1]), np.float32)
    elif coarsest == shape:
        d = init.copy()
    else:
        # Area averaging, not point sampling: an SGM estimate carries speckles and filled
        # holes that a bilinear sample of a few pixels would pass on to the coarsest level.
        d = cv2.resize(init, (coarsest[1], coarsest[0]), interpolation=cv2.INTER_AREA)
        d = np.ascontiguousarray(d * np.float32(coarsest[1] / shape[1]), dtype=np.float32)
    if initial_change is None:
        dp = np.zeros(coarsest, np.float32)
    else:
        dp = as_float_image(initial_change, "initial_change")
        check_same_shape(il0, dp, "il0", "initial_change")
    return d, dp
