"""Control curtains: surfaces that contain the viewing rays, and the mass flux through them.

A curtain is a straight segment in the (rectified, left) image. The viewing rays through
its pixels span a plane through the camera centre; every ray lies in it, so the column
density sigma_i (kg/m^2, integrated along ray i) times the component of the gas velocity
normal to that plane, times the metric width ds_i of the strip of rays one pixel step wide,
is the mass crossing the strip per second:

    Q = sum_i sigma_i (V_i . n) ds_i                                    [kg/s]

with, for a pixel ray r = (x - x0, y - y0, s) and the segment's unit image direction
e = (e_x, e_y, 0):

    n = (r x e) / |r x e|           (the same for every pixel of a straight segment)
    ds_i = Z_i / s * |e - (e . r^) r^|    (r^ = r / |r|; = Z_i / s on the optical axis)

and Z_i = s b / d_i the depth of the virtual gas surface (Eq. 4 geometry). The derivation:
the curtain is the ruled surface P(u, l) = l r^(u), whose area element is
l |dr^/du| du dl, and the column integrates c along l.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Curtain:
    """A straight image segment from ``start`` to ``end`` (x, y in px, left image).

    ``normal_sign`` orients the curtain: +1 keeps n = r x e, -1 flips it, so that a
    positive flux means gas leaving the source.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    normal_sign: float = 1.0

    @property
    def length_px(self) -> float:
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    def samples(self) -> np.ndarray:
        """Sample points about 1 px apart from ``start`` on (the end excluded), (N, 2) as (x, y).

        With integer end points of an axis-aligned curtain every sample is a pixel centre.
        """
        n = max(1, round(self.length_px))
        t = np.arange(n) / n
        p0, p1 = np.asarray(self.start, np.float64), np.asarray(self.end, np.float64)
        return p0[None] + t[:, None] * (p1 - p0)[None]

    @property
    def spacing_px(self) -> float:
        """Distance between samples, px (about 1)."""
        return self.length_px / max(1, round(self.length_px))

    def direction(self) -> np.ndarray:
        """Unit 3-vector e of the segment in the image plane, (e_x, e_y, 0)."""
        d = np.asarray(self.end, np.float64) - np.asarray(self.start, np.float64)
        length = float(np.hypot(*d))
        if length == 0.0:
            raise ValueError("a curtain needs two distinct end points")
        return np.array([d[0] / length, d[1] / length, 0.0])


def curtain_normal(curtain: Curtain, principal_point: tuple[float, float],
                   camera_constant: float) -> np.ndarray:
    """Unit normal n of the plane of viewing rays through ``curtain`` (camera frame)."""
    x0, y0 = principal_point
    r0 = np.array([curtain.start[0] - x0, curtain.start[1] - y0, camera_constant])
    n = np.cross(r0, curtain.direction())
    return curtain.normal_sign * n / np.linalg.norm(n)


def strip_widths(curtain: Curtain, depth_m: np.ndarray, principal_point: tuple[float, float],
                 camera_constant: float) -> np.ndarray:
    """Metric width ds_i (m) of each one-pixel strip of the curtain at depth Z_i.

    Parameters
    ----------
    curtain : Curtain
    depth_m : ndarray, shape (N,)
        Depth Z_i of the gas at each sample of ``curtain.samples()``, m.
    principal_point : (float, float)
        (x0, y0) in px.
    camera_constant : float
        s in px.

    Returns
    -------
    ndarray, shape (N,)
        ds_i = Z_i / s |e - (e . r^) r^| times the sample spacing (about 1 px).
    """
    pts = curtain.samples()
    e = curtain.direction()
    r = np.column_stack([pts[:, 0] - principal_point[0], pts[:, 1] - principal_point[1],
                         np.full(len(pts), camera_constant)])
    r_hat = r / np.linalg.norm(r, axis=1, keepdims=True)
    e_perp = e[None] - (r_hat @ e)[:, None] * r_hat
    return (np.asarray(depth_m, np.float64) * curtain.spacing_px / camera_constant
            * np.linalg.norm(e_perp, axis=1))


