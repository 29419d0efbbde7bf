"""Radiometric calibration: each camera's characteristic curve against a black body.

An OGI camera's raw counts grow (nearly) linearly with the in-band radiance reaching the
detector. Two cameras differ in gain and offset, and the scene-flow data terms (paper
Eq. 3a-3d) compare intensities *across* the cameras, so both are mapped to the same physical
quantity first (paper Sec. 4.1 and its ref. [16]).

Model (per camera, per pixel-average over a central region of interest)::

    counts = offset + gain * L                       (linear, default)
    counts = offset + gain * L + curvature * L**2    (quadratic, optional)

with L the black body's in-band radiance in W m^-2 sr^-1, i.e. Planck's spectral radiance
integrated over the camera's band (3.2-3.4 um). ``gain`` is in counts per W m^-2 sr^-1,
``offset`` in counts, ``curvature`` in counts per (W m^-2 sr^-1)^2. Emissivity of the black
body is taken as 1 unless given.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Physical constants (CODATA 2018, exact SI values).
PLANCK_H = 6.62607015e-34  # J s
LIGHT_C = 299792458.0  # m s^-1
BOLTZMANN_K = 1.380649e-23  # J K^-1

#: The OGI cameras' spectral band, metres.
OGI_BAND_M: tuple[float, float] = (3.2e-6, 3.4e-6)

#: Gauss-Legendre nodes used for the band integral; the integrand is smooth over a band of a
#: few 100 nm, and 32 nodes reach machine precision (checked against scipy.integrate.quad).
_GL_NODES = 32
# Computed once: the nodes cost an eigenvalue problem, ten times the integral itself (and
# the emission rate integrates the gas's band radiance on every rate).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_NODES)


def planck_spectral_radiance(wavelength_m: np.ndarray, temperature_k: np.ndarray) -> np.ndarray:
    """Planck's law, spectral radiance of a black body per unit wavelength.

    Parameters
    ----------
    wavelength_m : array_like
        Wavelength, metres.
    temperature_k : array_like
        Temperature, kelvin (> 0); broadcast against ``wavelength_m``.

    Returns
    -------
    numpy.ndarray, float64
        B_lambda in W m^-2 sr^-1 m^-1.
    """
    lam = np.asarray(wavelength_m, np.float64)
    t = np.asarray(temperature_k, np.float64)
    x = PLANCK_H * LIGHT_C / (lam * BOLTZMANN_K * t)
    return 2.0 * PLANCK_H * LIGHT_C**2 / lam**5 / np.expm1(x)


def band_radiance(
    temperature_k: float | np.ndarray,
    band_m: tuple[float, float] = OGI_BAND_M,
    emissivity: float = 1.0,
) -> np.ndarray:
    """In-band radiance of a grey body: Planck's law integrated over ``band_m``.

    Parameters
    ----------
    temperature_k : float or array_like
        Black-body temperature, kelvin (> 0).
    band_m : (float, float)
        Lower and upper band limits, metres (default 3.2-3.4 um).
    emissivity : float
        Emissivity of the source in the band, 0 < e <= 1.

    Returns
    -------
    numpy.ndarray, float64, shape of ``temperature_k``
        L in W m^-2 sr^-1.
    """
    t = np.asarray(temperature_k, np.float64)
    if np.any(~np.isfinite(t)) or np.any(t <= 0):
        raise ValueError(f"temperatures must be finite and > 0 K, got {temperature_k}")
    lo, hi = band_m
    if not 0 < lo < hi:
        raise ValueError(f"band must satisfy 0 < low < high, got {band_m}")
    if not 0 < emissivity <= 1:
        raise ValueError(f"emissivity must be in (0, 1], got {emissivity}")
    lam = 0.5 * (hi - lo) * _GL_X + 0.5 * (hi + lo)
    spectral = planck_spectral_radiance(lam, t[..., None])
    return emissivity * 0.5 * (hi - lo) * (spectral @ _GL_W)


def gas_radiance_and_floor(temperature_k: float, band_m: tuple[float, float],
                           floor_k: float) -> tuple[float, float]:
    """L_g, the in-band radiance of a black body at the gas temperature, and a contrast floor
    of ``floor_k`` kelvin at that temperature, both in W m^-2 sr^-1: the divisor's floor of the
    differential optical depth (I(t) - I(t+1)) / (I_mid - L_g).

    Parameters
    ----------
    temperature_k : float
        Gas temperature, K.
    band_m : (float, float)
        The camera's band, m (:attr:`CharacteristicCurve.band_m`).
    floor_k : float
        The floor in kelvin (radiance of a 1 K step about the gas temperature, times this).
    """
    t = float(temperature_k)
    lg = float(band_radiance(t, band_m))
    per_k = float(band_radiance(t + 0.5, band_m) - band_radiance(t - 0.5, band_m))
    return lg, per_k * float(floor_k)


def celsius_to_kelvin(t_c: float | np.ndarray) -> np.ndarray:
    """Degrees Celsius to kelvin."""
    return np.asarray(t_c, np.float64) + 273.15


@dataclass(frozen=True)
class CharacteristicCurve:
    """One camera's characteristic curve, counts as a function of in-band radiance.

    Attributes
    ----------
    offset : float
        Counts at zero radiance.
    gain : float
        Counts per W m^-2 sr^-1 (> 0).
    curvature : float
        Counts per (W m^-2 sr^-1)^2; 0 for the linear model.
    radiance_range : (float, float)
        Radiance span of the fit, W m^-2 sr^-1 (outside it the curve is extrapolated).
    residual_rms_counts : float
        RMS of the fit residuals, counts.
    residuals_counts : tuple of float
        Mean residual per calibration temperature, counts (shows non-linearity).
    temperatures_k : tuple of float
        Black-body temperatures used, kelvin.
    band_m : (float, float)
        Spectral band of the radiance, metres.
    """

    offset: float
    gain: float
    curvature: float = 0.0
    radiance_range: tuple[float, float] = (0.0, 0.0)
    residual_rms_counts: float = 0.0
    residuals_counts: tuple[float, ...] = ()
    temperatures_k: tuple[float, ...] = ()
    band_m: tuple[float, float] = OGI_BAND_M
    frames_per_temperature: tuple[int, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("offset", "gain", "curvature"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"characteristic curve {name} must be finite")
        if self.gain <= 0:
            raise ValueError(f"characteristic curve gain must be > 0 counts per W m^-2 sr^-1, "
                             f"got {self.gain}")

    @classmethod
    def from_counts_model(cls, model: Mapping[str, Any]) -> CharacteristicCurve:
        """The linear curve of a counts model ``{"offset": ..., "gain": ...}`` (counts =
        offset + gain L), as a simulated camera's ``meta.json`` gives it."""
        return cls(offset=float(model["offset"]), gain=float(model["gain"]))

    @property
    def model(self) -> str:
        """``"linear"`` or ``"quadratic"``."""
        return "linear" if self.curvature == 0.0 else "quadratic"

    def counts(self, radiance: np.ndarray) -> np.ndarray:
        """Forward model: counts for a radiance (W m^-2 sr^-1)."""
        L = np.asarray(radiance, np.float64)
        return self.offset + self.gain * L + self.curvature * L**2


