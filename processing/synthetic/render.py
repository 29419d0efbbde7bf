"""Stereo OGI rendering of a gas concentration volume, with ground truth (paper Eq. 1, 4; Sec. 5.1).

Geometry (one convention, used everywhere in ogiflow's synthetic data)
--------------------------------------------------------------------
Camera frame of the LEFT camera: X right, Y down, Z forward (metres), origin at its optical
centre. The right camera is the left one translated to X = +b (parallel image planes, same
intrinsics). A point (X, Y, Z) projects (pinhole, pixel centres at integer coordinates) to

    x_L = c_x + s X / Z,        y_L = c_y + s Y / Z,
    x_R = c_x + s (X - b) / Z,  y_R = y_L,

so the disparity ``d = x_L - x_R = s b / Z > 0`` for every point in front of the cameras. This
is the sign Eq. 4 needs (``Z = s b / d``, ``V_Z = f b (s/(d + d') - s/d)``). The paper's text
writes ``x_R = x_L + p_L`` with ``p_L = (d_L, 0)``; with our sign a matcher must look for the
right-image correspondence at ``x_L - d``. Default principal point: the image centre
``((W - 1) / 2, (H - 1) / 2)``.

Radiometry (Eq. 1)
------------------
Each ray sees a black-body background (temperature ``t_bg_k``, or a moving object's temperature
where one is hit) through the gas, which is a black body at ``t_gas_k`` with the Lambert-Beer
transmittance ``tau = exp(-alpha_g * integral c dl)`` (``c`` in ppm, ``l`` in m):

    L = L_BB(T_bg) tau + L_BB(T_gas) (1 - tau)

with ``L_BB`` the Planck radiance integrated over the camera band (3.2-3.4 um) in W/(m^2 sr).
Raw counts are ``round(offset + gain * L)`` clipped to uint16, one (gain, offset) per camera.

Ground truth (left camera, per pixel, along the pixel's ray)
------------------------------------------------------------
- column density ``integral c dl`` in ppm*m;
- path-averaged, concentration-weighted velocity ``V* = integral c V dl / integral c dl``
  (m/s, left camera frame) - the quantity Eq. 4 measures (Sec. 3, last paragraph);
- concentration-weighted mean position ``P* = Z* (x, y, 1)`` on the ray with
  ``Z* = integral c Z dl / integral c dl`` (m);
- gas mask: column density >= the NECL (ppm*m).
Pixels whose ray meets no gas have NaN velocity and position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

# The radiometry and camera-effect part of rendering lives in imaging; its names are
# re-exported here because a renderer's users reach for them together with the geometry.
from processing.synthetic.imaging import (  # noqa: F401
    Background,
    CountsModel,
    MovingObject,
    Radiometry,
    background_radiance,
    band_radiance,
    band_radiance_derivative,
    radiance_image,
    shift_image,
    to_counts,
)

_H_PLANCK = 6.62607015e-34
_C_LIGHT = 2.99792458e8
_K_BOLTZMANN = 1.380649e-23

#: Volume fraction in ppm of pure gas.
PPM = 1e6


@dataclass(frozen=True)
class StereoCamera:
    """Intrinsics shared by both cameras and the baseline (defaults: paper Sec. 5.1).

    Parameters
    ----------
    width, height : int
        Image size in px.
    s_px : float
        Camera constant (focal length) s in px.
    cx_px, cy_px : float or None
        Principal point in px; None means the image centre ``((W-1)/2, (H-1)/2)``.
    b_m : float
        Baseline b in m; the right camera sits at X = +b in the left camera frame.
    k1, k2 : float
        Radial lens distortion of both cameras on normalised coordinates
        (``x_d = x_u (1 + k1 r^2 + k2 r^4)``); 0 = ideal pinhole (default).
    """

    width: int = 320
    height: int = 240
    s_px: float = 780.0
    cx_px: float | None = None
    cy_px: float | None = None
    b_m: float = 0.2
    k1: float = 0.0
    k2: float = 0.0

    @property
    def cx(self) -> float:
        """Principal point x in px."""
        return (self.width - 1) / 2.0 if self.cx_px is None else float(self.cx_px)

    @property
    def cy(self) -> float:
        """Principal point y in px."""
        return (self.height - 1) / 2.0 if self.cy_px is None else float(self.cy_px)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        if self.width < 2 or self.height < 2:
            raise ValueError(f"image size must be >= 2x2, got {self.width}x{self.height}")
        if not self.s_px > 0 or not self.b_m > 0:
            raise ValueError(f"s_px and b_m must be > 0, got {self.s_px}, {self.b_m}")


@dataclass(frozen=True)
class Volume:
    """Placement of the simulation grid in the left camera frame (axes aligned).

    Parameters
    ----------
    origin_m : (3,)
        Position (X, Y, Z) of the grid's corner (cell [0, 0, 0]'s low corner), m.
    voxel_m : float
        Cell edge in m.
    shape : (nz, ny, nx)
    """

    origin_m: tuple[float, float, float]
    voxel_m: float
    shape: tuple[int, int, int]


# --------------------------------------------------------------------------------------------
# geometry


def _distort(xn: np.ndarray, yn: np.ndarray, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
    r2 = xn * xn + yn * yn
    f = 1.0 + k1 * r2 + k2 * r2 * r2
    return xn * f, yn * f


def _undistort(
    xd: np.ndarray, yd: np.ndarray, k1: float, k2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Invert the radial model by fixed-point iteration (converges for moderate distortion)."""
    xu, yu = xd.copy(), yd.copy()
    for _ in range(30):
        r2 = xu * xu + yu * yu
        f = 1.0 + k1 * r2 + k2 * r2 * r2
        xu, yu = xd / f, yd / f
    return xu, yu


