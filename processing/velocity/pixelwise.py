"""The chain's per-pixel stages in one compiled pass: velocity (Eq. 4), surface position and
quality U_SF (Eq. 7).

:func:`processing.velocity.triangulate.scene_flow_velocity`,
:func:`processing.velocity.triangulate.surface_position` and
:func:`processing.velocity.quality.scene_flow_energy` are the readable reference
implementations (numpy, one whole-image operation per step: about 20 full-size temporaries
and three separate warps). The live chain calls :func:`velocity_and_quality` instead, which
reads each input pixel once and writes each output once; ``tests/test_pixelwise.py`` holds
it to the references. The definitions, sign conventions and masks are exactly theirs:

- V = f b [(x - x0 + u)/(d + d') - (x - x0)/d, (y - y0 + v)/(d + d') - (y - y0)/d,
  s/(d + d') - s/d] in float64, stored as float32; valid where every input is finite,
  d > 0, d + d' > 0 and the float32 results are finite; position (x - x0, y - y0, s) b / d;
  both 0 where invalid;
- U_SF = gamma1 psi(|grad d|^2) + gamma2 psi(|grad d'|^2) + psi(E1^2) + psi(E3^2) +
  psi(E4^2), images sampled with the solvers' Catmull-Rom kernel, gradients as
  ``np.gradient`` (central inside, one-sided on the border); ``u_sf_valid`` where all three
  warped samples lie inside their images.
"""

from __future__ import annotations

import numba
import numpy as np

from processing.solvers.derivatives import catmull_rom_at, pad_for_sampling
from processing.validation import check_positive


@numba.njit(inline="always")
def _grad_sq(f: np.ndarray, y: int, x: int) -> float:
    """|grad f|^2 at (y, x) with np.gradient's differences (one-sided on the border)."""
    h, w = f.shape
    if w == 1:
        gx = 0.0
    elif x == 0:
        gx = f[y, 1] - f[y, 0]
    elif x == w - 1:
        gx = f[y, w - 1] - f[y, w - 2]
    else:
        gx = 0.5 * (f[y, x + 1] - f[y, x - 1])
    if h == 1:
        gy = 0.0
    elif y == 0:
        gy = f[1, x] - f[0, x]
    elif y == h - 1:
        gy = f[h - 1, x] - f[h - 2, x]
    else:
        gy = 0.5 * (f[y + 1, x] - f[y - 1, x])
    return gx * gx + gy * gy


@numba.njit(cache=True, error_model="numpy")
def _velocity_quality_rows(
    flow: np.ndarray, d: np.ndarray, dp: np.ndarray, il0: np.ndarray, ir0: np.ndarray,
    il1: np.ndarray, ir1: np.ndarray, x0: float, y0: float, s: float, b: float, dt: float,
    gamma1: float, gamma2: float, eps: float, qmask: np.ndarray,
    velocity: np.ndarray, position: np.ndarray, valid: np.ndarray, u_sf: np.ndarray,
    u_sf_valid: np.ndarray,
) -> None:
    h, w = d.shape
    fb = b / dt
    e2 = np.float32(eps * eps)
    g1 = np.float32(gamma1)
    g2 = np.float32(gamma2)
    wm = np.float32(w - 1)
    hm = np.float32(h - 1)
    big = 3.4028234663852886e38  # float32 max: beyond it the stored value would be inf
    for y in range(h):
        ry = y - y0
        for x in range(w):
            rx = x - x0
            u = np.float64(flow[y, x, 0])
            v = np.float64(flow[y, x, 1])
            dd = np.float64(d[y, x])
            d1 = dd + np.float64(dp[y, x])
            ok = (np.isfinite(dd) and np.isfinite(d1) and np.isfinite(u) and np.isfinite(v)
                  and dd > 0.0 and d1 > 0.0)
            vx = vy = vz = px = py = pz = 0.0
            if ok:
                inv0 = 1.0 / dd
                inv1 = 1.0 / d1
                vx = fb * ((rx + u) * inv1 - rx * inv0)
                vy = fb * ((ry + v) * inv1 - ry * inv0)
                vz = fb * s * (inv1 - inv0)
                px = rx * b * inv0
                py = ry * b * inv0
                pz = s * b * inv0
                ok = (abs(vx) <= big and abs(vy) <= big and abs(vz) <= big
                      and abs(px) <= big and abs(py) <= big and abs(pz) <= big)
                if not ok:
                    vx = vy = vz = px = py = pz = 0.0
            valid[y, x] = ok
            velocity[y, x, 0] = vx
            velocity[y, x, 1] = vy
            velocity[y, x, 2] = vz
            position[y, x, 0] = px
            position[y, x, 1] = py
            position[y, x, 2] = pz

            if not qmask[y, x]:
                u_sf[y, x] = np.nan
                u_sf_valid[y, x] = False
                continue
            # U_SF (Eq. 7) with the float32 arithmetic of the reference implementation.
            xf = np.float32(x)
            yf = np.float32(y)
            fx = xf + flow[y, x, 0]
            fy = yf + flow[y, x, 1]
            mx0 = xf - d[y, x]
            mx1 = fx - d[y, x] - dp[y, x]
            r0w = catmull_rom_at(ir0, mx0, yf)
            r1w = catmull_rom_at(ir1, mx1, fy)
            l1w = catmull_rom_at(il1, fx, fy)
            e1 = r0w - il0[y, x]
            e3 = r1w - r0w
            e4 = r1w - l1w
            u_sf[y, x] = (g1 * np.sqrt(np.float32(_grad_sq(d, y, x)) + e2)
                          + g2 * np.sqrt(np.float32(_grad_sq(dp, y, x)) + e2)
                          + np.sqrt(e1 * e1 + e2) + np.sqrt(e3 * e3 + e2)
                          + np.sqrt(e4 * e4 + e2))
            u_sf_valid[y, x] = (0 <= mx0 <= wm and 0 <= mx1 <= wm and 0 <= fy <= hm
                                and 0 <= fx <= wm)


