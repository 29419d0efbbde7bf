"""When a simulated release is on: a schedule of [on, off) intervals, repeating.

A measurement engineer states a test plan as "release from 2 s to 12 s, and again from 20 s
to 26 s, then nothing until the end of the 40 s cycle": a list of ``[on_s, off_s]``
intervals in seconds from the start of a cycle of ``period_s``. The fluid simulation asks
:meth:`ReleaseSchedule.is_on` before every step (the source releases no gas and forces no
jet while off), so the ground truth (gas mask, velocity) stays exact by construction: gas
already released keeps drifting with the wind after the release stops, and the truth shows
it as long as it is there. The truth release rate of a frame is
:meth:`ReleaseSchedule.rate_factor` times the source's rate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ReleaseSchedule:
    """Release on/off intervals within a repeating cycle.

    Parameters
    ----------
    intervals : tuple of (on_s, off_s)
        Sorted, non-overlapping intervals of the cycle during which the release is on,
        ``0 <= on_s < off_s <= period_s``, seconds from the cycle's start.
    period_s : float
        Length of the cycle, s; time ``t`` is taken modulo it.
    """

    intervals: tuple[tuple[float, float], ...]
    period_s: float

    @classmethod
    def from_lists(cls, intervals: Sequence[Sequence[float]], period_s: float
                   ) -> ReleaseSchedule:
        """Build and validate from ``[[on_s, off_s], ...]`` (config, JSON)."""
        pairs = tuple((float(a), float(b)) for a, b in intervals)
        schedule = cls(pairs, float(period_s))
        schedule.validate()
        return schedule

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad interval."""
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"release schedule period must be > 0 s, got {self.period_s}")
        if not self.intervals:
            raise ValueError("a release schedule needs at least one [on_s, off_s] interval")
        last = 0.0
        for on, off in self.intervals:
            if not (math.isfinite(on) and math.isfinite(off)):
                raise ValueError(f"release interval [{on}, {off}] is not finite")
            if not on < off:
                raise ValueError(f"release interval [{on}, {off}]: on_s must be < off_s")
            if on < last:
                raise ValueError(f"release interval [{on}, {off}] starts before the previous "
                                 "one ends (sort them, no overlap)")
            if off > self.period_s + 1e-9:
                raise ValueError(f"release interval [{on}, {off}] ends after the "
                                 f"{self.period_s:g} s cycle")
            last = off

    def is_on(self, t_s: float) -> bool:
        """Whether the release is on at time ``t_s`` (s from the first cycle's start)."""
        t = float(t_s) % self.period_s
        return any(on <= t < off for on, off in self.intervals)

    def rate_factor(self, t_s: float) -> float:
        """1.0 while on, 0.0 while off (the source's mean rate times this is the truth)."""
        return 1.0 if self.is_on(t_s) else 0.0

    def starts(self, duration_s: float) -> list[float]:
        """Times of every release start in ``[0, duration_s)``, s."""
        out: list[float] = []
        cycle = 0
        while cycle * self.period_s < duration_s:
            for on, _ in self.intervals:
                t = cycle * self.period_s + on
                if t < duration_s:
                    out.append(t)
            cycle += 1
        return out

    def releases(self, duration_s: float) -> list[tuple[float, float]]:
        """Every (on_s, off_s) in ``[0, duration_s)``, off clipped to the duration."""
        out: list[tuple[float, float]] = []
        cycle = 0
        while cycle * self.period_s < duration_s:
            for on, off in self.intervals:
                t0 = cycle * self.period_s + on
                if t0 < duration_s:
                    out.append((t0, min(cycle * self.period_s + off, duration_s)))
            cycle += 1
        return out

    def to_json(self) -> dict[str, Any]:
        """JSON-able form for ``meta.json``."""
        return {"intervals_s": [list(p) for p in self.intervals], "period_s": self.period_s}

    @classmethod
    def from_json(cls, d: dict[str, Any] | None) -> ReleaseSchedule | None:
        """Inverse of :meth:`to_json`; None for None (a release that is always on)."""
        if not d:
            return None
        return cls.from_lists(d["intervals_s"], d["period_s"])
