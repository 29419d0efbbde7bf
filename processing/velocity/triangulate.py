"""3D gas velocity (paper Eq. 4) and 3D position of the virtual gas surface.

Geometry of the rectified pair (paper Fig. 1): left camera at the origin, X right, Y down,
Z forward; the right camera at +b along X. A point (X, Y, Z) is seen in the left image at
x = x0 + s X / Z, y = y0 + s Y / Z and in the right one at x - d with d = s b / Z (the
sign convention of :mod:`processing.stereo.joint`). Hence

    X = (x - x0) b / d,   Y = (y - y0) b / d,   Z = s b / d

and, with the same point seen at t1 at x + w with disparity d + d', Eq. 4:

    V = f b [ (x - x0 + u) / (d + d') - (x - x0) / d,
              (y - y0 + v) / (d + d') - (y - y0) / d,
              s / (d + d') - s / d ]

with f = 1 / dt the frame rate. Pixels where the geometry is undefined (d <= 0 or
d + d' <= 0: at or beyond infinity, or behind the cameras) or any input is non-finite are
masked: their values are 0 and their mask entry False, so no NaN or inf can reach a
summary. The velocity belongs to a virtual surface at the concentration-weighted mean
depth of the gas along each ray (paper Sec. 3).
"""

from __future__ import annotations

import numpy as np

from processing.validation import check_positive


def _check_inputs(
    d: np.ndarray, principal_point: tuple[float, float], camera_constant: float,
    baseline: float,
) -> np.ndarray:
    if not isinstance(d, np.ndarray) or d.ndim != 2:
        raise ValueError(f"d must be a 2-D array, got {getattr(d, 'shape', type(d).__name__)}")
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"d must have a floating-point dtype, got {d.dtype}")
    if len(principal_point) != 2 or not all(np.isfinite(float(c)) for c in principal_point):
        raise ValueError(f"principal_point must be two finite numbers (x0, y0), "
                         f"got {principal_point!r}")
    check_positive(camera_constant, "camera_constant")
    check_positive(baseline, "baseline")
    return d.astype(np.float64)


def _pixel_offsets(shape: tuple[int, int], principal_point: tuple[float, float]
                   ) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape
    x0, y0 = (float(c) for c in principal_point)
    dx = np.arange(w, dtype=np.float64)[None, :] - x0
    dy = np.arange(h, dtype=np.float64)[:, None] - y0
    return dx, dy


def surface_position(
    d: np.ndarray,
    *,
    principal_point: tuple[float, float],
    camera_constant: float,
    baseline: float,
) -> tuple[np.ndarray, np.ndarray]:
    """3D position of the virtual gas surface per left pixel, in the left camera frame.

    Parameters
    ----------
    d : ndarray, shape (H, W), floating point
        Disparity in px (``x_R = x_L - d``), e.g. from
        :func:`processing.stereo.joint.joint_disparity`.
    principal_point : (float, float)
        (x0, y0) of the rectified left image in px.
    camera_constant : float
        s, the rectified camera constant (focal length) in px.
    baseline : float
        b, the stereo baseline in m.

    Returns
    -------
    position : ndarray, shape (H, W, 3), float32
        (X, Y, Z) in m: X = (x - x0) b / d, Y = (y - y0) b / d, Z = s b / d; 0 where
        invalid.
    valid : ndarray, shape (H, W), bool
        False where d <= 0 or d is not finite.

    Raises
    ------
    ValueError
        d not a 2-D float array; non-finite principal point; non-positive s or b.
    """
    d64 = _check_inputs(d, principal_point, camera_constant, baseline)
    dx, dy = _pixel_offsets(d64.shape, principal_point)
    with np.errstate(all="ignore"):
        valid = np.isfinite(d64) & (d64 > 0)
        inv = np.where(valid, float(baseline) / np.where(valid, d64, 1.0), 0.0)
        pos = np.stack([dx * inv, dy * inv, float(camera_constant) * inv], axis=-1)
        out = pos.astype(np.float32)
        valid &= np.all(np.isfinite(out), axis=-1)
    out[~valid] = 0.0
    return out, valid


def scene_flow_velocity(
    flow: np.ndarray,
    d: np.ndarray,
    d_change: np.ndarray,
    *,
    principal_point: tuple[float, float],
    camera_constant: float,
    baseline: float,
    dt: float,
) -> tuple[np.ndarray, np.ndarray]:
    """3D velocity V per left pixel by the paper's Eq. 4, in m/s.

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2), floating point
        Left optical flow w_L = (u, v) in px from t0 to t1.
    d : ndarray, shape (H, W), floating point
        Disparity d_L at t0 in px (``x_R = x_L - d``).
    d_change : ndarray, shape (H, W), floating point
        Disparity change d'_L in px (disparity at t1 along the flow is d + d').
    principal_point : (float, float)
        (x0, y0) of the rectified left image in px.
    camera_constant : float
        s in px.
    baseline : float
        b in m.
    dt : float
        Time between t0 and t1 in s, from the frames' timestamps (f = 1 / dt in Eq. 4).

    Returns
    -------
    velocity : ndarray, shape (H, W, 3), float32
        (V_X, V_Y, V_Z) in m/s in the left camera frame (X right, Y down, Z forward);
        0 where invalid.
    valid : ndarray, shape (H, W), bool
        False where d <= 0, d + d' <= 0, any input is non-finite, or the result would
        overflow float32.

    Raises
    ------
    ValueError
        Shapes that disagree, non-float inputs, non-positive s, b or dt.
    """
    d64 = _check_inputs(d, principal_point, camera_constant, baseline)
    check_positive(dt, "dt")
    for arr, name, shape in ((flow, "flow", (*d64.shape, 2)), (d_change, "d_change", d64.shape)):
        if not isinstance(arr, np.ndarray) or arr.shape != shape:
            got = getattr(arr, "shape", type(arr).__name__)
            raise ValueError(f"{name} must have shape {shape}, got {got}")
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"{name} must have a floating-point dtype, got {arr.dtype}")
    u = flow[..., 0].astype(np.float64)
    v = flow[..., 1].astype(np.float64)
    d1 = d64 + d_change.astype(np.float64)
    dx, dy = _pixel_offsets(d64.shape, principal_point)
    fb = float(baseline) / float(dt)
    s = float(camera_constant)
    with np.errstate(all="ignore"):
        valid = (np.isfinite(d64) & np.isfinite(d1) & np.isfinite(u) & np.isfinite(v)
                 & (d64 > 0) & (d1 > 0))
        inv0 = np.where(valid, 1.0 / np.where(valid, d64, 1.0), 0.0)
        inv1 = np.where(valid, 1.0 / np.where(valid, d1, 1.0), 0.0)
        uu = np.where(valid, u, 0.0)
        vv = np.where(valid, v, 0.0)
        vel = fb * np.stack([(dx + uu) * inv1 - dx * inv0,
                             (dy + vv) * inv1 - dy * inv0,
                             s * (inv1 - inv0)], axis=-1)
        out = vel.astype(np.float32)
        valid &= np.all(np.isfinite(out), axis=-1)
    out[~valid] = 0.0
    return out, valid
