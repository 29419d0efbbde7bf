"""Emission rate of one frame (stereo and single-camera) and its time average.

Stereo (ours): Q = sum sigma_i (V_i . n) ds_i with the 3D velocity of Eq. 4 and the depth
Z_i = s b / d_i of every pixel. Single-camera quantitative OGI (the baseline products use):
the same column density and curtains, but the velocity from image-plane flow at one typed-in
distance Z_typed, V = (u, v, 0) Z_typed / (s dt), and ds_i = Z_typed / s. It cannot see
motion along the optical axis nor the perspective of a plume moving towards the camera,
and any error in Z_typed enters the rate twice (in V and in ds).

:class:`processing.emission.estimator.EmissionEstimator` computes both through the same
curtains. A frame's rate is the mean over its defined curtains; the window average
(:class:`RateWindow`) is the mean over frames in the last ``window_s`` seconds, with an
uncertainty from the spread over curtains and over time (see :meth:`RateWindow.estimate`).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrameRate:
    """Rate of one frame.

    Attributes
    ----------
    rate_g_s : float or None
        Mean over the defined curtains, g/s; None when no curtain was defined.
    curtain_rates_g_s : tuple of float
        Each defined curtain's rate, g/s.
    reason : str
        Why the rate is None ("no gas", "no motion", "plume too short", "no valid
        velocity on the curtains"); empty otherwise.
    out_of_plane_deg : float or None
        Angle of the gas's motion out of the image plane (:func:`out_of_plane_deg`), deg;
        None when unknown (no valid velocity, or the single-camera rate).
    """

    rate_g_s: float | None
    curtain_rates_g_s: tuple[float, ...]
    reason: str = ""
    out_of_plane_deg: float | None = None


def single_camera_velocity(flow: np.ndarray, distance_m: float, camera_constant: float,
                           dt_s: float) -> np.ndarray:
    """Image-plane velocity at one typed-in distance: (u, v, 0) Z / (s dt), m/s, (H, W, 3)."""
    if not distance_m > 0 or not dt_s > 0:
        raise ValueError(f"distance and dt must be > 0, got {distance_m} m, {dt_s} s")
    f = np.asarray(flow, np.float64)
    v = np.zeros((*f.shape[:2], 3))
    v[..., :2] = f * (distance_m / (camera_constant * dt_s))
    return v


#: Mean angle of the gas's motion out of the image plane above which a window's rate is
#: flagged ``line_of_sight``: there the image sees less than 57 % of the speed, and the
#: rate's error grew with the angle. Measured with ``ogiflow eval emission`` (docs/accuracy.md,
#: emission rate), the angle as this module measures it: 2-14 deg within
#: 4.7 %, 35-50 deg within 6.9 %, 69 deg +18.5 % (that scene's simulated truth loses gas in
#: mid-image, so the share the measurement owes is not known); the flag sits between.
LINE_OF_SIGHT_DEG = 55.0


def out_of_plane_deg(sigma_kg_m2: np.ndarray, velocity_m_s: np.ndarray, valid: np.ndarray,
                     gas_mask: np.ndarray, *, principal_point: tuple[float, float],
                     camera_constant: float) -> float | None:
    """Angle between the gas's mean motion and the image plane, deg, in [0, 90].

    The column-density-weighted mean velocity V of the valid gas pixels against the
    column-density-weighted mean viewing ray r^ of the same pixels:
    asin(|V . r^| / |V|). Near 90 deg the gas moves along the line of sight, where an image
    sees little of its motion (the flux through the curtains rests on the image-plane
    part of it).

    Parameters
    ----------
    sigma_kg_m2 : ndarray, shape (H, W)
        Column density, kg/m^2 (the weights).
    velocity_m_s : ndarray, shape (H, W, 3)
        3D gas velocity (Eq. 4), m/s, left camera frame.
    valid, gas_mask : ndarray, shape (H, W), bool
    principal_point : (float, float)
        (x0, y0), px.
    camera_constant : float
        s, px.

    Returns
    -------
    float or None
        None when no valid gas pixel has a positive column density or the mean velocity
        is zero.
    """
    use = np.asarray(gas_mask, bool) & np.asarray(valid, bool)
    at = np.flatnonzero(use)  # flat indices: cheaper than (ys, xs) pairs
    if len(at) == 0:
        return None
    # index first, then widen: the gas pixels, not the whole frame, become float64
    w = np.clip(np.asarray(np.ravel(sigma_kg_m2)[at], np.float64), 0.0, None)
    vel = np.asarray(np.reshape(velocity_m_s, (-1, 3))[at], np.float64)
    ok = np.isfinite(w) & np.all(np.isfinite(vel), axis=1)
    if not ok.all():
        w, vel, at = w[ok], vel[ok], at[ok]
    ys, xs = np.divmod(at, use.shape[1])
    if w.sum() <= 0:
        return None
    v = (w[:, None] * vel).sum(axis=0) / w.sum()
    rays = np.column_stack([xs - principal_point[0], ys - principal_point[1],
                            np.full(len(xs), float(camera_constant))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    r = (w[:, None] * rays).sum(axis=0)
    r /= np.linalg.norm(r)
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return None
    return float(np.degrees(np.arcsin(min(1.0, abs(float(v @ r)) / speed))))


@dataclass(frozen=True)
class RateEstimate:
    """Windowed emission rate, what the appliance reports.

    Attributes
    ----------
    rate_g_s, rate_kg_h : float or None
        Mean rate over the window; None when no frame in the window had one.
    uncertainty_g_s : float or None
        One standard uncertainty of ``rate_g_s``.
    frames : int
        Frames in the window with a defined rate.
    frames_total : int
        All frames in the window.
    window_s : float
        Window length, s.
    out_of_plane_deg : float or None
        Mean over the window's frames of the gas's motion out of the image plane, deg.
    flags : tuple of str
        ``line_of_sight`` when ``out_of_plane_deg`` exceeds :data:`LINE_OF_SIGHT_DEG`: the
        rate is weak (docs/accuracy.md gives what it read in that geometry).
    """

    rate_g_s: float | None
    rate_kg_h: float | None
    uncertainty_g_s: float | None
    frames: int
    frames_total: int
    window_s: float
    out_of_plane_deg: float | None = None
    flags: tuple[str, ...] = ()


class RateWindow:
    """Time average of frame rates over the last ``window_s`` seconds.

    Parameters
    ----------
    window_s : float
        Window length in seconds (default 30 s).
    """

    def __init__(self, window_s: float = 30.0) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.window_s = float(window_s)
        # (t, rate, standard error of its curtain mean or None), the last computed once per
        # frame: recomputing it for the whole window on every push cost the daemon's
        # results thread ~3 ms per result at 240 frames in the window.
        self._items: collections.deque[tuple[float, FrameRate, float | None]] = (
            collections.deque())

    def push(self, t_s: float, rate: FrameRate) -> RateEstimate:
        """Add the rate of the frame at time ``t_s`` (s) and return the window's estimate."""
        self._items.append((float(t_s), rate, curtain_sem(rate)))
        while self._items and self._items[0][0] < t_s - self.window_s:
            self._items.popleft()
        return self.estimate()

    def estimate(self) -> RateEstimate:
        """Mean of the frame rates in the window and its standard uncertainty.

        The uncertainty combines (a) the spread over curtains: each frame's standard error
        of the curtain mean, averaged in quadrature over the frames; (b) the spread over
        time: the standard deviation of the frame rates over sqrt(n_eff), with n_eff the
        number of frames divided by twice the integral correlation time of the series
        (consecutive frames of a turbulent plume are not independent).
        """
        defined = [(r, sem) for _, r, sem in self._items if r.rate_g_s is not None]
        total = len(self._items)
        if not defined:
            return RateEstimate(None, None, None, 0, total, self.window_s)
        x = np.array([r.rate_g_s for r, _ in defined], np.float64)
        mean = float(x.mean())
        sem_curtains = [sem for _, sem in defined if sem is not None]
        a = (float(np.sqrt(np.mean(np.square(sem_curtains)) / len(defined)))
             if sem_curtains else 0.0)
        b = 0.0
        if len(x) > 1:
            n_eff = max(1.0, len(x) / (2.0 * integral_time_frames(x)))
            b = float(np.std(x, ddof=1) / np.sqrt(n_eff))
        unc = float(np.hypot(a, b))
        angles = [r.out_of_plane_deg for r, _ in defined if r.out_of_plane_deg is not None]
        angle = float(np.mean(angles)) if angles else None
        flags = ("line_of_sight",) if angle is not None and angle > LINE_OF_SIGHT_DEG else ()
        return RateEstimate(mean, mean * 3.6, unc, len(defined), total, self.window_s,
                            angle, flags)


def curtain_sem(rate: FrameRate) -> float | None:
    """Standard error of a frame's curtain mean, g/s (None: fewer than two curtains)."""
    n = len(rate.curtain_rates_g_s)
    if rate.rate_g_s is None or n < 2:
        return None
    return float(np.std(rate.curtain_rates_g_s, ddof=1) / np.sqrt(n))


def integral_time_frames(x: np.ndarray) -> float:
    """Integral correlation time of a series in samples (>= 0.5; sum of the
    autocorrelation up to its first zero crossing)."""
    x = np.asarray(x, np.float64) - np.mean(x)
    var = float(x @ x)
    if var == 0.0 or len(x) < 3:
        return 0.5
    acf = np.correlate(x, x, mode="full")[len(x) - 1:] / var
    cut = np.argmax(acf <= 0) if np.any(acf <= 0) else len(acf)
    return max(0.5, float(acf[:cut].sum()) - 0.5)
