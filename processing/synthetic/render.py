"""Stereo OGI rendering of a gas concentration volume, with ground truth (paper Eq. 1, 4; Sec. 5.1).

Geometry: :mod:`processing.synthetic.geometry` (left camera frame, d = x_L - x_R = s b / Z > 0).

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

from processing.synthetic.geometry import (  # noqa: F401 (re-exported, as above)
    StereoCamera,
    project_points,
    ray_directions,
)
from processing.synthetic.grid import cell_and_fraction

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
                i, tx = cell_and_fraction(gx, nx)
                j, ty = cell_and_fraction(gy, ny)
                k, tz = cell_and_fraction(gz, nz)
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
