"""What the cameras see besides the gas: backgrounds, moving objects, radiometry (Eq. 1), counts.

Backgrounds (:class:`Background`)
---------------------------------
- ``uniform``: one black body at ``Radiometry.t_bg_k`` (the paper's Sec. 5.1 scenes). It has
  no texture, so no registration can measure camera jitter on it.
- ``plant``: a wall of plant equipment at depth ``depth_m`` - horizontal and vertical pipes,
  tanks with cylindrical shading, flanges - at temperatures a few K around ``t_bg_k`` with
  edges about 2 px wide (optics blur), drawn from ``seed``. Both cameras see the same wall
  with the disparity s b / depth, and jitter moves it like a real scene: the textured case
  of a site.
- ``sky``: clear sky at infinity (no disparity): an effective temperature falling with
  elevation from ``sky_horizon_k`` by ``sky_gradient_k_per_rad`` and faint, large, smooth
  cloud structure. Nearly featureless: the open-sky case of vents and stacks.

Every background is a function of the ray direction, so a jittered camera is rendered
exactly (the background evaluated along the shifted rays, see
:func:`processing.synthetic.render.ray_directions`), not by interpolating an image.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

_H_PLANCK = 6.62607015e-34
_C_LIGHT = 2.99792458e8
_K_BOLTZMANN = 1.380649e-23

BACKGROUND_KINDS = ("uniform", "plant", "sky")


@dataclass(frozen=True)
class CountsModel:
    """Linear radiometric response of one camera: counts = offset + gain * L (L in W/(m^2 sr))."""

    gain: float = 4.0e5
    offset: float = 2000.0


@dataclass(frozen=True)
class Radiometry:
    """Radiometric scene parameters of Eq. 1.

    Parameters
    ----------
    t_bg_k, t_gas_k : float
        Background and gas temperatures in K.
    alpha_per_ppm_m : float
        Band-averaged absorption coefficient alpha_g, natural log, per ppm*m (the default is
        an approximate band average of methane in 3.2-3.4 um).
    band_um : (float, float)
        Spectral band of the cameras in um.
    gas_density_kg_m3 : float
        Density of the pure gas, to turn kg/m^3 into ppm by volume.
    """

    t_bg_k: float = 300.0
    t_gas_k: float = 285.0
    alpha_per_ppm_m: float = 5.0e-5
    band_um: tuple[float, float] = (3.2, 3.4)
    gas_density_kg_m3: float = 0.679


@dataclass(frozen=True)
class MovingObject:
    """A warm/cold disk in a plane of constant Z behind the gas, moving in X (optional).

    ``center_m`` (m, in the plane at ``z_m``) is its centre at t = 0. With ``back_forth_s``
    = 0 it moves on a straight line at ``velocity_m_s``; with ``back_forth_s`` > 0 it walks
    at that velocity for half the period and back for the other half (a worker or a vehicle
    going to and fro), so a scene looped over a multiple of the period has no jump.
    """

    z_m: float = 4.0
    radius_m: float = 0.25
    center_m: tuple[float, float] = (-0.6, 0.0)
    velocity_m_s: tuple[float, float] = (1.0, 0.0)
    t_k: float = 310.0
    back_forth_s: float = 0.0

    def center_at(self, t_s: float) -> tuple[float, float]:
        """Centre (X, Y) of the disk at time ``t_s``, m."""
        travel = float(t_s)
        if self.back_forth_s > 0:
            half = self.back_forth_s / 2.0
            phase = float(t_s) % self.back_forth_s
            travel = phase if phase <= half else self.back_forth_s - phase
        return (self.center_m[0] + self.velocity_m_s[0] * travel,
                self.center_m[1] + self.velocity_m_s[1] * travel)


@dataclass(frozen=True)
class Background:
    """The scene behind the gas (module docstring).

    Parameters
    ----------
    kind : str
        ``uniform``, ``plant`` or ``sky``.
    depth_m : float
        Distance of the plant wall (``plant`` only), m.
    seed : int
        Layout of the plant wall.
    contrast_k : float
        Typical temperature excursion of the wall's equipment from ``t_bg_k``, K.
    sky_horizon_k, sky_gradient_k_per_rad : float
        Sky temperature at the optical axis and its fall per radian of elevation.
    drift_k, drift_period_s : float
        Slow drift of the whole background's temperature (sun, clouds, the day):
        ``drift_k * sin(2 pi t / drift_period_s)`` K added at time t; 0 = none. A scene
        looped over a multiple of the period has no jump.
    """

    kind: str = "uniform"
    depth_m: float = 12.0
    seed: int = 0
    contrast_k: float = 3.0
    sky_horizon_k: float = 265.0
    sky_gradient_k_per_rad: float = 40.0
    drift_k: float = 0.0
    drift_period_s: float = 600.0

    def drift_at(self, t_s: float) -> float:
        """Temperature offset of the background at time ``t_s``, K."""
        if self.drift_k == 0.0:
            return 0.0
        return float(self.drift_k * np.sin(2.0 * np.pi * t_s / self.drift_period_s))

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        if self.kind not in BACKGROUND_KINDS:
            raise ValueError(f"background must be one of {', '.join(BACKGROUND_KINDS)}, "
                             f"got {self.kind!r}")
        if not self.depth_m > 0:
            raise ValueError(f"background depth_m must be > 0, got {self.depth_m}")
        if not self.drift_period_s > 0:
            raise ValueError(f"background drift_period_s must be > 0, got {self.drift_period_s}")


def band_radiance(t_k: float, band_um: tuple[float, float] = (3.2, 3.4)) -> float:
    """Black-body radiance integrated over ``band_um``, W/(m^2 sr) (Planck's law)."""
    lam = np.linspace(band_um[0], band_um[1], 401) * 1e-6
    spectral = 2 * _H_PLANCK * _C_LIGHT**2 / lam**5 / np.expm1(
        _H_PLANCK * _C_LIGHT / (lam * _K_BOLTZMANN * t_k)
    )
    return float(np.sum(0.5 * (spectral[1:] + spectral[:-1]) * np.diff(lam)))  # trapezoid rule


def band_radiance_derivative(t_k: float, band_um: tuple[float, float] = (3.2, 3.4)) -> float:
    """d L_BB / dT at ``t_k``, W/(m^2 sr K) (central difference), for NETD-like noise."""
    return (band_radiance(t_k + 0.05, band_um) - band_radiance(t_k - 0.05, band_um)) / 0.1


@lru_cache(maxsize=4)
def _radiance_table(band_um: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(T, L_BB(T)) on 150-400 K in 0.05 K steps: per-pixel Planck integrals by lookup."""
    t = np.arange(150.0, 400.0001, 0.05)
    return t, np.array([band_radiance(float(x), band_um) for x in t])


def temperature_radiance(t_k: np.ndarray, band_um: tuple[float, float]) -> np.ndarray:
    """L_BB of a temperature map (piecewise linear in 0.05 K steps, rel. error < 1e-6)."""
    t, lut = _radiance_table(tuple(band_um))
    return np.interp(np.asarray(t_k, dtype=float), t, lut)


def _soft_band(x: np.ndarray, lo: float, hi: float, edge: float) -> np.ndarray:
    """~1 inside [lo, hi], ~0 outside, with tanh edges of width ``edge`` (optics blur)."""
    return 0.25 * (1 + np.tanh((x - lo) / edge)) * (1 + np.tanh((hi - x) / edge))


def _row_and_column(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u`` as one row (1, W) and ``v`` as one column (H, 1) when (H, W) ``u`` is the same
    in every row and ``v`` the same in every column, else both as given.

    Through an undistorted lens (jittered or not) a pixel's ray lies on its column's and
    its row's planes, so a background that is a sum of products of functions of x and of y
    can be evaluated on W + H values instead of W * H and broadcast: every element is the
    same product of the same numbers as over the full grid, bit for bit (a rendered frame
    is unchanged; a distorted lens takes the full grid).
    """
    if u.ndim == 2 and v.ndim == 2 and u.shape == v.shape and u.shape[0] > 1:
        row, column = u[:1], v[:, :1]
        if (u == row).all() and (v == column).all():
            return np.ascontiguousarray(row), np.ascontiguousarray(column)
    return u, v


def plant_wall_temperature(x_m: np.ndarray, y_m: np.ndarray, t_bg_k: float,
                           background: Background) -> np.ndarray:
    """Temperature (K) of the plant wall at wall coordinates (X, Y) in m (module docstring),
    (H, W) for (H, W) ``x_m`` and ``y_m``.

    The layout (pipes, tanks, flanges) is drawn from ``background.seed``; edges are ~3 cm
    wide, about 2 px at the default 12 m. Every term is a function of X, of Y or a product
    of the two, evaluated on one row and one column where the grid allows
    (:func:`_row_and_column`): over every pixel, the tanh edges would take most of a plant
    scene's rendering time.
    """
    rng = np.random.default_rng([background.seed, 77])
    c = background.contrast_k
    edge = 0.01 * background.depth_m / 6.0
    temp = np.full(np.broadcast_shapes(np.shape(x_m), np.shape(y_m)), float(t_bg_k))
    x_m, y_m = _row_and_column(np.asarray(x_m, float), np.asarray(y_m, float))
    # slow structure of the wall itself (sun, shade)
    for _ in range(3):
        kx, ky = rng.uniform(0.5, 2.0, 2)
        ph = rng.uniform(0, 2 * np.pi)
        temp += 0.2 * c * np.sin(kx * x_m + ky * y_m + ph)
    for _ in range(4):  # tanks: wide vertical cylinders, shaded across
        x0 = rng.uniform(-6.0, 6.0)
        half = rng.uniform(0.4, 1.0)
        top = rng.uniform(-2.0, 0.5)
        shade = np.cos(np.clip((x_m - x0) / half, -1, 1) * 1.2)
        temp += rng.uniform(-1.0, 1.0) * c * shade * _soft_band(x_m, x0 - half, x0 + half, edge) \
            * _soft_band(y_m, top, 9.0, edge)
    for _ in range(7):  # horizontal pipes
        y0 = rng.uniform(-2.0, 2.0)
        r = rng.uniform(0.04, 0.15)
        prof = np.sqrt(np.clip(1 - ((y_m - y0) / r) ** 2, 0, 1))
        temp += rng.uniform(-1.0, 2.0) * c * (0.4 + 0.6 * prof) * _soft_band(
            y_m, y0 - r, y0 + r, edge)
    for _ in range(6):  # vertical pipes with a flange each
        x0 = rng.uniform(-4.0, 4.0)
        r = rng.uniform(0.03, 0.1)
        temp += rng.uniform(-1.0, 1.5) * c * _soft_band(x_m, x0 - r, x0 + r, edge)
        yf = rng.uniform(-1.5, 1.5)
        temp += 0.5 * c * _soft_band(x_m, x0 - 2 * r, x0 + 2 * r, edge) * _soft_band(
            y_m, yf - 0.04, yf + 0.04, edge)
    return temp


def sky_temperature(dirs: np.ndarray, background: Background) -> np.ndarray:
    """Effective sky temperature (K) per ray direction (x_n, y_n, 1): at infinity."""
    x_n, y_n = _row_and_column(dirs[..., 0], dirs[..., 1])
    elevation = -np.arctan(y_n)  # Y points down
    azimuth = np.arctan(x_n)
    temp = np.broadcast_to(
        background.sky_horizon_k - background.sky_gradient_k_per_rad * elevation,
        dirs.shape[:-1]).copy()
    # faint cumulus-like structure, tens of pixels across: not enough to register on
    rng = np.random.default_rng([background.seed, 78])
    for _ in range(4):
        kx, ky = rng.uniform(5.0, 15.0, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        temp += 0.15 * np.sin(kx * azimuth + ph[0]) * np.sin(ky * elevation + ph[1])
    return temp


def background_radiance(
    camera: object,
    radiometry: Radiometry,
    dirs: np.ndarray,
    camera_x_m: float,
    t_s: float,
    moving_object: MovingObject | None,
    background: Background | None = None,
) -> np.ndarray:
    """Background radiance per pixel (H, W) float64 W/(m^2 sr) for a camera at X =
    ``camera_x_m``: the scene's background and the moving object's black body where a ray
    hits it. ``camera`` is unused (kept for the call signature of the renderer)."""
    bg_kind = "uniform" if background is None else background.kind
    drift = 0.0 if background is None else background.drift_at(t_s)
    if bg_kind == "uniform":
        bg = np.full(dirs.shape[:2],
                     band_radiance(radiometry.t_bg_k + drift, radiometry.band_um))
    elif bg_kind == "plant":
        assert background is not None
        z = background.depth_m
        temp = plant_wall_temperature(camera_x_m + z * dirs[..., 0], z * dirs[..., 1],
                                      radiometry.t_bg_k, background)
        bg = temperature_radiance(temp + drift, radiometry.band_um)
    else:
        assert background is not None
        bg = temperature_radiance(sky_temperature(dirs, background) + drift,
                                  radiometry.band_um)
    if moving_object is not None:
        mo = moving_object
        x = camera_x_m + mo.z_m * dirs[..., 0]
        y = mo.z_m * dirs[..., 1]
        cxo, cyo = mo.center_at(t_s)
        # a soft rim (~1.5 cm) like every other edge of the scene: optics blur
        r = np.sqrt((x - cxo) ** 2 + (y - cyo) ** 2)
        inside = 0.5 * (1 + np.tanh((mo.radius_m - r) / (0.0025 * mo.z_m)))
        l_obj = band_radiance(mo.t_k, radiometry.band_um)
        bg = bg * (1 - inside) + l_obj * inside
    return bg


def radiance_image(
    column_ppm_m: np.ndarray, background: np.ndarray, radiometry: Radiometry
) -> np.ndarray:
    """Eq. 1: ``L = L_bg tau + L_gas (1 - tau)``, ``tau = exp(-alpha_g * column)``; (H, W)."""
    tau = np.exp(-radiometry.alpha_per_ppm_m * column_ppm_m)
    l_gas = band_radiance(radiometry.t_gas_k, radiometry.band_um)
    return background * tau + l_gas * (1.0 - tau)


def shift_image(img: np.ndarray, shift_xy: tuple[float, float]) -> np.ndarray:
    """Translate an image by a sub-pixel (dx, dy) - frame jitter of the rendered gas column.

    Content moves by +shift (as :func:`processing.synthetic.geometry.ray_directions` moves
    the background); quintic spline interpolation, edges replicated. A camera's jitter
    moves the gas without blurring it: the bilinear warp used before (cv2, positions rounded
    to 1/32 px) low-passed each frame's gas by its own fractional shift, so consecutive
    frames and the two cameras saw differently blurred gas while the background, rendered
    through shifted rays, stayed sharp. That alone took the chain's V_Z on an out-of-plane
    scene from 5 % to 15-40 % RMVE under 0.3 px jitter (measured, robustness
    matrix); the spline keeps a Gaussian blob's peak within 0.1 % at a half-pixel shift.
    """
    return ndimage.shift(np.asarray(img, np.float64), (float(shift_xy[1]), float(shift_xy[0])),
                         order=5, mode="nearest")


def to_counts(radiance: np.ndarray, model: CountsModel) -> np.ndarray:
    """Raw uint16 counts ``round(offset + gain * L)``, clipped to [0, 65535]."""
    counts = np.rint(model.offset + model.gain * radiance)
    return np.clip(counts, 0, 65535).astype(np.uint16)
