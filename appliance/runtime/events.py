"""Leak events: when a leak starts, is ongoing and ends, from per-frame evidence.

Pure decision logic (no threads, no I/O) so that it runs the same in the daemon, in
``ogiflow eval detection`` and in tests. A single frame's segmentation is not enough to
say "leak" (noise, a warm object, the sky can all be segmented as gas): an event needs
temporal evidence, in the spirit of continuous OGI monitoring products:

- *presence*: enough gas pixels inside the watched zones (ignored zones removed);
- *plume-like motion*: the flow inside the gas region is coherent (mean resultant length of
  the flow directions, 0 = random, 1 = all parallel), as a plume carried by wind is;
- *a fixed source*: the upstream end of the plume stays within ``max_source_shift_px`` of
  the running median over the event's frames, or gas still covers that median (a moving
  object drags its "source" along and leaves the place where it was first seen);
- *gas that stays at the source*: to start, the place of the candidate's first sources must have
  held gas in at least :data:`PERSISTENCE` of the frames of the last ``min_duration_s``
  (a leak keeps feeding it; a warm object covers any place only while it passes, its
  uniform middle not even then), and the gas must lie downstream of it along the latest
  flow direction;
- *a source that does not travel with the gas*: an event does not start while, over the
  last ``min_duration_s``, the source moved on from one frame to the next by at least
  :data:`TRANSLATION` of what the flow carried the gas (median over the steps): a rigid
  warm object translates as a whole, its upstream end with it at the speed of its flow
  (ratio 1 in the simulated no-release scene, also after it turns round), while a plume's
  upstream end stays at the leak whatever the gas downstream does (ratio about 0). The
  paper (Sec. 5.2, 6) names moving objects as its segmentation's failure and motion
  parameters as descriptors of gas; this is one;
- *a source in view*: before an event has started, a frame whose upstream end touches the
  image border (within :data:`appliance.runtime.evidence.BORDER_PX`; its source within
  twice that) counts only when its gas covers the candidate's source: gas entering across
  the edge cannot be located, and a warm object walking slowly into the view keeps its
  trailing end pinned to the border for seconds;
- *persistence with hysteresis*: an event starts when the positive frames cover at least
  ``start_fraction`` of the last ``start_window_s`` and have lasted ``min_duration_s``;
  it ends when they cover less than ``end_fraction`` of the last ``end_window_s``. Each
  window holds at least a few frame intervals (:data:`START_FRAMES`, :data:`END_FRAMES`):
  at one frame per second, 2 s are two frames, no evidence of persistence.

Footage slower than the flow can follow (evidence with an ``occupancy`` map,
:mod:`appliance.runtime.occupancy`) replaces the motion rules, which need a meaningful
flow, by where gas stays: a frame is positive when the persistent plume covers at least
``min_gas_pixels`` and its apex, in view, stays within ``max_source_shift_px`` of the
candidate's sources; once an event is open, while the cells around its source stay occupied
(:data:`~appliance.runtime.occupancy.HOLD_OCCUPANCY`): the plume is still anchored there,
however much of the view it fills and whether or not the frame's own plume is segmented.

The event's start is back-dated to its first positive frame, its end to its last.
"""

from __future__ import annotations

import collections
import itertools
from dataclasses import replace

import numpy as np

from appliance.runtime.event_config import EventConfig
from appliance.runtime.evidence import (
    COVERAGE_CELL_PX,
    GAP_S,
    EvidenceStream,
    FrameEvidence,
    Polygon,
    covers,
    evidence_from_fields,
    moves,
    zone_mask,
)
from appliance.runtime.leak_event import SOURCE_WINDOW, LeakEvent, median_point
from appliance.runtime.occupancy import HOLD_OCCUPANCY, near_mean

__all__ = ["SOURCE_WINDOW", "EventConfig", "EvidenceStream", "FrameEvidence", "LeakDetector",
           "LeakEvent", "Polygon", "evidence_from_fields", "zone_mask"]


#: Positive frames whose sources anchor a candidate event (start rule, LeakDetector._stayed).
ANCHOR_FRAMES = 5

#: Median ratio of a source's step along the flow to the flow's own step (px per frame
#: interval times the frames between two results) from which the candidate is a translating
#: object, not a plume (start rule, LeakDetector._translating).
TRANSLATION = 0.5

#: Frame intervals the start window and the minimum duration hold at least.
START_FRAMES = 8

#: Frame intervals the end window holds at least.
END_FRAMES = 20

