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
- *a source in view*: before an event has started, a frame whose upstream end touches the
  image border (within :data:`BORDER_PX`; its source within twice that) counts only when
  its gas covers the candidate's
  source: gas entering across the edge cannot be located, and a warm object walking slowly
  into the view keeps its trailing end pinned to the border for seconds;
- *persistence with hysteresis*: an event starts when the positive frames cover at least
  ``start_fraction`` of the last ``start_window_s`` and have lasted ``min_duration_s``;
  it ends when they cover less than ``end_fraction`` of the last ``end_window_s``.

The event's start is back-dated to its first positive frame, its end to its last.
"""

from __future__ import annotations

import collections
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

Polygon = Sequence[tuple[float, float]]


@dataclass(frozen=True)
class EventConfig:
    """Thresholds of the leak-event logic (config section ``events``).

    Attributes
    ----------
    min_gas_pixels : int
        Gas pixels inside the watched zones for a frame to count as positive.
    min_coherence : float
        Smallest flow coherence (0-1) of a positive frame.
    min_rate_g_s : float
        Smallest emission rate of a positive frame when the rate is known (0: any).
    max_source_shift_px : float
        Largest distance of a frame's source from the event's median source, px.
    min_duration_s, start_window_s, start_fraction : float
        Start rule (module docstring).
    end_window_s, end_fraction : float
        End rule (module docstring).
    watch_zones, ignore_zones : tuple of polygons
        Polygons in left-image pixel coordinates; no watch zone = the whole image.
    """

    min_gas_pixels: int = 150
    min_coherence: float = 0.5
    min_rate_g_s: float = 0.0
    max_source_shift_px: float = 25.0
    min_duration_s: float = 2.0
    start_window_s: float = 3.0
    start_fraction: float = 0.6
    end_window_s: float = 6.0
    end_fraction: float = 0.2
    watch_zones: tuple[tuple[tuple[float, float], ...], ...] = ()
    ignore_zones: tuple[tuple[tuple[float, float], ...], ...] = ()


def zone_mask(shape: tuple[int, int], watch: Sequence[Polygon] = (),
              ignore: Sequence[Polygon] = ()) -> np.ndarray:
    """Pixels the event logic looks at: inside a watch zone (all when none) and no ignore zone.

    Returns
    -------
    ndarray, shape ``shape``, bool
    """
    import cv2

    h, w = shape
    if watch:
        m = np.zeros((h, w), np.uint8)
        cv2.fillPoly(m, [np.round(np.asarray(p, np.float64)).astype(np.int32) for p in watch], 1)
    else:
        m = np.ones((h, w), np.uint8)
    if ignore:
        cv2.fillPoly(m, [np.round(np.asarray(p, np.float64)).astype(np.int32) for p in ignore],
                     0)
    return m.astype(bool)


@dataclass(frozen=True)
class FrameEvidence:
    """What one processed frame says about a leak.

    Attributes
    ----------
    t_s : float
        Frame time, s (any monotonic origin).
    frame : int
        Frame or pair index (reports).
    gas_pixels : int
        Gas pixels inside the zones.
    coherence : float
        Mean resultant length of the flow directions over those pixels (0-1).
    source_xy : (float, float) or None
        Upstream end of the plume, px.
    rate_g_s : float or None
        Emission rate of the frame, when known.
    velocity_m_s : (float, float, float) or None
        Mean 3D gas velocity.
    wind_m_s : (float, float, float) or None
        Anemometer wind in the camera frame.
    source_xyz_m : (float, float, float) or None
        3D position of the source, m (camera frame).
    resultant : (float, float) or None
        Mean unit flow direction of the gas pixels (length = coherence).
    on_border : bool
        Some of the most upstream gas pixels lie within :data:`BORDER_PX` of the image's
        edge (the gas enters the view there), or the source within twice that.
    coverage : ndarray, shape (ceil(H / COVERAGE_CELL_PX), ceil(W / COVERAGE_CELL_PX)), bool
        Which cells of the image hold gas (to ask whether a source is still under gas).
    """

    t_s: float
    frame: int
    gas_pixels: int
    coherence: float
    source_xy: tuple[float, float] | None = None
    rate_g_s: float | None = None
    velocity_m_s: tuple[float, float, float] | None = None
    wind_m_s: tuple[float, float, float] | None = None
    source_xyz_m: tuple[float, float, float] | None = None
    resultant: tuple[float, float] | None = None
    on_border: bool = False
    coverage: np.ndarray | None = field(default=None, compare=False, repr=False)

    def covers(self, xy: tuple[float, float]) -> bool:
        """Whether this frame's gas lies within one coverage cell of ``xy`` (px)."""
        return covers(self.coverage, xy)


def covers(coverage: np.ndarray | None, xy: tuple[float, float], cells: int = 1) -> bool:
    """Whether a coverage grid (:attr:`FrameEvidence.coverage`) holds gas within ``cells``
    cells (of ``COVERAGE_CELL_PX``) of the point ``xy`` (px)."""
    if coverage is None:
        return False
    i, j = int(xy[1]) // COVERAGE_CELL_PX, int(xy[0]) // COVERAGE_CELL_PX
    h, w = coverage.shape
    return bool(coverage[max(i - cells, 0):min(i + cells + 1, h),
                         max(j - cells, 0):min(j + cells + 1, w)].any())


