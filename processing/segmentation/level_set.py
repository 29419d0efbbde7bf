"""The descent of the two-region level set of Eq. 9 (paper Sec. 4.4): the Gaussian region
force log q_g - log q_bg and the semi-implicit Chan-Vese curvature sweeps.

Used by :func:`processing.segmentation.segment.segment_gas`, whose docstring describes the scheme
(Getreuer, IPOL 2012, in Jacobi order; region models re-estimated before every sweep).
"""

from __future__ import annotations

import numba
import numpy as np

#: Variance floors of the Gaussian region models, per feature: I_diff in [0, 1] (standard
#: deviation >= 0.01) and u, v in px/frame (>= 0.1 px, about the accuracy of the flow).
#: Without them a region of nearly constant value (zero flow in a static background) gets
#: an arbitrarily narrow density, and flow differences far below what the flow solver can
#: resolve would decide the boundary (seen on real footage: noise-only frames split along
#: smooth 0.05 px flow gradients).
VAR_FLOOR = np.array([1e-4, 1e-2, 1e-2])


@numba.njit(cache=True, fastmath=True, error_model="numpy")
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


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def chan_vese_sweeps(
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


@numba.njit(cache=True, fastmath=True, error_model="numpy", inline="always")
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


# Compiled into descend(): only the fastmath flags that give the same code whether this is
# compiled fresh with its caller or loaded from numba's cache (fused multiply-adds,
# reciprocal and function approximations do not; docs/design.md). Reassociation lets the
# sums vectorise (3.9 ms per segmentation without any flag, 2.1 with these, 1.9 with all).
@numba.njit(cache=True, fastmath={"reassoc", "nsz", "nnan", "ninf"}, error_model="numpy")
def _region_moments(
    features: np.ndarray, phi: np.ndarray, known: np.ndarray, eps: float, stride: int
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted moments of each feature in both regions, weights H_eps(phi) and 1 - H_eps(phi),
    for the motion features (k >= 1) times ``known`` (H, W), the measured share of a pixel.

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
    sk0 = np.float32(0.0)
    nk = np.float32(0.0)
    inv_pi = np.float32(1.0 / np.pi)
    inv_eps = np.float32(1.0 / eps)
    everywhere = known.shape[0] == 1  # the 1 x 1 sentinel (segment.py): every pixel known
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
        hk = np.float32(0.0)
        ks = np.float32(0.0)
        for j in range(0, w, stride):
            hv = np.float32(0.5) + np.float32(_atan(phi[i, j] * inv_eps)) * inv_pi
            kv = np.float32(1.0) if everywhere else known[i, j]
            hw = hv * kv
            x0 = features[0, i, j]
            x1 = features[1, i, j]
            x2 = features[2, i, j]
            hs += hv
            hk += hw
            ks += kv
            a0 += hv * x0
            a1 += hw * x1
            a2 += hw * x2
            b0 += hv * x0 * x0
            b1 += hw * x1 * x1
            b2 += hw * x2 * x2
            c0 += x0
            c1 += kv * x1
            c2 += kv * x2
            d0 += x0 * x0
            d1 += kv * x1 * x1
            d2 += kv * x2 * x2
            n += 1
        s0 += hs
        sk0 += hk
        nk += ks
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
        gas[k, 0] = s0 if k == 0 else sk0
        gas[k, 1] = s1[k]
        gas[k, 2] = s2[k]
        # float64 like n - s0: with every pixel known, nk == n and sk0 == s0 to the bit
        bg[k, 0] = n - s0 if k == 0 else np.float64(nk) - np.float64(sk0)
        bg[k, 1] = t1[k] - s1[k]
        bg[k, 2] = t2[k] - s2[k]
    return gas, bg


# Compiled into descend(): see _region_moments for the flags.
@numba.njit(cache=True, fastmath={"nsz", "nnan", "ninf"}, error_model="numpy")
def _apply_force(
    features: np.ndarray,
    known: np.ndarray,
    mean_g: np.ndarray,
    mean_b: np.ndarray,
    a_g: np.ndarray,
    a_b: np.ndarray,
    cst: np.ndarray,
    force_clip: float,
    force: np.ndarray,
) -> None:
    """force = sum_k m_k (cst[k] + a_b[k] (x_k - mean_b[k])^2 - a_g[k] (x_k - mean_g[k])^2),
    clipped; m_0 = 1, m_k = ``known`` for the motion features k >= 1.

    Written as the sum over every feature minus (1 - m_k) times the motion features' terms,
    so that with every pixel known the force is the plain sum to the bit.
    """
    nf, h, w = features.shape
    clip = np.float32(force_clip)
    everywhere = known.shape[0] == 1  # the 1 x 1 sentinel (segment.py): every pixel known
    total = 0.0  # float64, summed as the constant always was
    for k in range(nf):
        total += cst[k]
    for i in range(h):
        for j in range(w):
            force[i, j] = np.float32(total)
        for k in range(nf):
            mg = np.float32(mean_g[k])
            mb = np.float32(mean_b[k])
            ag = np.float32(a_g[k])
            ab = np.float32(a_b[k])
            c = np.float32(cst[k])
            if k == 0 or everywhere:
                for j in range(w):
                    x = features[k, i, j]
                    force[i, j] += ab * (x - mb) * (x - mb) - ag * (x - mg) * (x - mg)
            else:
                for j in range(w):
                    x = features[k, i, j]
                    t = ab * (x - mb) * (x - mb) - ag * (x - mg) * (x - mg)
                    force[i, j] += t - (np.float32(1.0) - known[i, j]) * (c + t)
        for j in range(w):
            force[i, j] = min(max(force[i, j], -clip), clip)


@numba.njit(cache=True, error_model="numpy")
def region_force(features: np.ndarray, phi: np.ndarray, known: np.ndarray, eps: float,
                 force_clip: float, force: np.ndarray) -> None:
    """log q_g - log q_bg per pixel with the Gaussian region models of Eq. 9 (into ``force``).

    Parameters
    ----------
    features : ndarray, shape (3, H, W), float32
        I_diff, u, v.
    phi : ndarray, shape (H, W), float32
        Embedding function (the region weights are H_eps(phi) and 1 - H_eps(phi)).
    known : ndarray, shape (H, W) or (1, 1), float32
        Measured share of each pixel's flow in [0, 1]: u and v count only as far as they
        were measured (the models' moments and the ratios), I_diff everywhere; a 1 x 1
        array means every pixel is measured.
    eps : float
        Heaviside width.
    force_clip : float
        Clip of the output.
    force : ndarray, shape (H, W), float32
        Output.
    """
    # 20k samples estimate a mean and a variance well; subsample large levels for speed.
    stride = max(1, int(np.sqrt(phi.size / 20000.0)))
    gas, bg = _region_moments(features, phi, known, eps, stride)
    nf = features.shape[0]
    mean_g = np.empty(nf)
    mean_b = np.empty(nf)
    a_g = np.empty(nf)
    a_b = np.empty(nf)
    cst = np.empty(nf)
    for k in range(nf):
        wg = gas[k, 0] + 1e-9
        wb = bg[k, 0] + 1e-9
        mean_g[k] = gas[k, 1] / wg
        mean_b[k] = bg[k, 1] / wb
        var_g = max(gas[k, 2] / wg - mean_g[k] ** 2, VAR_FLOOR[k])
        var_b = max(bg[k, 2] / wb - mean_b[k] ** 2, VAR_FLOOR[k])
        cst[k] = 0.5 * np.log(var_b / var_g)
        a_g[k] = 0.5 / var_g
        a_b[k] = 0.5 / var_b
    _apply_force(features, known, mean_g, mean_b, a_g, a_b, cst, force_clip, force)


@numba.njit(cache=True, error_model="numpy")
def descend(features: np.ndarray, phi: np.ndarray, known: np.ndarray, nu: float, dt: float,
            eps: float, force_clip: float, n_updates: int, sweeps_per_update: int) -> None:
    """``n_updates`` times: re-estimate the region models (:func:`region_force`), then
    ``sweeps_per_update`` sweeps of phi (:func:`chan_vese_sweeps`); phi (H, W) in place,
    ``features`` (3, H, W) and ``known`` (H, W) or (1, 1) as in :func:`region_force`."""
    force = np.empty_like(phi)
    for _ in range(n_updates):
        region_force(features, phi, known, eps, force_clip, force)
        chan_vese_sweeps(phi, force, nu, dt, eps, sweeps_per_update)
