"""The true wind of the simulated anemometer: constant, gusty or turbulent (seeded)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drivers.anemometer.base import AnemometerConfigError

__all__ = ["WIND_KINDS", "WindModel"]

WIND_KINDS = ("constant", "gusty", "turbulent")


class WindModel:
    """The true wind of the simulation, in the sensor's own (Gill U, V, W) axes, m/s.

    Parameters
    ----------
    kind : {"constant", "gusty", "turbulent"}
        ``constant``: always ``mean``. ``gusty``: the mean scaled by 1 + ``gust_amplitude`` *
        a smooth random burst every ~``gust_period_s`` seconds, turning by up to 15 deg.
        ``turbulent``: the mean plus an Ornstein-Uhlenbeck process per component with time
        constant ``time_constant_s`` and standard deviation ``turbulence_intensity`` * |mean|
        (vertical: half of it).
    mean : sequence of 3 float
    seed : int
    """

    def __init__(
        self,
        kind: str = "constant",
        mean: Sequence[float] = (3.0, 0.0, 0.0),
        *,
        seed: int = 0,
        gust_amplitude: float = 0.5,
        gust_period_s: float = 8.0,
        turbulence_intensity: float = 0.2,
        time_constant_s: float = 1.0,
    ) -> None:
        if kind not in WIND_KINDS:
            raise AnemometerConfigError(f"wind must be one of {WIND_KINDS}, got {kind!r}")
        m = np.asarray(mean, dtype=np.float64)
        if m.shape != (3,) or not np.all(np.isfinite(m)):
            raise AnemometerConfigError(f"mean wind must be 3 finite numbers, got {mean!r}")
        self.kind = kind
        self.mean = m
        self.gust_amplitude = gust_amplitude
        self.gust_period_s = gust_period_s
        self.time_constant_s = time_constant_s
        rng = np.random.default_rng(seed)
        self._rng = rng
        self._phase = rng.uniform(0, 2 * math.pi, size=3)
        sigma = turbulence_intensity * max(float(np.linalg.norm(m)), 0.5)
        self._sigma = np.array([sigma, sigma, 0.5 * sigma])
        self._state = np.zeros(3)
        self._last_t: float | None = None

    def at(self, t_s: float) -> np.ndarray:
        """Wind at simulation time ``t_s`` (call with increasing times), shape (3,)."""
        if self.kind == "constant":
            return self.mean.copy()
        if self.kind == "gusty":
            p = self.gust_period_s
            burst = max(0.0, math.sin(2 * math.pi * t_s / p + self._phase[0])) ** 2
            factor = 1.0 + self.gust_amplitude * burst
            turn = math.radians(15.0) * math.sin(2 * math.pi * t_s / (2.7 * p) + self._phase[1])
            c, s = math.cos(turn), math.sin(turn)
            u, v, w = self.mean
            return factor * np.array([c * u - s * v, s * u + c * v, w])
        dt = 0.0 if self._last_t is None else max(0.0, t_s - self._last_t)
        self._last_t = t_s
        a = math.exp(-dt / self.time_constant_s)
        noise = self._sigma * math.sqrt(1 - a * a) * self._rng.standard_normal(3)
        self._state = a * self._state + noise
        return self.mean + self._state
