"""One leak event: what is reported over MQTT, recorded and shown (running statistics).

Decided by :class:`appliance.runtime.events.LeakDetector`.
"""

from __future__ import annotations

import collections
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from appliance.runtime.evidence import FrameEvidence

#: Newest source positions whose median is an event's source (older ones are forgotten).
SOURCE_WINDOW = 200


@dataclass
class LeakEvent:
    """One leak event (what is reported over MQTT, recorded and shown)."""

    id: int
    start_t_s: float
    start_frame: int
    end_t_s: float | None = None
    end_frame: int | None = None
    end_reason: str = ""
    source_xy: tuple[float, float] | None = None
    source_xyz_m: tuple[float, float, float] | None = None
    peak_rate_g_s: float | None = None
    mean_rate_g_s: float | None = None
    mean_velocity_m_s: tuple[float, float, float] | None = None
    mean_wind_m_s: tuple[float, float, float] | None = None
    confidence: float = 0.0
    frames: int = 0
    positive_frames: int = 0
    # Running sums, not per-frame lists: a leak can last for weeks until it is repaired,
    # and lists grew by ~450 bytes and a full mean per result (measured in a soak: the
    # daemon's memory rose by tens of MB an hour while the simulated leak was on).
    _sources: collections.deque[tuple[float, float]] = field(
        default_factory=lambda: collections.deque(maxlen=SOURCE_WINDOW), repr=False)
    _rate_n: int = field(default=0, repr=False)
    _rate_sum: float = field(default=0.0, repr=False)
    _velocity_n: int = field(default=0, repr=False)
    _velocity_sum: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), repr=False)
    _wind_n: int = field(default=0, repr=False)
    _wind_sum: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), repr=False)
    _coherence_sum: float = field(default=0.0, repr=False)

    @property
    def ongoing(self) -> bool:
        return self.end_t_s is None

    def duration_s(self, now_s: float) -> float:
        return (self.end_t_s if self.end_t_s is not None else now_s) - self.start_t_s

    def add(self, ev: FrameEvidence, positive: bool) -> None:
        """Account one frame of the event (statistics over positive frames only)."""
        self.frames += 1
        if not positive:
            return
        self.positive_frames += 1
        if ev.source_xy is not None:
            self._sources.append(ev.source_xy)
            self.source_xy = median_point(self._sources)
        if ev.source_xyz_m is not None:
            self.source_xyz_m = ev.source_xyz_m
        if ev.rate_g_s is not None:
            rate = float(ev.rate_g_s)
            self._rate_n += 1
            self._rate_sum += rate
            self.peak_rate_g_s = rate if self.peak_rate_g_s is None else max(
                self.peak_rate_g_s, rate)
            self.mean_rate_g_s = self._rate_sum / self._rate_n
        if ev.velocity_m_s is not None:
            self._velocity_n += 1
            self._velocity_sum = _add3(self._velocity_sum, ev.velocity_m_s)
            self.mean_velocity_m_s = _scale3(self._velocity_sum, 1.0 / self._velocity_n)
        if ev.wind_m_s is not None:
            self._wind_n += 1
            self._wind_sum = _add3(self._wind_sum, ev.wind_m_s)
            self.mean_wind_m_s = _scale3(self._wind_sum, 1.0 / self._wind_n)
        self._coherence_sum += float(ev.coherence)
        # positive/frames times the mean coherence of the positive frames
        self.confidence = float(self._coherence_sum / self.frames)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (no private lists)."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_")}


def median_point(points: Sequence[tuple[float, float]]) -> tuple[float, float]:
    a = np.asarray(points, np.float64)
    return float(np.median(a[:, 0])), float(np.median(a[:, 1]))


def _add3(a: tuple[float, float, float], b: Sequence[float]) -> tuple[float, float, float]:
    return a[0] + float(b[0]), a[1] + float(b[1]), a[2] + float(b[2])


def _scale3(a: tuple[float, float, float], k: float) -> tuple[float, float, float]:
    return a[0] * k, a[1] * k, a[2] * k