#: Positive frames whose sources anchor a candidate event (start rule, LeakDetector._stayed).
ANCHOR_FRAMES = 5

#: Cell size of :attr:`FrameEvidence.coverage`, px (a 320 x 240 frame: 40 x 30 cells).
COVERAGE_CELL_PX = 8

#: Gas this close to the image's edge among a frame's most upstream pixels means it enters
#: the view there, px (start rule).
BORDER_PX = 8

#: Share of the frames of the last ``min_duration_s`` in which the place of a candidate's
#: source (one coverage cell around it) held gas, for the event to start.
PERSISTENCE = 0.8


def _coverage(mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    c = COVERAGE_CELL_PX
    padded = np.zeros((-(-h // c) * c, -(-w // c) * c), bool)
    padded[:h, :w] = mask
    return padded.reshape(padded.shape[0] // c, c, padded.shape[1] // c, c).any(axis=(1, 3))


def evidence_from_fields(t_s: float, frame: int, gas_mask: np.ndarray, flow: np.ndarray,
                         zones: np.ndarray | None = None, *,
                         direction: tuple[float, float] | None = None,
                         **extra: object) -> FrameEvidence:
    """Evidence of one frame from its gas mask (H, W) and image-plane flow (H, W, 2).

    The source is the mean position of the 2 % most upstream gas pixels along ``direction``
    (unit vector in the image, px; default: the frame's mean flow direction); ``extra``
    fills the optional fields of :class:`FrameEvidence`.
    """
    mask = np.asarray(gas_mask, bool)
    if zones is not None:
        mask = mask & zones
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return FrameEvidence(t_s, frame, 0, 0.0, **extra)  # type: ignore[arg-type]
    f = np.asarray(flow, np.float64)[ys, xs]
    mag = np.hypot(f[:, 0], f[:, 1])
    moving = mag > 1e-3
    if not moving.any():
        return FrameEvidence(t_s, frame, len(xs), 0.0, **extra)  # type: ignore[arg-type]
    unit = f[moving] / mag[moving, None]
    resultant = unit.mean(axis=0)
    coherence = float(np.hypot(*resultant))
    d = (np.asarray(direction, np.float64) if direction is not None
         else resultant / max(coherence, 1e-12))
    along = xs * d[0] + ys * d[1]
    up = along <= np.percentile(along, 2.0)
    source = (float(xs[up].mean()), float(ys[up].mean()))
    h, w = mask.shape
    # any of the most upstream pixels at the edge, not only their mean (a warm object walking
    # into the view has its upstream end on the edge, its mean 15-20 px inside); and a
    # source within two border widths (a strip along the edge where registration resamples)
    ux, uy = xs[up], ys[up]
    on_border = bool(min(ux.min(), uy.min(), w - 1 - ux.max(), h - 1 - uy.max()) < BORDER_PX
                     or min(source[0], source[1], w - 1 - source[0], h - 1 - source[1])
                     < 2 * BORDER_PX)
    return FrameEvidence(t_s, frame, len(xs), coherence, source,  # type: ignore[arg-type]
                         resultant=(float(resultant[0]), float(resultant[1])),
                         on_border=on_border, coverage=_coverage(mask), **extra)


class EvidenceStream:
    """Per-frame evidence of one camera stream, with the plume's direction smoothed in time.

    The upstream end of a bent or billowing plume depends strongly on the direction it is
    measured along: with each frame's own mean flow direction, the source of a real plume
    jumped between two ends of its base (50 px apart in the simulated site), so the
    fixed-source rule rejected about half of its frames and an event started or not by
    chance. Along the direction averaged over ``tau_s`` the source stays put, while a moving
    object's trailing end still travels with it.

    Parameters
    ----------
    zones : ndarray (H, W) of bool, optional
        From :func:`zone_mask`.
    tau_s : float
        Time constant of the exponential average of the flow resultant, s.
    """

    def __init__(self, zones: np.ndarray | None = None, tau_s: float = 3.0) -> None:
        self.zones = zones
        self.tau_s = tau_s
        self._mean: np.ndarray | None = None
        self._t: float | None = None

    def __call__(self, t_s: float, frame: int, gas_mask: np.ndarray, flow: np.ndarray,
                 **extra: object) -> FrameEvidence:
        """Evidence of one frame (frames may arrive slightly out of order)."""
        direction = None
        if self._mean is not None and np.hypot(*self._mean) > 1e-6:
            direction = tuple(self._mean / np.hypot(*self._mean))
        ev = evidence_from_fields(t_s, frame, gas_mask, flow, self.zones,
                                  direction=direction, **extra)  # type: ignore[arg-type]
        if ev.resultant is not None:
            r = np.asarray(ev.resultant)
            if self._mean is None or self._t is None:
                self._mean, self._t = r, t_s
            else:
                a = 1.0 - np.exp(-max(t_s - self._t, 0.0) / self.tau_s)
                self._mean = self._mean + max(a, 0.02) * (r - self._mean)
                self._t = max(self._t, t_s)
        return ev


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
    _sources: list[tuple[float, float]] = field(default_factory=list, repr=False)
    _rates: list[float] = field(default_factory=list, repr=False)
    _velocities: list[tuple[float, float, float]] = field(default_factory=list, repr=False)
    _winds: list[tuple[float, float, float]] = field(default_factory=list, repr=False)
    _coherence: list[float] = field(default_factory=list, repr=False)

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
            self.source_xy = _median_point(self._sources)
        if ev.source_xyz_m is not None:
            self.source_xyz_m = ev.source_xyz_m
        if ev.rate_g_s is not None:
            self._rates.append(ev.rate_g_s)
            self.peak_rate_g_s = max(self._rates)
            self.mean_rate_g_s = float(np.mean(self._rates))
        if ev.velocity_m_s is not None:
            self._velocities.append(ev.velocity_m_s)
            self.mean_velocity_m_s = _mean3(self._velocities)
        if ev.wind_m_s is not None:
            self._winds.append(ev.wind_m_s)
            self.mean_wind_m_s = _mean3(self._winds)
        self._coherence.append(ev.coherence)
        self.confidence = float(self.positive_frames / self.frames * np.mean(self._coherence))

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (no private lists)."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_")}


def _median_point(points: Sequence[tuple[float, float]]) -> tuple[float, float]:
    a = np.asarray(list(points)[-200:], np.float64)
    return float(np.median(a[:, 0])), float(np.median(a[:, 1]))


def _mean3(vs: Sequence[tuple[float, float, float]]) -> tuple[float, float, float]:
    m = np.mean(np.asarray(vs, np.float64), axis=0)
    return float(m[0]), float(m[1]), float(m[2])


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

    def positive(self, ev: FrameEvidence) -> bool:
        """Whether one frame, on its own, looks like a leak at the current source."""
        c = self.cfg
        if ev.gas_pixels < c.min_gas_pixels or ev.coherence < c.min_coherence:
            return False
        if ev.rate_g_s is not None and ev.rate_g_s < c.min_rate_g_s:
            return False
        ref = (self.current.source_xy if self.current is not None
               else (_median_point(self._candidate_sources) if self._candidate_sources
                     else None))
        if self.current is None and ev.on_border:
            # only the jumping end of a plume whose source is known and under this gas
            return ref is not None and ev.covers(ref)
        return ref is None or self._same_source(ev, ref)

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
            ev, _median_point(list(self._candidate_sources)[:ANCHOR_FRAMES]))

    def _persistent(self, now: float) -> bool:
        """Whether the place of the candidate's first sources (their median, one coverage
        cell around it) held gas in at least :data:`PERSISTENCE` of the frames of the last
        ``min_duration_s`` (module docstring)."""
        if not self._candidate_sources:
            return True
        # where the candidate was first seen: a running median would follow a moving object
        ref = _median_point(list(self._candidate_sources)[:ANCHOR_FRAMES])
        spans = [cov for t, cov in self._coverages
                 if t >= now - self.cfg.min_duration_s and cov is not None]
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

    def update(self, ev: FrameEvidence) -> list[tuple[str, LeakEvent]]:
        """Account one frame; return the transitions it caused."""
        c = self.cfg
        pos = self.positive(ev)
        if pos and ev.source_xy is not None and self.current is None:
            self._candidate_sources.append(ev.source_xy)
            if len(self._candidate_sources) <= ANCHOR_FRAMES and ev.coverage is not None:
                self._anchor_coverage = (ev.coverage if self._anchor_coverage is None
                                         else self._anchor_coverage | ev.coverage)
        if ev.resultant is not None:
            self._last_resultant = ev.resultant
        self._recent.append((ev.t_s, ev.frame, pos))
        horizon = max(c.start_window_s, c.end_window_s, c.min_duration_s) + 1.0
        while self._recent and self._recent[0][0] < ev.t_s - horizon:
            self._recent.popleft()
        if self.current is None:
            self._coverages.append((ev.t_s, ev.coverage))
            while self._coverages and self._coverages[0][0] < ev.t_s - c.min_duration_s - 1.0:
                self._coverages.popleft()
        out: list[tuple[str, LeakEvent]] = []
        if self.current is None:
            frac, first = self._fraction(ev.t_s, c.start_window_s)
            if (first is not None and frac >= c.start_fraction
                    and ev.t_s - first >= c.min_duration_s and self._stayed(ev)
                    and self._persistent(ev.t_s)):
                start_frame = next(f for t, f, p in self._recent if t == first and p)
                self.current = LeakEvent(next(self._ids), first, start_frame)
                self.current.add(ev, pos)
                out.append(("start", self.current))
            elif frac == 0.0:
                self._forget_candidate()  # nothing recent
            return out
        self.current.add(ev, pos)
        frac, _ = self._fraction(ev.t_s, c.end_window_s)
        if frac < c.end_fraction and ev.t_s - self.current.start_t_s >= c.end_window_s:
            out.append(("end", self._close(ev, "gas gone")))
        else:
            out.append(("update", self.current))
        return out

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