def roi_means(
    frames: Sequence[np.ndarray] | np.ndarray, roi_fraction: float = 0.25
) -> np.ndarray:
    """Mean counts over a central region of interest of each frame.

    The black body's aperture should fill at least the central ``roi_fraction`` of the
    image in both directions. Saturated pixels (at the dtype's maximum for integer frames)
    inside the ROI make the frame unusable and raise.

    Parameters
    ----------
    frames : sequence of numpy.ndarray, each shape (H, W)
        Raw frames of the black body at one temperature.
    roi_fraction : float
        Side of the ROI as a fraction of the image side (0 < f <= 1).

    Returns
    -------
    numpy.ndarray, shape (n_frames,), float64
        Mean counts per frame.
    """
    if not 0 < roi_fraction <= 1:
        raise ValueError(f"roi_fraction must be in (0, 1], got {roi_fraction}")
    means = []
    for k, frame in enumerate(frames):
        f = np.asarray(frame)
        if f.ndim != 2:
            raise ValueError(f"frame {k}: expected a single-channel image, got shape {f.shape}")
        h, w = f.shape
        rh, rw = max(1, round(h * roi_fraction)), max(1, round(w * roi_fraction))
        y0, x0 = (h - rh) // 2, (w - rw) // 2
        roi = f[y0 : y0 + rh, x0 : x0 + rw]
        if np.issubdtype(f.dtype, np.integer) and np.any(roi == np.iinfo(f.dtype).max):
            raise ValueError(f"frame {k}: saturated pixels in the central ROI; lower the "
                             "black-body temperature or the camera's integration time")
        means.append(float(roi.mean(dtype=np.float64)))
    return np.asarray(means)


