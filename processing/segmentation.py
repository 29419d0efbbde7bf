"""Gas segmentation by a two-region level set (paper Sec. 4.4, Eq. 9).

The image domain is split into the gas region Omega_g (phi > 0) and the background Omega_bg
(phi < 0) by minimising

    E_ROI(phi) = nu int |grad H(phi)| - int H(phi) log q_g - int (1 - H(phi)) log q_bg

with q_i(I_diff, u, v) = q_i(I_diff) q_i(u) q_i(v), each factor a normal density whose mean
and variance are re-estimated from the current regions (weights H(phi) and 1 - H(phi))
during the descent, and H_eps(phi) = 1/2 (1 + 2/pi arctan(phi / eps)) the smoothed Heaviside
with delta_eps(phi) = eps / (pi (eps^2 + phi^2)).

Descent: the gradient flow dphi/dt = delta_eps(phi) [nu div(grad phi / |grad phi|) +
log q_g - log q_bg] is integrated with the semi-implicit scheme of Chan and Vese as written out
by Getreuer (IPOL 2012, "Chan-Vese Segmentation"): the curvature term is discretised with
the four half-point coefficients C1..C4; each new value is a convex combination of the old
value and its neighbours plus the force step, which is stable for large time steps. We
sweep in Jacobi order (Getreuer uses Gauss-Seidel) so that the numba loop vectorises: one
sweep takes ~0.7 ms at 320x240 on this machine. The region models are re-estimated before
every sweep (one fused numba pass for the weighted moments, with a polynomial arctan).
The data force is clipped to +-``force_clip`` so one outlier pixel cannot dominate.

Multi-scale: the features are area-downsampled by 2 per level; the descent starts on the
coarsest level, and phi is upsampled to initialise the next finer one (coarse-to-fine), so the
fine level only refines the boundary. Defaults: 4 levels (40x30 ... 320x240) with 20, 10, 4
and 2 sweeps, a few ms in total at 320x240 (``benchmarks/bench_preprocess.py``).

Initialisation (documented choice): a pixel starts as gas when the smoothed normalised
contrast max(|I_diff - 0.5| / s_I, |w| / s_w) exceeds ``init_threshold``, with s_I and s_w
robust spreads (scaled mean absolute values) over the whole frame, evaluated on the coarsest
level; if that gives an empty or a full region, a checkerboard of period 10 px is used
instead (Getreuer's default).

Which region is gas: the two-region model is symmetric, so after the descent the region with
the larger mean "activity" |I_diff - 0.5| / s_I + |w| / s_w is called gas (phi is flipped if
needed). Frames without gas: the model still splits the frame in two; the split is accepted
as gas only when the gas region's mean activity exceeds the background's by the factor
``min_activity_ratio``, otherwise the mask is empty (and phi is all negative).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from processing.validation import as_float_image, check_positive

#: Smallest accepted image side in pixels.
MIN_SEGMENT_SIZE = 8

#: Variance floors of the Gaussian region models, per feature: I_diff in [0, 1] (standard
#: deviation >= 0.01) and u, v in px/frame (>= 0.1 px, about the accuracy of the flow).
#: Without them a region of nearly constant value (zero flow in a static background) gets
#: an arbitrarily narrow density, and flow differences far below what the flow solver can
#: resolve would decide the boundary (seen on real footage: noise-only frames split along
#: smooth 0.05 px flow gradients).
VAR_FLOOR = np.array([1e-4, 1e-2, 1e-2])


@numba.njit(cache=True, fastmath=True)
def _pad_edge(phi: np.ndarray, out: np.ndarray) -> None:
    """Copy phi into out[1:-1, 1:-1] and replicate its border (Neumann condition)."""
    h, w = phi.shape
    for i in range(h):
        for j in range(w):
            out[i + 1, j + 1] = phi[i, j]
        out[i + 1, 0] = phi[i, 0]
        out[i + 1, w + 1] = phi[i, w - 1]
    for j in range(w + 2):
        out[0, j] = out[1, j]
        out[h + 1, j] = out[h, j]


@numba.njit(cache=True, fastmath=True)
def _chan_vese_sweeps(
    phi: np.ndarray, force: np.ndarray, nu: float, dt: float, eps: float, n_sweeps: int
) -> None:
    """In-place semi-implicit (Jacobi) sweeps of the Eq. 9 gradient flow.

    Each new value is a convex combination of the old value and its four neighbours plus
    the force step (Getreuer 2012, Eq. 20, with Jacobi instead of Gauss-Seidel order so the
    inner loop vectorises), hence stable for any dt.

    Parameters
    ----------
    phi : ndarray, shape (H, W), float32
        Embedding function, updated in place.
    force : ndarray, shape (H, W), float32
        Region force log q_g - log q_bg per pixel (positive pulls towards gas).
    nu, dt, eps : float
        Length weight, time step and Heaviside width.
    n_sweeps : int
        Number of sweeps.
    """
    h, w = phi.shape
    eta = np.float32(1e-8)
    half = np.float32(0.5)
    inv_pi = np.float32(1.0 / np.pi)
    e = np.float32(eps)
    fdt = np.float32(dt)
    fnu = np.float32(nu)
    pad = np.empty((h + 2, w + 2), dtype=np.float32)
    for _ in range(n_sweeps):
        _pad_edge(phi, pad)
        for i in range(1, h + 1):
            for j in range(1, w + 1):
                p = pad[i, j]
                pe = pad[i, j + 1]
                pw = pad[i, j - 1]
                ps = pad[i + 1, j]
                pn = pad[i - 1, j]
                dxp = pe - p
                dxm = p - pw
                dyp = ps - p
                dym = p - pn
                dy0 = half * (ps - pn)
                dx0 = half * (pe - pw)
                dy_w = half * (pad[i + 1, j - 1] - pad[i - 1, j - 1])
                dx_n = half * (pad[i - 1, j + 1] - pad[i - 1, j - 1])
                c1 = np.float32(1.0) / np.sqrt(eta + dxp * dxp + dy0 * dy0)
                c2 = np.float32(1.0) / np.sqrt(eta + dxm * dxm + dy_w * dy_w)
                c3 = np.float32(1.0) / np.sqrt(eta + dyp * dyp + dx0 * dx0)
                c4 = np.float32(1.0) / np.sqrt(eta + dym * dym + dx_n * dx_n)
                delta = e * inv_pi / (e * e + p * p)
                k = fdt * delta * fnu
                num = p + k * (c1 * pe + c2 * pw + c3 * ps + c4 * pn)
                num += fdt * delta * force[i - 1, j - 1]
                phi[i - 1, j - 1] = num / (np.float32(1.0) + k * (c1 + c2 + c3 + c4))


def heaviside(phi: np.ndarray, eps: float = 1.0) -> np.ndarray:
    """Smoothed Heaviside H_eps(phi) = 1/2 (1 + 2/pi arctan(phi / eps)) (Eq. 9's H)."""
    return (0.5 + np.arctan(phi / eps) / np.pi).astype(np.float32)


def dirac(phi: np.ndarray, eps: float = 1.0) -> np.ndarray:
    """Its derivative delta_eps(phi) = eps / (pi (eps^2 + phi^2))."""
    return (eps / (np.pi * (eps * eps + phi * phi))).astype(np.float32)


@numba.njit(cache=True, fastmath=True, inline="always")
def _atan(z: float) -> float:
    """arctan with |error| <= 1.2e-5 rad (Abramowitz & Stegun 4.4.47), branch-light.

    libm's atan is a scalar call that dominated the segmentation time; this polynomial
    vectorises. The smoothed Heaviside changes by < 4e-6, far below anything that matters.
    """
    a = abs(z)
    big = a > 1.0
    t = 1.0 / a if big else a
    t2 = t * t
    p = t * (0.9998660 + t2 * (-0.3302995 + t2 * (0.1801410 + t2 * (-0.0851330 + t2 * 0.0208351))))
    r = 0.5 * np.pi - p if big else p
    return r if z >= 0 else -r


@numba.njit(cache=True, fastmath=True)
def _region_moments(
    features: np.ndarray, phi: np.ndarray, eps: float, stride: int
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted moments of each feature in both regions, weights H_eps(phi) and 1 - H_eps(phi).

    Returns
    -------
    gas, bg : ndarray, shape (3, 3), float64
        Rows per feature: (sum of weights, weighted sum, weighted sum of squares), taken
        over every ``stride``-th pixel in each direction. The background sums are the
        totals minus the gas sums.
    """
    nf, h, w = features.shape
    s0 = np.float32(0.0)
    s1 = np.zeros(3, np.float32)
    s2 = np.zeros(3, np.float32)
    t1 = np.zeros(3, np.float32)
    t2 = np.zeros(3, np.float32)
    n = 0
    inv_pi = np.float32(1.0 / np.pi)
    inv_eps = np.float32(1.0 / eps)
    for i in range(0, h, stride):
        a0 = np.float32(0.0)
        a1 = np.float32(0.0)
        a2 = np.float32(0.0)
        b0 = np.float32(0.0)
        b1 = np.float32(0.0)
        b2 = np.float32(0.0)
        c0 = np.float32(0.0)
        c1 = np.float32(0.0)
        c2 = np.float32(0.0)
        d0 = np.float32(0.0)
        d1 = np.float32(0.0)
        d2 = np.float32(0.0)
        hs = np.float32(0.0)
        for j in range(0, w, stride):
            hv = np.float32(0.5) + np.float32(_atan(phi[i, j] * inv_eps)) * inv_pi
            x0 = features[0, i, j]
            x1 = features[1, i, j]
            x2 = features[2, i, j]
            hs += hv
            a0 += hv * x0
            a1 += hv * x1
            a2 += hv * x2
            b0 += hv * x0 * x0
            b1 += hv * x1 * x1
            b2 += hv * x2 * x2
            c0 += x0
            c1 += x1
            c2 += x2
            d0 += x0 * x0
            d1 += x1 * x1
            d2 += x2 * x2
            n += 1
        s0 += hs
        s1[0] += a0
        s1[1] += a1
        s1[2] += a2
        s2[0] += b0
        s2[1] += b1
        s2[2] += b2
        t1[0] += c0
        t1[1] += c1
        t1[2] += c2
        t2[0] += d0
        t2[1] += d1
        t2[2] += d2
    gas = np.zeros((nf, 3))
    bg = np.zeros((nf, 3))
    for k in range(nf):
        gas[k, 0] = s0
        gas[k, 1] = s1[k]
        gas[k, 2] = s2[k]
        bg[k, 0] = n - s0
        bg[k, 1] = t1[k] - s1[k]
        bg[k, 2] = t2[k] - s2[k]
    return gas, bg


@numba.njit(cache=True, fastmath=True)
def _apply_force(
    features: np.ndarray,
    mean_g: np.ndarray,
    mean_b: np.ndarray,
    a_g: np.ndarray,
    a_b: np.ndarray,
    cst: float,
    force_clip: float,
    force: np.ndarray,
) -> None:
    """force = cst + sum_k a_b[k] (x_k - mean_b[k])^2 - a_g[k] (x_k - mean_g[k])^2, clipped."""
    nf, h, w = features.shape
    clip = np.float32(force_clip)
    for i in range(h):
        for j in range(w):
            force[i, j] = np.float32(cst)
        for k in range(nf):
            mg = np.float32(mean_g[k])
            mb = np.float32(mean_b[k])
            ag = np.float32(a_g[k])
            ab = np.float32(a_b[k])
            for j in range(w):
                x = features[k, i, j]
                force[i, j] += ab * (x - mb) * (x - mb) - ag * (x - mg) * (x - mg)
        for j in range(w):
            force[i, j] = min(max(force[i, j], -clip), clip)


def _region_force(
    features: np.ndarray, phi: np.ndarray, eps: float, force_clip: float, force: np.ndarray
) -> None:
    """log q_g - log q_bg per pixel with the Gaussian region models of Eq. 9 (into ``force``).

    Parameters
    ----------
    features : ndarray, shape (3, H, W), float32
        I_diff, u, v.
    phi : ndarray, shape (H, W), float32
        Embedding function (the region weights are H_eps(phi) and 1 - H_eps(phi)).
    eps : float
        Heaviside width.
    force_clip : float
        Clip of the output.
    force : ndarray, shape (H, W), float32
        Output.
    """
    # 20k samples estimate a mean and a variance well; subsample large levels for speed.
    stride = max(1, int(np.sqrt(phi.size / 20000.0)))
    gas, bg = _region_moments(features, phi, eps, stride)
    wg = gas[:, 0] + 1e-9
    wb = bg[:, 0] + 1e-9
    mean_g = gas[:, 1] / wg
    mean_b = bg[:, 1] / wb
    var_g = np.maximum(gas[:, 2] / wg - mean_g**2, VAR_FLOOR)
    var_b = np.maximum(bg[:, 2] / wb - mean_b**2, VAR_FLOOR)
    cst = float(0.5 * np.sum(np.log(var_b / var_g)))
    _apply_force(features, mean_g, mean_b, 0.5 / var_g, 0.5 / var_b, cst, force_clip, force)


def _activity(diff: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """|I_diff - 0.5|, |w| and their robust spreads s_I, s_w over the frame.

    The spreads are mean absolute values (x 1.2533, the Gaussian mean-absolute to standard
    deviation factor): cheaper than medians and only used to put the two features on one
    scale.
    """
    a = np.abs(diff - np.float32(0.5))
    m = np.sqrt(flow[..., 0] ** 2 + flow[..., 1] ** 2)
    s_i = 1.2533 * float(a.mean()) + 1e-6
    s_w = 1.2533 * float(m.mean()) + 1e-6
    return a, m, s_i, s_w


def initial_phi(diff: np.ndarray, flow: np.ndarray, *, threshold: float = 2.0) -> np.ndarray:
    """Initial embedding function (module docstring: thresholds, checkerboard fallback).

    Parameters
    ----------
    diff : ndarray, shape (H, W), float32
        Normalised differential image in [0, 1].
    flow : ndarray, shape (H, W, 2), float32
        Optical flow (u, v) in px/frame.
    threshold : float
        Threshold on the smoothed normalised contrast.

    Returns
    -------
    ndarray, shape (H, W), float32
        +1 (gas) / -1 (background), lightly smoothed.
    """
    a, m, s_i, s_w = _activity(diff, flow)
    score = np.maximum(a / s_i, m / s_w).astype(np.float32)
    score = cv2.GaussianBlur(score, (0, 0), 2.0)
    mask = score > threshold
    if not mask.any() or mask.all():
        y, x = np.mgrid[0 : diff.shape[0], 0 : diff.shape[1]]
        return (np.sin(np.pi * x / 5.0) * np.sin(np.pi * y / 5.0)).astype(np.float32)
    phi = np.where(mask, np.float32(1.0), np.float32(-1.0))
    return cv2.GaussianBlur(phi, (0, 0), 1.0)


def _all_background(phi: np.ndarray) -> np.ndarray:
    """An embedding function that is negative everywhere (no gas), shaped like ``phi``."""
    return (-np.abs(phi) - np.float32(1e-3)).astype(np.float32)


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_gas`.

    Attributes
    ----------
    mask : ndarray, shape (H, W), bool
        True on gas pixels (Omega_g).
    phi : ndarray, shape (H, W), float32
        Embedding function, > 0 inside the gas region (all negative when no gas was found).
    activity_ratio : float
        Mean activity of the gas region over that of the background (>= 1 by construction
        of the gas/background choice); compared with ``min_activity_ratio``.
    """

    mask: np.ndarray
    phi: np.ndarray
    activity_ratio: float


def segment_gas(
    diff: np.ndarray,
    flow: np.ndarray,
    *,
    nu: float = 0.5,
    eps: float = 1.0,
    dt: float = 0.5,
    n_levels: int = 4,
    iterations: tuple[int, ...] = (20, 10, 4, 2),
    sweeps_per_update: int = 1,
    force_clip: float = 20.0,
    init_threshold: float = 2.0,
    min_activity_ratio: float = 1.5,
) -> Segmentation:
    """Segment the gas region of a differential image with its optical flow (Eq. 9).

    Parameters
    ----------
    diff : ndarray, shape (H, W), float
        Normalised differential image I_diff in [0, 1] (0.5 = no change), left camera, t0.
    flow : ndarray, shape (H, W, 2), float
        Optical flow w_L = (u, v) in px/frame from I_diff(t0) to I_diff(t1) (Eq. 5).
    nu : float
        Weight of the length term (paper: 0.5).
    eps : float
        Width of the smoothed Heaviside and delta, in units of phi.
    dt : float
        Time step of the semi-implicit descent.
    n_levels : int
        Number of pyramid levels (factor 2 each), >= 1.
    iterations : tuple of int
        Region-model updates per level, coarsest first; the last value repeats if there
        are more levels than entries. Each update is followed by ``sweeps_per_update``
        Gauss-Seidel sweeps of phi.
    sweeps_per_update : int
        Sweeps of phi between two re-estimations of the Gaussian region models.
    force_clip : float
        Clip of the per-pixel log-likelihood ratio.
    init_threshold : float
        See :func:`initial_phi`.
    min_activity_ratio : float
        Gas accepted only if its mean activity is at least this multiple of the
        background's (module docstring); 0 disables the check.

    Returns
    -------
    Segmentation

    Raises
    ------
    ValueError
        Wrong shapes or dtypes, NaN/inf, too small, or bad parameters.
    """
    d = as_float_image(diff, "diff", min_size=MIN_SEGMENT_SIZE)
    if not isinstance(flow, np.ndarray) or flow.shape != (*d.shape, 2):
        got = getattr(flow, "shape", type(flow).__name__)
        raise ValueError(f"flow must have shape {(*d.shape, 2)}, got {got}")
    if not np.issubdtype(flow.dtype, np.floating) or not np.all(np.isfinite(flow)):
        raise ValueError("flow must be a finite floating-point array")
    fl = np.ascontiguousarray(flow, dtype=np.float32)
    nu = check_positive(nu, "nu", allow_zero=True)
    eps = check_positive(eps, "eps")
    dt = check_positive(dt, "dt")
    force_clip = check_positive(force_clip, "force_clip")
    if int(n_levels) < 1 or not iterations or any(int(n) < 0 for n in iterations):
        raise ValueError("n_levels must be >= 1 and iterations a non-empty tuple of counts >= 0")
    if int(sweeps_per_update) < 1:
        raise ValueError(f"sweeps_per_update must be >= 1, got {sweeps_per_update}")

    features_full = np.stack([d, fl[..., 0], fl[..., 1]])
    pyramid = [features_full]
    for _ in range(int(n_levels) - 1):
        prev = pyramid[-1]
        if min(prev.shape[1:]) < 2 * MIN_SEGMENT_SIZE:
            break
        size = (prev.shape[2] // 2, prev.shape[1] // 2)
        pyramid.append(np.stack([cv2.resize(c, size, interpolation=cv2.INTER_AREA) for c in prev]))
    pyramid.reverse()  # coarsest first

    coarse = pyramid[0]
    phi = initial_phi(coarse[0], np.dstack([coarse[1], coarse[2]]), threshold=init_threshold)
    for level, feats in enumerate(pyramid):
        if phi.shape != feats.shape[1:]:
            phi = cv2.resize(phi, (feats.shape[2], feats.shape[1]), interpolation=cv2.INTER_LINEAR)
        phi = np.ascontiguousarray(phi, dtype=np.float32)
        force = np.empty_like(phi)
        n_updates = int(iterations[min(level, len(iterations) - 1)])
        for _ in range(n_updates):
            _region_force(feats, phi, eps, force_clip, force)
            _chan_vese_sweeps(phi, force, nu, dt, eps, int(sweeps_per_update))

    # Which side is gas: larger mean activity (module docstring).
    a, m, s_i, s_w = _activity(d, fl)
    act = a / s_i + m / s_w
    pos = phi > 0
    n_pos = int(pos.sum())
    if n_pos == 0 or n_pos == pos.size:
        return Segmentation(np.zeros(d.shape, bool), _all_background(phi), 1.0)
    act_pos = float(act[pos].mean())
    act_neg = float(act[~pos].mean())
    if act_neg > act_pos:
        phi = -phi
        pos = ~pos
        act_pos, act_neg = act_neg, act_pos
    ratio = act_pos / max(act_neg, 1e-12)
    if ratio < min_activity_ratio:
        return Segmentation(np.zeros(d.shape, bool), _all_background(phi), ratio)
    return Segmentation(pos, phi.astype(np.float32, copy=False), ratio)
