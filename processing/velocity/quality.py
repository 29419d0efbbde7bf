"""Quality of the scene flow: U_SF per pixel (paper Eq. 7) and c_USF per frame (Eq. 8).

U_SF evaluates the energy density of Eq. 6 with the final fields:

    U_SF = gamma1 psi(|grad d|^2) + gamma2 psi(|grad d'|^2)
           + psi(|E1|^2) + psi(|E3|^2) + psi(|E4|^2)

with the data terms E1, E3, E4 of Eq. 3 in the sign convention of
:mod:`processing.stereo.joint` (``x_R = x_L - d``), the images warped by Catmull-Rom
bicubic interpolation (as in the solver) at the final d, d' and w. Its floor is
(gamma1 + gamma2 + 3) eps (psi(0) = eps), about 0.0036 at the paper's parameters, so
exp(-U_SF) <= 1.

c_USF = |Omega_g|^-1 sum over Omega_g of exp(-U_SF) (Eq. 8): close to 1 when the
stereo-kinematic assumptions hold in the gas region.
"""

from __future__ import annotations

import numpy as np

from processing.solvers import derivatives
from processing.validation import as_float_image, as_flow_field, check_positive, check_same_shape


def _psi(s2: np.ndarray, eps: float) -> np.ndarray:
    return np.sqrt(s2 + np.float32(eps * eps))


def _warp(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    # The solver's interpolation (Catmull-Rom), so U_SF judges the fields it produced.
    return derivatives.warp_dx_catmull_rom(image, map_x, map_y)[0]


def _grad_sq(f: np.ndarray) -> np.ndarray:
    # Central differences inside, as the solvers' lagged weights
    # (processing.solvers.redblack.compact_gradient_sq); on the border rows and columns np.gradient
    # is one-sided where the solvers use half of that (Neumann ghost values).
    gy, gx = np.gradient(f)
    return (gx * gx + gy * gy).astype(np.float32)


def scene_flow_energy(
    il0: np.ndarray,
    ir0: np.ndarray,
    il1: np.ndarray,
    ir1: np.ndarray,
    flow: np.ndarray,
    d: np.ndarray,
    d_change: np.ndarray,
    *,
    gamma1: float = 0.05,
    gamma2: float = 0.5,
    eps: float = 0.001,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel quality measure U_SF of Eq. 7.

    Parameters
    ----------
    il0, ir0, il1, ir1 : ndarray, shape (H, W), floating point
        The rectified differential images in [0, 1] the fields were computed from.
    flow : ndarray, shape (H, W, 2), floating point
        Left optical flow (u, v) in px.
    d, d_change : ndarray, shape (H, W), floating point
        Disparity and disparity change in px (:func:`processing.stereo.joint.joint_disparity`).
    gamma1, gamma2, eps : float
        The weights and Charbonnier epsilon of Eq. 6 (paper: 0.05, 0.5, 0.001).

    Returns
    -------
    u_sf : ndarray, shape (H, W), float32
        U_SF (dimensionless, >= (gamma1 + gamma2 + 3) eps). Always finite.
    valid : ndarray, shape (H, W), bool
        True where every warped sample (x - d at t0; x + w and x + w - d - d' at t1) lies
        inside its image. Elsewhere the data terms compare against replicated border
        values and carry no information: exclude such pixels (see :func:`c_usf`).

    Raises
    ------
    ValueError
        Bad images or fields (shape, dtype, NaN/inf) or non-positive parameters.
    """
    imgs = [as_float_image(a, n) for a, n in
            ((il0, "il0"), (ir0, "ir0"), (il1, "il1"), (ir1, "ir1"))]
    shape = imgs[0].shape
    for img, name in zip(imgs[1:], ("ir0", "il1", "ir1"), strict=True):
        check_same_shape(imgs[0], img, "il0", name)
    w = as_flow_field(flow, shape, "flow")
    dd = as_float_image(d, "d")
    dp = as_float_image(d_change, "d_change")
    check_same_shape(imgs[0], dd, "il0", "d")
    check_same_shape(imgs[0], dp, "il0", "d_change")
    check_positive(gamma1, "gamma1", allow_zero=True)
    check_positive(gamma2, "gamma2", allow_zero=True)
    check_positive(eps, "eps")
    l0, r0, l1, r1 = imgs

    xx, yy = derivatives.pixel_grid(shape)
    fx, fy = xx + w[..., 0], yy + w[..., 1]
    mx0 = xx - dd
    mx1 = fx - dd - dp
    r0w = _warp(r0, mx0, yy)
    r1w = _warp(r1, mx1, fy)
    l1w = _warp(l1, fx, fy)
    e1 = r0w - l0
    e3 = r1w - r0w
    e4 = r1w - l1w
    valid = ((derivatives.inside_mask(mx0, yy) > 0) & (derivatives.inside_mask(mx1, fy) > 0)
             & (derivatives.inside_mask(fx, fy) > 0))
    u_sf = (np.float32(gamma1) * _psi(_grad_sq(dd), eps)
            + np.float32(gamma2) * _psi(_grad_sq(dp), eps)
            + _psi(e1 * e1, eps) + _psi(e3 * e3, eps) + _psi(e4 * e4, eps))
    return u_sf.astype(np.float32), valid


def c_usf(u_sf: np.ndarray, region: np.ndarray, valid: np.ndarray | None = None) -> float | None:
    """Per-frame quality coefficient c_USF of Eq. 8 over a region (the gas mask).

    Parameters
    ----------
    u_sf : ndarray, shape (H, W), floating point
        U_SF from :func:`scene_flow_energy`.
    region : ndarray, shape (H, W), bool
        Omega_g, the pixels to average over (the segmented gas region).
    valid : ndarray, shape (H, W), bool, optional
        Pixels where U_SF is defined (second output of :func:`scene_flow_energy`); the
        average runs over ``region & valid``.

    Returns
    -------
    float or None
        Mean of exp(-U_SF) over the region, in (0, 1]. ``None`` when the region (after
        removing invalid pixels) is empty: there is no quality to report, and None - unlike
        NaN - cannot slip silently into an average or a plot; the caller must decide how
        to display "no gas region".

    Raises
    ------
    ValueError
        Shapes differ, region/valid not boolean, or U_SF not finite inside the region.
    """
    for arr, name in ((region, "region"), (valid, "valid")):
        if arr is None:
            continue
        if not isinstance(arr, np.ndarray) or arr.dtype != np.bool_:
            raise ValueError(f"{name} must be a boolean array")
        if arr.shape != u_sf.shape:
            raise ValueError(f"{name} and u_sf differ in shape: {arr.shape} vs {u_sf.shape}")
    mask = region if valid is None else (region & valid)
    n = int(np.count_nonzero(mask))
    if n == 0:
        return None
    vals = np.asarray(u_sf, dtype=np.float64)[mask]
    if not np.all(np.isfinite(vals)):
        raise ValueError("u_sf contains NaN or infinite values inside the region")
    return float(np.exp(-vals).mean())