def sample_nearest(field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Values of ``field`` ((H, W) or (H, W, C)) at the nearest pixels of ``points`` (N, 2)."""
    return field[nearest_pixels(field.shape[:2], points)]


def nearest_pixels(shape: tuple[int, ...], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the pixels nearest to ``points`` (N, 2) as (x, y) in an image of
    ``shape`` (H, W), clipped to it: index several fields at the same samples with them."""
    h, w = shape
    # floor(x + 0.5), not rint: rint rounds halves to even and would skip pixels.
    xi = np.clip(np.floor(points[:, 0] + 0.5).astype(int), 0, w - 1)
    yi = np.clip(np.floor(points[:, 1] + 0.5).astype(int), 0, h - 1)
    return yi, xi


@dataclass(frozen=True)
class CurtainFlux:
    """Mass flux through one curtain in one frame.

    Attributes
    ----------
    rate_kg_s : float
        Q (kg/s); 0.0 when ``defined`` is False (never NaN).
    defined : bool
        False when too few of the curtain's gas samples had a valid velocity and depth.
    gas_samples : int
        Samples of the curtain inside the gas mask.
    filled_fraction : float
        Fraction of gas samples whose velocity/depth were filled from the curtain's valid
        samples (median) because their own were invalid.
    """

    rate_kg_s: float
    defined: bool
    gas_samples: int
    filled_fraction: float


def curtain_flux(curtain: Curtain, sigma_kg_m2: np.ndarray, velocity_m_s: np.ndarray,
                 depth_m: np.ndarray, valid: np.ndarray, gas_mask: np.ndarray, *,
                 principal_point: tuple[float, float], camera_constant: float,
                 max_filled: float = 0.5,
                 column_mask: np.ndarray | None = None) -> CurtainFlux:
    """Q = sum_i sigma_i (V_i . n) ds_i through one curtain (module docstring).

    Parameters
    ----------
    curtain : Curtain
    sigma_kg_m2 : ndarray, shape (H, W)
        Mass column density, kg/m^2.
    velocity_m_s : ndarray, shape (H, W, 3)
        3D gas velocity (Eq. 4), m/s, left camera frame.
    depth_m : ndarray, shape (H, W)
        Depth Z of the virtual gas surface, m.
    valid : ndarray, shape (H, W), bool
        Where velocity and depth are defined.
    gas_mask : ndarray, shape (H, W), bool
        Gas pixels; sigma outside is taken as 0 (noise, not gas).
    principal_point, camera_constant
        Rectified (x0, y0) and s, px.
    max_filled : float
        Largest fraction of gas samples with invalid velocity/depth that may be filled from
        the curtain's valid ones (their median) before the curtain is undefined.
    column_mask : ndarray, shape (H, W), bool, optional
        Pixels whose column density is gas although the motion segmentation missed them
        (faint plume edges: little contrast in the differential images). They count with
        their sigma and the median velocity and depth of the curtain's valid gas samples.

    Returns
    -------
    CurtainFlux
    """
    at = nearest_pixels(gas_mask.shape, curtain.samples())  # every field at the same pixels
    gas = gas_mask[at].astype(bool)
    n_gas = int(gas.sum())
    faint = np.zeros_like(gas) if column_mask is None else column_mask[at].astype(bool)
    if n_gas == 0:
        if faint.any():  # gas without a velocity: undefined, not zero
            return CurtainFlux(0.0, False, 0, 1.0)
        return CurtainFlux(0.0, True, 0, 0.0)  # no gas crosses: a defined zero
    ok = valid[at].astype(bool) & gas
    n_ok = int(ok.sum())
    filled = 1.0 - n_ok / n_gas
    if n_ok == 0 or filled > max_filled:
        return CurtainFlux(0.0, False, n_gas, filled)
    counted = gas | faint
    sigma = np.where(counted, sigma_kg_m2[at], 0.0)
    vel = velocity_m_s[at].astype(np.float64)
    z = depth_m[at].astype(np.float64)
    vel[~ok] = np.median(vel[ok], axis=0)
    z[~ok] = np.median(z[ok])
    n = curtain_normal(curtain, principal_point, camera_constant)
    ds = strip_widths(curtain, z, principal_point, camera_constant)
    q = float(np.sum(sigma * (vel @ n) * ds))
    return CurtainFlux(q if np.isfinite(q) else 0.0, bool(np.isfinite(q)), n_gas, filled)