def velocity_and_quality(
    flow: np.ndarray, d: np.ndarray, d_change: np.ndarray,
    images: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], *,
    principal_point: tuple[float, float], camera_constant: float, baseline: float, dt: float,
    gamma1: float = 0.05, gamma2: float = 0.5, eps: float = 0.001,
    quality_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Velocity V (Eq. 4), surface position and U_SF (Eq. 7) of every pixel in one pass.

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2), float32
        Left optical flow (u, v) in px (Eq. 5).
    d, d_change : ndarray, shape (H, W), float32
        Disparity and disparity change in px (Eq. 6; ``x_R = x_L - d``).
    images : (il0, ir0, il1, ir1), each (H, W) float32
        The normalised differential images the fields were computed from.
    principal_point, camera_constant, baseline, dt
        (x0, y0) and s in px, b in m, the frame interval in s (f = 1/dt).
    gamma1, gamma2, eps
        Weights and Charbonnier epsilon of Eq. 6.
    quality_mask : ndarray, shape (H, W), bool, optional
        Compute U_SF only where True: the segmented gas, the only region Eq. 8 averages it
        over (its three bicubic samples per pixel are most of this pass: at 320x240 4.5 ms
        for every pixel, 1.2 ms with a sixth of them gas, 0.6 ms without gas; measured).
        Elsewhere ``u_sf`` is NaN and ``u_sf_valid`` False. None: every pixel.

    Returns
    -------
    velocity : (H, W, 3) float32, m/s
    position : (H, W, 3) float32, m
    valid : (H, W) bool
        Where both V and the position are defined (module docstring).
    u_sf : (H, W) float32
    u_sf_valid : (H, W) bool
        Where U_SF was computed and its warps stayed inside the images.

    Raises
    ------
    ValueError
        Shapes that disagree; NaN or inf in any input; non-positive s, b or dt;
        non-finite principal point.
    """
    shape = d.shape
    for name, arr, want in (("flow", flow, (*shape, 2)), ("d_change", d_change, shape),
                            *((f"images[{i}]", im, shape) for i, im in enumerate(images))):
        if not isinstance(arr, np.ndarray) or arr.shape != want:
            raise ValueError(f"{name} must have shape {want}, got "
                             f"{getattr(arr, 'shape', type(arr).__name__)}")
    if len(principal_point) != 2 or not all(np.isfinite(float(c)) for c in principal_point):
        raise ValueError(f"principal_point must be two finite numbers, got {principal_point!r}")
    s = check_positive(camera_constant, "camera_constant")
    b = check_positive(baseline, "baseline")
    t = check_positive(dt, "dt")
    f32 = [np.ascontiguousarray(a, dtype=np.float32) for a in (flow, d, d_change, *images)]
    # U_SF warps by the fields: a NaN would become an out-of-range index in the kernel
    # (the reference scene_flow_energy rejects non-finite input the same way).
    for name, arr in zip(("flow", "d", "d_change", "il0", "ir0", "il1", "ir1"), f32,
                         strict=True):
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} contains NaN or infinite values")
    if quality_mask is not None and (not isinstance(quality_mask, np.ndarray)
                                     or quality_mask.shape != shape):
        raise ValueError(f"quality_mask must have shape {shape}, got "
                         f"{getattr(quality_mask, 'shape', type(quality_mask).__name__)}")
    qmask = (np.ones(shape, np.bool_) if quality_mask is None
             else np.ascontiguousarray(quality_mask, dtype=np.bool_))
    velocity = np.empty((*shape, 3), np.float32)
    position = np.empty((*shape, 3), np.float32)
    valid = np.empty(shape, np.bool_)
    u_sf = np.empty(shape, np.float32)
    u_sf_valid = np.empty(shape, np.bool_)
    # The three images U_SF samples go to the Catmull-Rom samplers padded.
    padded = [pad_for_sampling(a) for a in f32[4:]]
    _velocity_quality_rows(*f32[:4], *padded, float(principal_point[0]),
                           float(principal_point[1]), s, b, t,
                           float(gamma1), float(gamma2), float(eps), qmask, velocity, position,
                           valid, u_sf, u_sf_valid)
    return velocity, position, valid, u_sf, u_sf_valid
