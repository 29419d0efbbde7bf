"""A bounded history of wind vectors, interpolated at any host time.

Linear interpolation between the two valid samples around the query time, but only when they
are at most ``max_gap_s`` apart: a longer gap (sensor down, samples invalid) is flagged, never
bridged. Queries before the oldest or after the newest kept sample are flagged as well (no
extrapolation); a query exactly at a sample's time returns that sample.
"""

from __future__ import annotations

import bisect
import threading
from dataclasses import dataclass

import numpy as np

from drivers.anemometer.mounting import CameraWind

#: Flags of :class:`WindAt`.
OK = "ok"
GAP = "gap"
TOO_EARLY = "before history"
TOO_LATE = "after newest sample"
EMPTY = "no samples"


@dataclass(frozen=True)
class WindAt:
    """Wind interpolated at ``host_ns``.

    ``vector`` (3,) float64 m/s, all NaN unless ``flag == "ok"``. ``span_ns`` is the time
    between the two samples used (0 for an exact hit). ``vertical_measured`` is False when
    either sample came from a 2-D sensor.
    """

    host_ns: int
    vector: np.ndarray
    flag: str
    span_ns: int
    vertical_measured: bool

    @property
    def ok(self) -> bool:
        return self.flag == OK


class WindHistory:
    """Bounded, thread-safe history of valid wind vectors (camera frame or any other).

    Parameters
    ----------
    capacity : int
        Most samples kept (oldest dropped first). 32 Hz for 10 min is ~19,200.
    max_gap_s : float
        Two samples further apart than this are not interpolated between.
    """

    def __init__(self, capacity: int = 20_000, max_gap_s: float = 0.5) -> None:
        if capacity < 2:
            raise ValueError(f"capacity must be >= 2, got {capacity!r}")
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be > 0, got {max_gap_s!r}")
        self.capacity = capacity
        self.max_gap_ns = int(max_gap_s * 1e9)
        self._t: list[int] = []
        self._v: list[np.ndarray] = []
        self._vert: list[bool] = []
        self._lock = threading.Lock()
        #: Samples refused: flagged invalid by the sensor, or older than the newest kept.
        self.rejected_invalid = 0
        self.rejected_out_of_order = 0

    def __len__(self) -> int:
        return len(self._t)

    def add(self, wind: CameraWind) -> bool:
        """Add one sample; invalid or out-of-order samples are counted and ignored."""
        if not wind.valid or not np.all(np.isfinite(wind.vector)):
            self.rejected_invalid += 1
            return False
        with self._lock:
            if self._t and wind.host_ns <= self._t[-1]:
                self.rejected_out_of_order += 1
                return False
            self._t.append(wind.host_ns)
            self._v.append(np.asarray(wind.vector, dtype=np.float64))
            self._vert.append(wind.vertical_measured)
            if len(self._t) > 2 * self.capacity:
                # Trim in batches: amortised O(1) per add.
                drop = len(self._t) - self.capacity
                del self._t[:drop], self._v[:drop], self._vert[:drop]
        return True

    def at(self, host_ns: int) -> WindAt:
        """Wind at host time ``host_ns`` (see the module docstring for the flags)."""
        nan = np.full(3, np.nan)
        with self._lock:
            t = self._t
            lo_bound = max(0, len(t) - self.capacity)
            if len(t) <= lo_bound:
                return WindAt(host_ns, nan, EMPTY, 0, False)
            if host_ns < t[lo_bound]:
                return WindAt(host_ns, nan, TOO_EARLY, 0, False)
            if host_ns > t[-1]:
                return WindAt(host_ns, nan, TOO_LATE, 0, False)
            i = bisect.bisect_left(t, host_ns, lo=lo_bound)
            if t[i] == host_ns:
                return WindAt(host_ns, self._v[i].copy(), OK, 0, self._vert[i])
            t0, t1 = t[i - 1], t[i]
            v0, v1 = self._v[i - 1], self._v[i]
            vert = self._vert[i - 1] and self._vert[i]
        span = t1 - t0
        if span > self.max_gap_ns:
            return WindAt(host_ns, nan, GAP, span, vert)
        a = (host_ns - t0) / span
        return WindAt(host_ns, (1.0 - a) * v0 + a * v1, OK, span, vert)