#: Share of the frames of the last ``min_duration_s`` in which the place of a candidate's
#: source (one coverage cell around it) held gas, for the event to start.
PERSISTENCE = 0.8


class LeakDetector:
    """The event state machine (module docstring); feed it frames in time order.

    ``update`` returns the transitions the frame caused, as (kind, event) with kind
    ``"start"``, ``"update"`` (every frame of an ongoing event) or ``"end"``.
    """

    def __init__(self, cfg: EventConfig | None = None) -> None:
        self.cfg = cfg or EventConfig()
        self._recent: collections.deque[tuple[float, int, bool]] = collections.deque()
        self._ids = itertools.count(1)
        self.current: LeakEvent | None = None
        self.finished: list[LeakEvent] = []
        self._candidate_sources: collections.deque[tuple[float, float]] = collections.deque(
            maxlen=200)
        # Gas of the candidate's first positive frames (``_same_source``), kept while the
        # event lasts.
        self._anchor_coverage: np.ndarray | None = None
        # Gas of every frame of the last min_duration_s while no event is on (_persistent).
        self._coverages: collections.deque[tuple[float, np.ndarray | None]] = (
            collections.deque())
        self._last_resultant: tuple[float, float] | None = None
        # slow footage: (t, apex or None) of the frames of the last start window
        self._apexes: collections.deque[tuple[float, tuple[float, float] | None]] = (
            collections.deque())
        self._last_gas_t: float | None = None
        # (t, frame, source, mean flow) of the frames with coherent gas while no event is on
        self._track: collections.deque[
            tuple[float, int, tuple[float, float], tuple[float, float]]] = collections.deque()

    def positive(self, ev: FrameEvidence) -> bool:
        """Whether one frame, on its own, looks like a leak at the current source."""
        c = self.cfg
        if ev.occupancy is not None:
            return self._anchored(ev)
        if ev.gas_pixels < c.min_gas_pixels or ev.coherence < c.min_coherence:
            return False
        if ev.rate_g_s is not None and ev.rate_g_s < c.min_rate_g_s:
            return False
        ref = (self.current.source_xy if self.current is not None
               else (median_point(self._candidate_sources) if self._candidate_sources
                     else None))
        if self.current is None and ev.on_border:
            # only the jumping end of a plume whose source is known and under this gas
            return ref is not None and ev.covers(ref)
        return ref is None or self._same_source(ev, ref)

    def _anchored(self, ev: FrameEvidence) -> bool:
        """Slow footage: the plume anchored at the source (module docstring)."""
        if self.current is not None and self.current.source_xy is not None:
            return near_mean(ev.occupancy, self.current.source_xy) >= HOLD_OCCUPANCY
        return (ev.plume_px >= self.cfg.min_gas_pixels and ev.source_xy is not None
                and not ev.on_border)

    def _fixed_apex(self, now: float, window: float) -> bool:
        """Slow footage: at least ``start_fraction`` of the frames of the last ``window``
        have their plume's apex within ``max_source_shift_px`` of the median apex of the
        positive ones (the plume is anchored; while a plume builds up, its apex first lies
        downstream and then moves up to the source)."""
        frames = [xy for t, xy in self._apexes if t > now - window]
        points = [xy for xy in frames if xy is not None]
        if not points:
            return False
        ref = median_point(points)
        near = sum(np.hypot(x - ref[0], y - ref[1]) <= self.cfg.max_source_shift_px
                   for x, y in points)
        return near >= self.cfg.start_fraction * len(frames)

    def windows(self, ev: FrameEvidence) -> tuple[float, float, float]:
        """(min_duration_s, start_window_s, end_window_s) for the frame interval of ``ev``:
        the configured seconds, or :data:`START_FRAMES` / :data:`END_FRAMES` frame
        intervals when those are longer (slow footage)."""
        c, dt = self.cfg, ev.frame_interval_s or 0.0
        # the start window half as long again as the minimum duration, as configured (2, 3 s)
        return (max(c.min_duration_s, START_FRAMES * dt),
                max(c.start_window_s, 1.5 * START_FRAMES * dt),
                max(c.end_window_s, END_FRAMES * dt))

    def _same_source(self, ev: FrameEvidence, ref: tuple[float, float]) -> bool:
        """Whether the frame's source is the reference source ``ref`` (px).

        The upstream end of a billowing plume jumps (in the simulated site between its
        base and gas spread against the image edge, 50 px apart), so besides being close,
        the two count as one source when either lies under the other's gas: this frame's
        gas still covers ``ref``, or the gas of the candidate's first frames covered this
        frame's source. A moving object leaves both places behind.
        """
        if ev.source_xy is None:
            return True
        shift = np.hypot(ev.source_xy[0] - ref[0], ev.source_xy[1] - ref[1])
        return bool(shift <= self.cfg.max_source_shift_px or ev.covers(ref)
                    # the first frames' gas is a union: no extra margin around it
                    or covers(self._anchor_coverage, ev.source_xy, cells=0))

    def _fraction(self, now: float, window: float) -> tuple[float, float | None]:
        """Positive fraction of the frames in (now - window, now] and the first positive t."""
        items = [(t, p) for t, _, p in self._recent if t > now - window]
        if not items:
            return 0.0, None
        first = next((t for t, p in items if p), None)
        return sum(p for _, p in items) / len(items), first

    def _stayed(self, ev: FrameEvidence) -> bool:
        """Whether the candidate's first sources are still at this frame's source or under
        its gas: a warm object moving slowly enough to keep up with the running median is
        caught here, because it has left the place where it was first seen."""
        if ev.source_xy is None or not self._candidate_sources:
            return True
        return self._same_source(
            ev, median_point(list(self._candidate_sources)[:ANCHOR_FRAMES]))

    def _persistent(self, now: float, min_duration_s: float) -> bool:
        """Whether the place of the candidate's first sources (their median, one coverage
        cell around it) held gas in at least :data:`PERSISTENCE` of the frames of the last
        ``min_duration_s`` (module docstring)."""
        if not self._candidate_sources:
            return True
        # where the candidate was first seen: a running median would follow a moving object
        ref = median_point(list(self._candidate_sources)[:ANCHOR_FRAMES])
        spans = [cov for t, cov in self._coverages
                 if t >= now - min_duration_s and cov is not None]
        if not spans:
            return True  # evidence without gas maps (tests of the other rules)
        held = sum(covers(cov, ref) for cov in spans)
        return held >= PERSISTENCE * len(spans) and self._downstream(spans[-1], ref)

    def _downstream(self, coverage: np.ndarray, ref: tuple[float, float]) -> bool:
        """Whether the gas lies downstream of the source ``ref`` along the latest flow
        direction, as a plume does: after a warm object turns round, the smoothed "upstream"
        direction lags for seconds, its "source" is its leading end, and its body covers
        that place as it advances (it started events in the no-release scene)."""
        if self._last_resultant is None:
            return True
        ys, xs = np.nonzero(coverage)
        if len(xs) == 0:
            return True
        c = COVERAGE_CELL_PX
        centroid = ((xs.mean() + 0.5) * c - ref[0], (ys.mean() + 0.5) * c - ref[1])
        return bool(centroid[0] * self._last_resultant[0]
                    + centroid[1] * self._last_resultant[1] > 0.0)

    def _translating(self, now: float, min_duration_s: float) -> bool:
        """Whether the gas of the last ``min_duration_s`` moved as a whole: the median, over
        steps between consecutive frames, of the source's displacement along the mean flow
        divided by the flow's displacement is at least :data:`TRANSLATION` (module
        docstring). A median over at least 3 steps: a plume's upstream end that jumps once
        between two ends of its base, or one frame whose flow is near zero, does not decide.
        """
        rows = sorted((r for r in self._track if r[0] >= now - min_duration_s),
                      key=lambda r: r[1])
        ratios = []
        for (_, f0, s0, w0), (_, f1, s1, w1) in itertools.pairwise(rows):
            w = (0.5 * (w0[0] + w1[0]), 0.5 * (w0[1] + w1[1]))
            step = (f1 - f0) * (w[0] * w[0] + w[1] * w[1])  # |w|^2 per frame x frames
            if f1 > f0 and step > 0.0:
                ratios.append(((s1[0] - s0[0]) * w[0] + (s1[1] - s0[1]) * w[1]) / step)
        return len(ratios) >= 3 and float(np.median(ratios)) >= TRANSLATION

    def update(self, ev: FrameEvidence) -> list[tuple[str, LeakEvent]]:
        """Account one frame; return the transitions it caused."""
        c = self.cfg
        slow = ev.occupancy is not None
        min_duration, start_window, end_window = self.windows(ev)
        if not slow and ev.gas_pixels >= c.min_gas_pixels and moves(ev):
            if (self.current is None and self._last_gas_t is not None
                    and ev.t_s - self._last_gas_t > GAP_S):
                # gas after a gap is new evidence: a warm object walking out of the view and
                # back in under the old candidate's source started events with it
                self._forget_candidate()
                self._track.clear()
            self._last_gas_t = max(ev.t_s, self._last_gas_t or ev.t_s)
        pos = self.positive(ev)
        if pos and ev.source_xy is not None and self.current is None:
            self._candidate_sources.append(ev.source_xy)
            if len(self._candidate_sources) <= ANCHOR_FRAMES and ev.coverage is not None:
                self._anchor_coverage = (ev.coverage if self._anchor_coverage is None
                                         else self._anchor_coverage | ev.coverage)
        if ev.resultant is not None:
            self._last_resultant = ev.resultant
        self._recent.append((ev.t_s, ev.frame, pos))
        if slow:
            self._apexes.append((ev.t_s, ev.source_xy if pos else None))
            while self._apexes and self._apexes[0][0] <= ev.t_s - start_window:
                self._apexes.popleft()
        horizon = max(start_window, end_window, min_duration) + 1.0
        while self._recent and self._recent[0][0] < ev.t_s - horizon:
            self._recent.popleft()
        if self.current is None:
            self._coverages.append((ev.t_s, ev.coverage))
            while self._coverages and self._coverages[0][0] < ev.t_s - min_duration - 1.0:
                self._coverages.popleft()
            if (ev.source_xy is not None and ev.flow_px is not None
                    and ev.gas_pixels >= c.min_gas_pixels and ev.coherence >= c.min_coherence):
                self._track.append((ev.t_s, ev.frame, ev.source_xy, ev.flow_px))
            while self._track and self._track[0][0] < ev.t_s - min_duration - 1.0:
                self._track.popleft()
        out: list[tuple[str, LeakEvent]] = []
        if self.current is None:
            frac, first = self._fraction(ev.t_s, start_window)
            # slow footage: the occupancy map is the persistence, and the flow that the
            # translation rule reads means nothing there
            if (first is not None and frac >= c.start_fraction
                    and ev.t_s - first >= min_duration
                    and (self._fixed_apex(ev.t_s, start_window) if slow else
                         (self._stayed(ev) and self._persistent(ev.t_s, min_duration)
                          and not self._translating(ev.t_s, min_duration)))):
                start_frame = next(f for t, f, p in self._recent if t == first and p)
                self.current = LeakEvent(next(self._ids), first, start_frame)
                self.current.add(ev, pos)
                out.append(("start", self.current))
            elif frac == 0.0:
                self._forget_candidate()  # nothing recent
            return out
        self.current.add(self._at_event_source(ev), pos)
        frac, _ = self._fraction(ev.t_s, end_window)
        if frac < c.end_fraction and ev.t_s - self.current.start_t_s >= end_window:
            out.append(("end", self._close(ev, "gas gone")))
        else:
            out.append(("update", self.current))
        return out

    def _at_event_source(self, ev: FrameEvidence) -> FrameEvidence:
        """Slow footage: only the apex of a persistent plume in view counts towards the open
        event's source (the median of the newest :data:`SOURCE_WINDOW`): the apex of a plume
        still building up lies downstream and moves up to the source within a minute. The
        flow's coherence means nothing there: the occupancy around the source stands for it
        in the event's confidence."""
        if ev.occupancy is None:
            return ev
        cur = self.current
        held = near_mean(ev.occupancy, cur.source_xy) if cur and cur.source_xy else 0.0
        keep = (ev.source_xy is not None and ev.plume_px >= self.cfg.min_gas_pixels
                and not ev.on_border)
        return replace(ev, source_xy=ev.source_xy if keep else None, coherence=min(held, 1.0))

    def _close(self, ev: FrameEvidence, reason: str) -> LeakEvent:
        assert self.current is not None
        last = [(t, f) for t, f, p in self._recent if p]
        t_end, f_end = last[-1] if last else (ev.t_s, ev.frame)
        event = self.current
        event.end_t_s, event.end_frame, event.end_reason = t_end, f_end, reason
        self.finished.append(event)
        self.current = None
        self._forget_candidate()
        return event

    def _forget_candidate(self) -> None:
        self._candidate_sources.clear()
        self._anchor_coverage = None

    def close(self, t_s: float, frame: int, reason: str = "appliance stopped"
              ) -> LeakEvent | None:
        """End an ongoing event (shutdown, end of data); returns it, or None."""
        if self.current is None:
            return None
        return self._close(FrameEvidence(t_s, frame, 0, 0.0), reason)