def fit_characteristic_curve(
    temperatures_k: Sequence[float],
    counts_per_temperature: Sequence[Sequence[float] | np.ndarray],
    *,
    quadratic: bool = False,
    band_m: tuple[float, float] = OGI_BAND_M,
    emissivity: float = 1.0,
) -> CharacteristicCurve:
    """Fit counts = offset + gain L (+ curvature L^2) by linear least squares.

    Every frame mean is one sample, so a temperature with more frames weighs more.

    Parameters
    ----------
    temperatures_k : sequence of float, length T
        Black-body temperatures, kelvin.
    counts_per_temperature : sequence of array_like, length T
        Mean counts of each frame at each temperature (e.g. from :func:`roi_means`).
    quadratic : bool
        Fit the quadratic model (needs >= 3 temperatures) instead of the linear one.
    band_m : (float, float)
        Camera band, metres.
    emissivity : float
        Black-body emissivity in the band.

    Returns
    -------
    CharacteristicCurve
    """
    temps = [float(t) for t in temperatures_k]
    if len(temps) != len(counts_per_temperature):
        raise ValueError(f"{len(temps)} temperatures but {len(counts_per_temperature)} "
                         "groups of frames")
    need = 3 if quadratic else 2
    if len(set(temps)) < need:
        raise ValueError(f"the {'quadratic' if quadratic else 'linear'} characteristic curve "
                         f"needs at least {need} distinct temperatures, got {len(set(temps))}")
    radiances = band_radiance(np.asarray(temps), band_m, emissivity)
    L_list, c_list = [], []
    for t, L, counts in zip(temps, radiances, counts_per_temperature, strict=True):
        c = np.asarray(counts, np.float64).ravel()
        if c.size == 0:
            raise ValueError(f"no frames for the black body at {t - 273.15:g} degC")
        L_list.append(np.full(c.size, L))
        c_list.append(c)
    L_all = np.concatenate(L_list)
    c_all = np.concatenate(c_list)
    cols = [np.ones_like(L_all), L_all] + ([L_all**2] if quadratic else [])
    A = np.stack(cols, axis=1)
    # Scale the columns so the normal equations stay well conditioned (L ~ 0.01-1).
    scale = np.abs(A).max(axis=0)
    coef, *_ = np.linalg.lstsq(A / scale, c_all, rcond=None)
    coef = coef / scale
    offset, gain = float(coef[0]), float(coef[1])
    curvature = float(coef[2]) if quadratic else 0.0
    if gain <= 0:
        raise ValueError(f"fitted gain {gain:.4g} counts per W m^-2 sr^-1 is not positive: counts "
                         "fall with temperature; are the temperatures in the order of the frames?")
    fitted = offset + gain * L_all + curvature * L_all**2
    resid = c_all - fitted
    per_t = []
    start = 0
    for c in c_list:
        per_t.append(float(resid[start : start + c.size].mean()))
        start += c.size
    return CharacteristicCurve(
        offset=offset,
        gain=gain,
        curvature=curvature,
        radiance_range=(float(radiances.min()), float(radiances.max())),
        residual_rms_counts=float(np.sqrt(np.mean(resid**2))),
        residuals_counts=tuple(per_t),
        temperatures_k=tuple(temps),
        band_m=(float(band_m[0]), float(band_m[1])),
        frames_per_temperature=tuple(int(c.size) for c in c_list),
    )


def apply_characteristic_curve(
    counts: np.ndarray, curve: CharacteristicCurve | None
) -> np.ndarray:
    """Map raw counts to in-band radiance by inverting the characteristic curve.

    Parameters
    ----------
    counts : numpy.ndarray, shape (H, W), any numeric dtype
        Raw frame of one camera.
    curve : CharacteristicCurve or None
        That camera's curve. ``None`` (camera not radiometrically calibrated) returns the
        counts unchanged as float32, so the caller's chain runs the same either way.

    Returns
    -------
    numpy.ndarray, shape (H, W), float32
        Radiance in W m^-2 sr^-1 (or counts when ``curve`` is None). For the quadratic model,
        counts beyond the curve's extremum map to the extremum's radiance.
    """
    c = np.asarray(counts)
    if curve is None:
        return c.astype(np.float32)
    x = c.astype(np.float64) - curve.offset
    if curve.curvature == 0.0:
        return (x / curve.gain).astype(np.float32)
    a, b = curve.curvature, curve.gain
    x_vertex = -b * b / (4.0 * a)  # counts (minus offset) at the curve's extremum
    x = np.minimum(x, x_vertex) if a < 0 else np.maximum(x, x_vertex)
    disc = np.maximum(b * b + 4.0 * a * x, 0.0)
    # Root on the branch through L = 0, written without cancellation for small a.
    return (2.0 * x / (b + np.sqrt(disc))).astype(np.float32)