def project_points(camera: StereoCamera, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project points of the left camera frame into both images.

    Parameters
    ----------
    camera : StereoCamera
    xyz : (..., 3) float array
        Points (X, Y, Z) in m, left camera frame, Z > 0.

    Returns
    -------
    left, right : (..., 2) float64 arrays
        Pixel coordinates (x, y) in each image; ``left[..., 0] - right[..., 0] = s b / Z``
        when there is no lens distortion.
    """
    p = np.asarray(xyz, dtype=float)
    if p.shape[-1] != 3:
        raise ValueError(f"xyz must have a last axis of 3, got shape {p.shape}")
    if np.any(p[..., 2] <= 0):
        raise ValueError("points must lie in front of the cameras (Z > 0)")
    out = []
    for x_offset in (0.0, camera.b_m):
        xn = (p[..., 0] - x_offset) / p[..., 2]
        yn = p[..., 1] / p[..., 2]
        xd, yd = _distort(xn, yn, camera.k1, camera.k2)
        out.append(np.stack((camera.cx + camera.s_px * xd, camera.cy + camera.s_px * yd), -1))
    return out[0], out[1]


def ray_directions(camera: StereoCamera,
                   shift_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Direction of each pixel's ray (x_n, y_n, 1), float64 (H, W, 3), lens distortion removed.

    A point at depth Z on the ray of pixel (x, y) is ``Z * dirs[y, x]``. ``shift_px`` = (dx,
    dy) moves the detector so that the image content is displaced by +shift (camera jitter):
    pixel (x, y) then sees what the unshifted pixel (x - dx, y - dy) sees.
    """
    camera.validate()
    ys, xs = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    xs -= float(shift_px[0])
    ys -= float(shift_px[1])
    xd = (xs - camera.cx) / camera.s_px
    yd = (ys - camera.cy) / camera.s_px
    if camera.k1 or camera.k2:
        xd, yd = _undistort(xd, yd, camera.k1, camera.k2)
    return np.stack((xd, yd, np.ones_like(xd)), axis=-1)


# --------------------------------------------------------------------------------------------
# ray marching


@numba.njit(cache=True, inline="always")
def _interp8(
    f: np.ndarray, k: int, j: int, i: int, w000: float, w001: float, w010: float,
    w011: float, w100: float, w101: float, w110: float, w111: float,
) -> float:
    """Trilinear combination of the 8 corners of cell [k, j, i] with precomputed weights."""
    return (
        w000 * f[k, j, i] + w001 * f[k, j, i + 1] + w010 * f[k, j + 1, i]
        + w011 * f[k, j + 1, i + 1] + w100 * f[k + 1, j, i] + w101 * f[k + 1, j, i + 1]
        + w110 * f[k + 1, j + 1, i] + w111 * f[k + 1, j + 1, i + 1]
    )


@numba.njit(cache=True)
def _march(
    c: np.ndarray,
    vel: np.ndarray,
    with_velocity: bool,
    cam_vol: np.ndarray,
    dirs: np.ndarray,
    h: float,
    step_cells: float,
    column: np.ndarray,
    zsum: np.ndarray,
    vsum: np.ndarray,
    vzsum: np.ndarray,
) -> None:
    """Integrate c (and c Z, c V, c V Z) along every pixel's ray through the volume
    (midpoint rule).

    ``cam_vol`` is the camera centre in volume coordinates (m); a ray is ``cam_vol + t d``
    with ``d_z = 1``, so t is the depth Z from this camera. Outputs are (H, W) / (H, W, 3).
    """
    nz, ny, nx = c.shape
    lo = np.zeros(3)
    hi = np.array((nx * h, ny * h, nz * h))
    hgt, wid = dirs.shape[0], dirs.shape[1]
    for y in range(hgt):
        for x in range(wid):
            t0 = 0.0
            t1 = 1e30
            for a in range(3):
                d = dirs[y, x, a]
                o = cam_vol[a]
                if abs(d) < 1e-15:
                    if o < lo[a] or o > hi[a]:
                        t1 = -1.0
                else:
                    ta = (lo[a] - o) / d
                    tb = (hi[a] - o) / d
                    if ta > tb:
                        ta, tb = tb, ta
                    t0 = max(t0, ta)
                    t1 = min(t1, tb)
            column[y, x] = 0.0
            zsum[y, x] = 0.0
            if with_velocity:
                for a in range(3):
                    vsum[y, x, a] = 0.0
                    vzsum[y, x, a] = 0.0
            if t1 <= t0:
                continue
            norm = math.sqrt(dirs[y, x, 0] ** 2 + dirs[y, x, 1] ** 2 + dirs[y, x, 2] ** 2)
            length = (t1 - t0) * norm
            n = max(1, math.ceil(length / (step_cells * h)))
            dt = (t1 - t0) / n
            dl = dt * norm
            acc = 0.0
            accz = 0.0
            av0 = 0.0
            av1 = 0.0
            av2 = 0.0
            az0 = 0.0
            az1 = 0.0
            az2 = 0.0
            for m in range(n):
                t = t0 + (m + 0.5) * dt
                gx = (cam_vol[0] + t * dirs[y, x, 0]) / h - 0.5
                gy = (cam_vol[1] + t * dirs[y, x, 1]) / h - 0.5
                gz = (cam_vol[2] + t * dirs[y, x, 2]) / h - 0.5
                gx = min(max(gx, 0.0), nx - 1.0)
                gy = min(max(gy, 0.0), ny - 1.0)
                gz = min(max(gz, 0.0), nz - 1.0)
                i = min(int(gx), nx - 2)
                j = min(int(gy), ny - 2)
                k = min(int(gz), nz - 2)
                tx = gx - i
                ty = gy - j
                tz = gz - k
                w000 = (1 - tx) * (1 - ty) * (1 - tz)
                w001 = tx * (1 - ty) * (1 - tz)
                w010 = (1 - tx) * ty * (1 - tz)
                w011 = tx * ty * (1 - tz)
                w100 = (1 - tx) * (1 - ty) * tz
                w101 = tx * (1 - ty) * tz
                w110 = (1 - tx) * ty * tz
                w111 = tx * ty * tz
                cv = _interp8(c, k, j, i, w000, w001, w010, w011, w100, w101, w110, w111)
                if cv <= 0.0:
                    continue
                acc += cv * dl
                accz += cv * t * dl
                if with_velocity:
                    f0 = cv * dl * _interp8(vel[0], k, j, i, w000, w001, w010, w011,
                                            w100, w101, w110, w111)
                    f1 = cv * dl * _interp8(vel[1], k, j, i, w000, w001, w010, w011,
                                            w100, w101, w110, w111)
                    f2 = cv * dl * _interp8(vel[2], k, j, i, w000, w001, w010, w011,
                                            w100, w101, w110, w111)
                    av0 += f0
                    av1 += f1
                    av2 += f2
                    az0 += f0 * t
                    az1 += f1 * t
                    az2 += f2 * t
            column[y, x] = acc
            zsum[y, x] = accz
            if with_velocity:
                vsum[y, x, 0] = av0
                vsum[y, x, 1] = av1
                vsum[y, x, 2] = av2
                vzsum[y, x, 0] = az0
                vzsum[y, x, 1] = az1
                vzsum[y, x, 2] = az2


def _check_volume(c: np.ndarray, volume: Volume) -> None:
    if c.ndim != 3 or tuple(c.shape) != tuple(volume.shape):
        raise ValueError(f"concentration shape {c.shape} does not match volume {volume.shape}")


def column_integrals(
    c: np.ndarray,
    volume: Volume,
    dirs: np.ndarray,
    camera_x_m: float = 0.0,
    velocity: np.ndarray | None = None,
    step_cells: float = 0.5,
    moment_out: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Line integrals along the rays of a camera at (camera_x_m, 0, 0) in the left frame.

    Parameters
    ----------
    c : (nz, ny, nx) float array
        Concentration (any unit u) on the cell centres.
    volume : Volume
    dirs : (H, W, 3) float64
        Ray directions with d_z = 1 (:func:`ray_directions`).
    camera_x_m : float
        X of the camera centre (0 left, b right).
    velocity : (3, nz, ny, nx) float array, optional
        Cell-centred velocity (X, Y, Z) in m/s.
    step_cells : float
        Marching step in cells (0.5 samples every cell twice).
    moment_out : (H, W, 3) float64 array, optional
        Filled (with ``velocity``) with the flux moment ``integral c V Z dl`` in u*m^3/s:
        the exact flux of c through a curtain of viewing rays is built from it
        (:func:`processing.emission.truth.true_curtain_flux`).

    Returns
    -------
    column : (H, W) float64
        ``integral c dl`` in u*m.
    zsum : (H, W) float64
        ``integral c Z dl`` in u*m^2.
    vsum : (H, W, 3) float64 or None
        ``integral c V dl`` in u*m^2/s (only with ``velocity``).
    """
    _check_volume(c, volume)
    h = float(volume.voxel_m)
    cam = np.array([camera_x_m, 0.0, 0.0]) - np.asarray(volume.origin_m, dtype=float)
    hgt, wid = dirs.shape[:2]
    column = np.empty((hgt, wid))
    zsum = np.empty((hgt, wid))
    with_v = velocity is not None
    if with_v:
        velocity = np.ascontiguousarray(velocity, dtype=float)
        if velocity.shape != (3, *c.shape):
            raise ValueError(f"velocity must have shape (3, *{c.shape}), got {velocity.shape}")
        vsum = np.empty((hgt, wid, 3))
        vzsum = np.empty((hgt, wid, 3)) if moment_out is None else moment_out
        if vzsum.shape != (hgt, wid, 3) or vzsum.dtype != np.float64:
            raise ValueError(f"moment_out must be float64 {(hgt, wid, 3)}")
    else:
        velocity = np.zeros((3, 2, 2, 2))
        vsum = np.zeros((1, 1, 3))
        vzsum = np.zeros((1, 1, 3))
    # zsum integrates depth measured from the camera; camera_z = 0 in the left frame.
    _march(
        np.ascontiguousarray(c, dtype=float), velocity, with_v, cam,
        np.ascontiguousarray(dirs, dtype=float), h, step_cells, column, zsum, vsum, vzsum,
    )
    return column, zsum, (vsum if with_v else None)


@dataclass
class GroundTruth:
    """Left-camera ground truth of one frame (see module docstring).

    Attributes
    ----------
    velocity : (H, W, 3) float32, m/s (NaN where no gas on the ray)
    position : (H, W, 3) float32, m (NaN where no gas on the ray)
    mask : (H, W) bool, column density >= NECL
    column_density_ppm_m : (H, W) float32
    flux_moment_kg_s : (H, W, 3) float32 or None
        ``integral c V Z dl`` along the ray with c in kg/m^3 (so kg/s): with the curtain
        geometry of :mod:`processing.emission.curtains`, the exact mass flux through a
        curtain of viewing rays is sum_i (M_i . n) |e_perp,i| / s.
    release_rate_g_s : float or None
        Mean release rate of the sources over this frame's interval, g/s.
    """

    velocity: np.ndarray
    position: np.ndarray
    mask: np.ndarray
    column_density_ppm_m: np.ndarray
    flux_moment_kg_s: np.ndarray | None = None
    release_rate_g_s: float | None = None


def ground_truth(
    column_ppm_m: np.ndarray,
    zsum: np.ndarray,
    vsum: np.ndarray,
    dirs: np.ndarray,
    necl_ppm_m: float,
) -> GroundTruth:
    """Turn the left camera's line integrals into V*, P*, the mask and the column density.

    ``zsum`` and ``vsum`` must be integrated with the same concentration unit as the column.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        has_gas = column_ppm_m > 0
        inv = np.where(has_gas, 1.0 / np.where(has_gas, column_ppm_m, 1.0), np.nan)
        vel = vsum * inv[..., None]
        z_mean = zsum * inv
    pos = z_mean[..., None] * dirs
    return GroundTruth(
        velocity=vel.astype(np.float32),
        position=pos.astype(np.float32),
        mask=column_ppm_m >= necl_ppm_m,
        column_density_ppm_m=column_ppm_m.astype(np.float32),
    )
