"""Column density of the gas from calibrated radiance (paper Eq. 1 inverted, Lambert-Beer).

Eq. 1 with black-body background and gas, in radiance L (W m^-2 sr^-1, in-band):

    L = L_bg tau + L_g (1 - tau),      tau = exp(-alpha_g CL)

so, per pixel, with the background radiance L_bg that the pixel would see without gas and
the radiance L_g of a black body at the gas temperature:

    tau = (L - L_g) / (L_bg - L_g),    CL = -ln(tau) / alpha_g   [ppm*m].

The inversion needs thermal contrast: where |L_bg - L_g| is small, tau is the ratio of two
small, noisy numbers and CL is undefined. Such pixels are reported (``low_contrast``), not
guessed. tau >= 1 (noise, or gas warmer than assumed) gives CL = 0; tau is floored at
``tau_min`` (an opaque plume has no finite column density estimate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

#: Pixels per block of :func:`nanmedian_first_axis`: 60 samples of 4096 pixels are 1 MB.
MEDIAN_BLOCK = 4096


@dataclass(frozen=True)
class ColumnDensity:
    """Result of :func:`column_density`.

    Attributes
    ----------
    ppm_m : ndarray, shape (H, W), float32
        Column density CL in ppm*m; 0 where undefined.
    defined : ndarray, shape (H, W), bool
        True where the thermal contrast allowed the inversion.
    transmittance : ndarray, shape (H, W), float32
        tau in [tau_min, 1]; 1 where undefined.
    """

    ppm_m: np.ndarray
    defined: np.ndarray
    transmittance: np.ndarray

    @property
    def low_contrast_fraction(self) -> float:
        """Fraction of pixels whose contrast was too small for the inversion."""
        return float(1.0 - self.defined.mean()) if self.defined.size else 0.0


def column_density(radiance: np.ndarray, background: np.ndarray, gas_radiance: float,
                   alpha_per_ppm_m: float, *, min_contrast: float = 1e-3,
                   tau_min: float = 1e-3) -> ColumnDensity:
    """Column density per pixel from Eq. 1 with Lambert-Beer.

    Parameters
    ----------
    radiance : ndarray, shape (H, W)
        Calibrated in-band radiance L of the frame, W m^-2 sr^-1.
    background : ndarray, shape (H, W)
        Radiance L_bg each pixel sees without gas (e.g. :class:`BackgroundModel`).
    gas_radiance : float
        In-band radiance L_g of a black body at the gas temperature, W m^-2 sr^-1.
    alpha_per_ppm_m : float
        Band-averaged absorption coefficient alpha_g, natural log, per ppm*m.
    min_contrast : float
        Smallest |L_bg - L_g| in W m^-2 sr^-1 for which the inversion is defined (set it a
        few times the radiance noise: NETD x dL/dT).
    tau_min : float
        Floor of tau (0 < tau_min < 1).

    Returns
    -------
    ColumnDensity
    """
    L = np.asarray(radiance, np.float64)
    bg = np.asarray(background, np.float64)
    if L.shape != bg.shape or L.ndim != 2:
        raise ValueError(f"radiance and background must be the same 2-D shape, got "
                         f"{L.shape} and {bg.shape}")
    if not alpha_per_ppm_m > 0 or not 0 < tau_min < 1 or not min_contrast > 0:
        raise ValueError("alpha_per_ppm_m and min_contrast must be > 0, 0 < tau_min < 1")
    contrast = bg - float(gas_radiance)
    defined = np.isfinite(L) & np.isfinite(bg) & (np.abs(contrast) >= min_contrast)
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(defined, (L - float(gas_radiance)) / np.where(defined, contrast, 1.0),
                       1.0)
    tau = np.clip(tau, tau_min, 1.0)
    cl = -np.log(tau) / alpha_per_ppm_m
    return ColumnDensity(ppm_m=np.where(defined, cl, 0.0).astype(np.float32),
                         defined=defined, transmittance=tau.astype(np.float32))


#: First scale of the spatial fill, px (of 320x240 frames, where it was chosen).
FILL_SIGMA_PX = 8.0


class BackgroundModel:
    """Background radiance without gas: per-pixel median of recent gas-free samples.

    A robust temporal statistic: each pixel's median over the last ``capacity`` frames in
    which that pixel was not segmented as gas. Pixels with fewer than ``min_samples``
    gas-free samples (a plume sitting on them, or a plume present since the first frame)
    take a spatial estimate instead: the normalised Gaussian average of the surrounding
    pixels' own estimates (the scale grows until every pixel is reached). The median over
    all their samples would include the gas and bias CL low (by 75 % on a steady field
    plume); the spatial fill is exact on a smooth background (sky, a uniform wall) and
    wrong on a textured one, where the temporal history must be long enough (``capacity``)
    to see the pixel free of gas. :attr:`fallback_fraction` reports the share of filled
    pixels. The estimate is refreshed every ``refresh`` updates while the stack fills and
    every ``capacity`` updates once it is full: a background changes over minutes, and a
    median over a full stack of 320 x 240 frames costs about 20 ms
    (:func:`nanmedian_first_axis`; 160 ms with ``np.nanmedian``, measured), the spatial
    fill when a plume covers a third of the frame about 27 ms more.

    Parameters
    ----------
    capacity : int
        Frames kept (e.g. 60 = 2 s at 30 Hz).
    min_samples : int
        Gas-free samples a pixel needs for its own estimate.
    refresh : int
        Recompute the median every this many updates while fewer than ``capacity`` frames
        are kept (afterwards every ``capacity`` updates).
    fill_sigma_px : float
        First scale of the spatial fill, px (:func:`spatial_fill`).
    """

    def __init__(self, capacity: int = 60, min_samples: int = 8, refresh: int = 10,
                 fill_sigma_px: float = FILL_SIGMA_PX) -> None:
        if capacity < 1 or not 1 <= min_samples <= capacity or refresh < 1:
            raise ValueError("need capacity >= 1, 1 <= min_samples <= capacity, refresh >= 1")
        self.capacity, self.min_samples, self.refresh = capacity, min_samples, refresh
        self.fill_sigma_px = fill_sigma_px
        self._frames: np.ndarray | None = None
        self._gas: np.ndarray | None = None
        self._count = 0
        self._estimate: np.ndarray | None = None
        self.fallback_fraction = 0.0

    def update(self, radiance: np.ndarray, gas_mask: np.ndarray | None = None) -> None:
        """Add one frame (W m^-2 sr^-1, (H, W)) and its gas mask (True = gas)."""
        L = np.asarray(radiance, np.float32)
        if self._frames is None or self._frames.shape[1:] != L.shape:
            self._frames = np.empty((self.capacity, *L.shape), np.float32)
            self._gas = np.zeros((self.capacity, *L.shape), bool)
            self._count = 0
        assert self._gas is not None
        k = self._count % self.capacity
        self._frames[k] = L
        self._gas[k] = False if gas_mask is None else np.asarray(gas_mask, bool)
        self._count += 1
        every = self.refresh if self._count < self.capacity else self.capacity
        if self._estimate is None or self._count % every == 0:
            self._estimate = self._median()

    def _median(self) -> np.ndarray:
        assert self._frames is not None and self._gas is not None
        n = min(self._count, self.capacity)
        frames, gas = self._frames[:n], self._gas[:n]
        enough = (~gas).sum(axis=0) >= min(self.min_samples, n)
        # gas samples left out only where enough others remain (one pass over the stack)
        own = nanmedian_first_axis(frames, drop=gas & enough[None])
        self.fallback_fraction = float(1.0 - enough.mean())
        if enough.any() and not enough.all():
            own = spatial_fill(own, enough, self.fill_sigma_px)
        return own.astype(np.float32)

    def estimate(self) -> np.ndarray | None:
        """Current background radiance, (H, W) float32; None before the first frame."""
        return self._estimate

    @property
    def frames(self) -> int:
        """Frames seen so far."""
        return self._count


def nanmedian_first_axis(stack: np.ndarray, drop: np.ndarray | None = None,
                         block: int = MEDIAN_BLOCK) -> np.ndarray:
    """Median over axis 0 ignoring NaN and the ``drop`` samples, as
    ``np.nanmedian(np.where(drop, np.nan, stack), axis=0)`` (NaN where a column has no
    number), by one sort of the pixels' sample rows, ``block`` pixels at a time.

    ``np.nanmedian`` takes a masked-array path for short axes: 160-290 ms for 60 frames of
    320 x 240, this about 20 ms (measured), the same values up to float rounding. The
    blocks keep every temporary in the cache: the whole stack at once allocated three
    copies of it (18 MB each) and took 55-60 ms, 450 ms when the memory had just been
    returned to the system (page faults, 350 ms of system time, measured).

    Parameters
    ----------
    stack : ndarray, shape (N, H, W), float
    drop : ndarray, shape (N, H, W), bool, optional
        Samples to leave out (True), as if they were NaN.
    block : int
        Pixels per block.

    Returns
    -------
    ndarray, shape (H, W), float64
    """
    n = stack.shape[0]
    flat = stack.reshape(n, -1)
    dropped = None if drop is None else drop.reshape(n, -1)
    med = np.empty(flat.shape[1], np.float64)
    for j in range(0, flat.shape[1], block):
        rows = np.array(flat[:, j:j + block].T, order="C")
        if dropped is not None:
            rows[dropped[:, j:j + block].T] = np.nan
        rows.sort(axis=1)  # NaN sort last
        count = n - np.isnan(rows).sum(axis=1)
        lo = np.take_along_axis(rows, np.maximum(count - 1, 0)[:, None] // 2, axis=1)[:, 0]
        hi = np.take_along_axis(rows, (count // 2)[:, None].clip(max=n - 1), axis=1)[:, 0]
        part = 0.5 * (lo.astype(np.float64) + hi)
        part[count == 0] = np.nan
        med[j:j + block] = part
    return med.reshape(stack.shape[1:])


def spatial_fill(values: np.ndarray, known: np.ndarray,
                 sigma_px: float = FILL_SIGMA_PX) -> np.ndarray:
    """``values`` where ``known``, elsewhere the normalised Gaussian average of the known
    values around (sigma doubling from ``sigma_px`` until every pixel is reached).

    Parameters
    ----------
    values : ndarray, shape (H, W)
    known : ndarray, shape (H, W), bool
        At least one pixel True.

    Returns
    -------
    ndarray, shape (H, W), float64
    """
    v = np.where(known, np.asarray(values, np.float64), 0.0)
    w = known.astype(np.float64)
    out = np.asarray(values, np.float64).copy()
    todo = ~known
    sigma = float(sigma_px)
    while todo.any():
        num = ndimage.gaussian_filter(v, sigma, mode="nearest", truncate=3.0)
        den = ndimage.gaussian_filter(w, sigma, mode="nearest", truncate=3.0)
        reached = todo & (den > 1e-3)
        out[reached] = num[reached] / den[reached]
        todo &= ~reached
        sigma *= 2.0
        if sigma > 4.0 * max(values.shape):
            out[todo] = float(np.mean(v[known]))
            break
    return out
