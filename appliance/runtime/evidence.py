"""Per-frame evidence of a leak: what one processed frame says, for the event logic.

From a frame's gas mask and image-plane flow (:func:`evidence_from_fields`): the gas pixels
inside the watched zones (:func:`zone_mask`), how coherently they move, where the plume's
upstream end (its source) lies, whether it touches the image border, and a coarse grid of
where gas is (to ask later whether a place is still under gas).
:class:`EvidenceStream` measures "upstream" along the flow direction averaged over a few
seconds. The decisions are in :mod:`appliance.runtime.events`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from appliance.runtime.occupancy import CELL_PX, OccupancyModel, persistent_plume

Polygon = Sequence[tuple[float, float]]


def zone_mask(shape: tuple[int, int], watch: Sequence[Polygon] = (),
              ignore: Sequence[Polygon] = ()) -> np.ndarray:
    """Pixels the event logic looks at: inside a watch zone (all when none) and no ignore zone.

    Returns
    -------
    ndarray, shape ``shape``, bool
    """
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
    flow_px : (float, float) or None
        Mean image flow of the gas pixels, px per frame interval (the chain's w_L, Eq. 5):
        how far the gas moves from one frame to the next.
    on_border : bool
        Some of the most upstream gas pixels lie within :data:`BORDER_PX` of the image's
        edge (the gas enters the view there), or the source within twice that.
    coverage : ndarray, shape (ceil(H / COVERAGE_CELL_PX), ceil(W / COVERAGE_CELL_PX)), bool
        Which cells of the image hold gas (to ask whether a source is still under gas).
    frame_interval_s : float or None
        Time between the camera frames the chain compared, s (None: not known, the chain's
        own rate); the event logic's windows hold at least a few frames of it.
    occupancy : ndarray (cells of :data:`appliance.runtime.occupancy.CELL_PX`) or None
        Footage slower than :data:`FLOW_MAX_INTERVAL_S` only: the running occupancy map
        (:class:`~appliance.runtime.occupancy.OccupancyModel`); ``source_xy`` is then the
        apex of its persistent plume and ``on_border`` whether that apex is at the edge.
    plume_px : int
        With ``occupancy``: area of the persistent plume, px.
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
    flow_px: tuple[float, float] | None = None
    on_border: bool = False
    coverage: np.ndarray | None = field(default=None, compare=False, repr=False)
    frame_interval_s: float | None = None
    occupancy: np.ndarray | None = field(default=None, compare=False, repr=False)
    plume_px: int = 0

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


#: Cell size of :attr:`FrameEvidence.coverage`, px (a 320 x 240 frame: 40 x 30 cells).
COVERAGE_CELL_PX = 8

#: After this long without gas, gas is new evidence, s: its flow direction is averaged
#: afresh (EvidenceStream) and a candidate event starts afresh (LeakDetector).
GAP_S = 1.0

#: Gas whose mean flow is slower than this does not move, px per frame interval: it says
#: nothing about a direction and does not end a gap (GAP_S). The no-release scene gave
#: frames of 5000-17000 "gas" pixels at 0.04 px per frame (a glitch of the chain; the
#: walker moves at 1.4, the simulated plume at 6).
MIN_FLOW_PX = 0.2

#: Longest frame interval over which the chain's flow follows the gas, s: the differential
#: images of the plume stay alike over a few camera frames at 30 Hz, not over a second (at
#: 1 frame/s the mean flow of the segmented gas measured 30-90 px per frame in random
#: directions). Slower footage is judged by where gas stays (:mod:`appliance.runtime.
#: occupancy`) instead of how it moves.
FLOW_MAX_INTERVAL_S = 0.2

#: Gas this close to the image's edge among a frame's most upstream pixels means it enters
#: the view there, px (start rule).
BORDER_PX = 8


def moves(ev: FrameEvidence) -> bool:
    """Whether the frame's gas moves (mean flow at least :data:`MIN_FLOW_PX`); evidence
    without a mean flow counts as moving."""
    return ev.flow_px is None or float(np.hypot(*ev.flow_px)) >= MIN_FLOW_PX


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
    """Evidence of one frame from its gas mask (H, W) and image-plane flow, px.

    ``flow`` is the whole field (H, W, 2) or only its values at the N gas pixels of
    ``gas_mask`` in row-major order, (N, 2): what a live worker sends (a fifth of the
    bytes). The source is the mean position of the 2 % most upstream gas pixels along
    ``direction`` (unit vector in the image, px; default: the frame's mean flow direction);
    ``extra`` fills the optional fields of :class:`FrameEvidence`.
    """
    mask = np.asarray(gas_mask, bool)
    flow = np.asarray(flow)
    if flow.ndim == 2:
        idx = np.flatnonzero(mask)
        if flow.shape != (idx.size, 2):
            raise ValueError(f"flow at the gas pixels must have shape ({idx.size}, 2), "
                             f"got {flow.shape}")
        if zones is not None:
            keep = zones.ravel()[idx]
            idx, flow = idx[keep], flow[keep]
            mask = mask & zones
        ys, xs = np.divmod(idx, mask.shape[1])
    else:
        if zones is not None:
            mask = mask & zones
        ys, xs = np.nonzero(mask)
        flow = flow[ys, xs]
    if len(xs) == 0:
        return FrameEvidence(t_s, frame, 0, 0.0, **extra)  # type: ignore[arg-type]
    # one contiguous float64 column per component: numpy's (N, 2) reductions along axis 0
    # took 0.7 of the 1.3 ms of a 12 800-pixel plume in the daemon's results thread
    u = flow[:, 0].astype(np.float64)
    v = flow[:, 1].astype(np.float64)
    mag = np.hypot(u, v)
    moving = mag > 1e-3
    if not moving.any():
        return FrameEvidence(t_s, frame, len(xs), 0.0, **extra)  # type: ignore[arg-type]
    if not moving.all():
        u_m, v_m, mag_m = u[moving], v[moving], mag[moving]
    else:
        u_m, v_m, mag_m = u, v, mag
    resultant = np.array([np.mean(u_m / mag_m), np.mean(v_m / mag_m)])
    mean_flow = np.array([u.mean(), v.mean()])
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
                         flow_px=(float(mean_flow[0]), float(mean_flow[1])),
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
    gap_s : float
        After this long without gas the average restarts from the next frame's own
        direction, s.
    frame_interval_s : float, optional
        Time between the camera frames of one triple, s. Above :data:`FLOW_MAX_INTERVAL_S`
        the evidence carries the occupancy map and its plume's apex as the source.
    """

    def __init__(self, zones: np.ndarray | None = None, tau_s: float = 3.0,
                 gap_s: float = GAP_S, frame_interval_s: float | None = None) -> None:

        self.zones = zones
        self.tau_s = tau_s
        self.gap_s = gap_s
        self.frame_interval_s = frame_interval_s
        self.occupancy = (OccupancyModel(frame_interval_s) if frame_interval_s is not None
                          and frame_interval_s > FLOW_MAX_INTERVAL_S else None)
        self._mean: np.ndarray | None = None
        self._t: float | None = None

    def __call__(self, t_s: float, frame: int, gas_mask: np.ndarray, flow: np.ndarray,
                 **extra: object) -> FrameEvidence:
        """Evidence of one frame (frames may arrive slightly out of order)."""
        if self._t is not None and t_s - self._t > self.gap_s:
            # after ``gap_s`` without gas the average belongs to gas that has gone: a warm
            # object coming back into view along it had its "source" at its leading end,
            # inside the view, and then pinned to the border under its own gas (the border
            # rule let it start events in the no-release scene)
            self._mean, self._t = None, None
        direction = None
        if self._mean is not None and np.hypot(*self._mean) > 1e-6:
            direction = tuple(self._mean / np.hypot(*self._mean))
        ev = evidence_from_fields(t_s, frame, gas_mask, flow, self.zones,
                                  direction=direction, frame_interval_s=self.frame_interval_s,
                                  **extra)  # type: ignore[arg-type]
        if self.occupancy is not None:
            return self._anchored(ev, gas_mask)
        if ev.resultant is not None and moves(ev):
            r = np.asarray(ev.resultant)
            if self._mean is None or self._t is None:
                self._mean, self._t = r, t_s
            else:
                a = 1.0 - np.exp(-max(t_s - self._t, 0.0) / self.tau_s)
                self._mean = self._mean + max(a, 0.02) * (r - self._mean)
                self._t = max(self._t, t_s)
        return ev

    def _anchored(self, ev: FrameEvidence, gas_mask: np.ndarray) -> FrameEvidence:
        """Slow footage: the evidence of the occupancy map (frame ``ev`` added)."""

        assert self.occupancy is not None
        mask = np.asarray(gas_mask, bool)
        occ = self.occupancy.update(ev.t_s, mask if self.zones is None else mask & self.zones)
        region, apex = persistent_plume(occ)
        h, w = mask.shape
        edge = apex is not None and min(apex[0], apex[1], w - 1 - apex[0],
                                        h - 1 - apex[1]) < 2 * BORDER_PX
        return replace(ev, source_xy=apex, on_border=bool(edge), occupancy=occ.copy(),
                       plume_px=int(region.sum()) * CELL_PX * CELL_PX)
