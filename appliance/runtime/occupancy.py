"""Where gas stays: a running occupancy map of the gas mask, for footage too slow for the flow.

The chain's flow (Eq. 5) follows the gas between two differential images one frame interval
apart; it needs the gas texture to move a few pixels per interval and keep its shape. One
frame per second (the GasVid videos) is 30 times slower than the cameras the chain is built
for: there, the mean flow of the segmented gas measured 30-90 px per frame in random
directions, so its direction, coherence and the "translating source" test say nothing, and
the upstream end along it (the old source) landed anywhere in the plume.

What does survive a slow frame rate is *where* gas keeps being segmented. A leak feeds a
plume anchored at its source: the cells next to the source hold gas in most frames, for
minutes. Cloud texture drifting across the sky, noise and a passing warm object are
segmented in one place for a few frames only. :class:`OccupancyModel` keeps, per cell of
:data:`CELL_PX`, an exponential average of the share of gas pixels (time constant
:data:`OCCUPANCY_FRAMES` frame intervals); the persistent plume is its largest connected
region above :data:`START_OCCUPANCY`, and its source the point of that region farthest,
inside the region, from where it leaves the view (the apex of the plume), or, for a plume
wholly in view, the more occupied end of its longest path.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: Cell of the occupancy map, px (a 320 x 240 frame: 80 x 60 cells).
CELL_PX = 4

#: Time constant of the occupancy average in frame intervals: 20 s at 1 frame/s. In the
#: no-release and leak class 0 minutes of the development videos the largest cell reached
#: 0.32 and 0.35 with it (0.50 and 0.55 with 10 frames); a plume from 278 g/h on, 0.8-1.
OCCUPANCY_FRAMES = 20.0

#: Occupancy of the cells of a persistent plume (start rule): well above the 0.35 that
#: cloud texture reached in the development videos.
START_OCCUPANCY = 0.6

#: Mean occupancy of the cells within :data:`HOLD_CELLS` of an open event's source that keeps
#: the event going: the plume is still anchored there. At 6.9 m the biggest releases fill the
#: view and the segmentation drops whole frames; the source cells then fell to 0.2-0.3 (5th
#: percentile), while before any visible leak they stayed below 0.2 (at the source) and 0.01
#: (median).
HOLD_OCCUPANCY = 0.15

#: Half-width of the source neighbourhood of :data:`HOLD_OCCUPANCY`, cells.
HOLD_CELLS = 2

#: Occupancy of the region whose contrast is the plume's apparent size
#: (:func:`appliance.evaluation.labelled.apparent_size`): the gas present a good share of
#: the time, not only the cells above the start threshold (which the largest plumes at
#: 6.9 m leave).
REGION_OCCUPANCY = 0.3


class OccupancyModel:
    """Exponential average of the gas share per cell (module docstring).

    Parameters
    ----------
    frame_interval_s : float
        Time between consecutive frames of the footage, s.
    """

    def __init__(self, frame_interval_s: float) -> None:
        if not frame_interval_s > 0:
            raise ValueError(f"frame interval must be > 0, got {frame_interval_s}")
        self.frame_interval_s = frame_interval_s
        self.tau_s = OCCUPANCY_FRAMES * frame_interval_s
        self.map: np.ndarray | None = None
        self._t: float | None = None

    def update(self, t_s: float, mask: np.ndarray) -> np.ndarray:
        """Account one frame's gas mask (H, W) at time ``t_s``; returns the map (cells).

        A frame that is missing counts as a frame without gas: the map decays with the time
        since the last frame, so a gap in the footage weakens the evidence, never builds it.
        """
        share = _cell_share(np.asarray(mask, bool))
        if self.map is None or self._t is None or self.map.shape != share.shape:
            self.map = np.zeros_like(share)
        else:
            # one frame interval of decay per frame; longer after a gap
            extra = max(t_s - self._t - self.frame_interval_s, 0.0)
            self.map *= np.float32(np.exp(-extra / self.tau_s))
        a = np.float32(1.0 - np.exp(-self.frame_interval_s / self.tau_s))
        self.map += a * (share - self.map)
        self._t = t_s if self._t is None else max(self._t, t_s)
        return self.map


def _cell_share(mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    c = CELL_PX
    padded = np.zeros((-(-h // c) * c, -(-w // c) * c), np.float32)
    padded[:h, :w] = mask
    return padded.reshape(padded.shape[0] // c, c, padded.shape[1] // c, c).mean(axis=(1, 3))


def persistent_plume(occupancy: np.ndarray, threshold: float = START_OCCUPANCY
                     ) -> tuple[np.ndarray, tuple[float, float] | None]:
    """The largest connected region of cells at or above ``threshold`` and its apex.

    Returns
    -------
    region : ndarray (cells), bool
        Empty when no cell reaches the threshold.
    source_xy : (float, float) or None
        The apex, px (module docstring); None for an empty region.
    """
    above = occupancy >= threshold
    labels, n = ndimage.label(above, np.ones((3, 3), bool))
    if n == 0:
        return above, None
    sizes = ndimage.sum_labels(above, labels, range(1, n + 1))
    region = labels == int(np.argmax(sizes)) + 1
    return region, _apex(region, occupancy)


def _geodesic(region: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Steps (8-connected, inside ``region``) from the nearest seed cell; -1 = unreached."""
    dist = np.full(region.shape, -1, np.int32)
    front = seeds & region
    seen = front.copy()
    dist[front] = 0
    step, k = np.ones((3, 3), bool), 0
    while front.any():
        k += 1
        front = ndimage.binary_dilation(front, step) & region & ~seen
        dist[front] = k
        seen |= front
    return dist


def _far_end(dist: np.ndarray) -> tuple[float, float]:
    """Centre (px) of the cells at the largest distance (within one step of it)."""
    ys, xs = np.nonzero(dist >= dist.max() - 1)
    return (float(xs.mean()) + 0.5) * CELL_PX, (float(ys.mean()) + 0.5) * CELL_PX


def _apex(region: np.ndarray, occupancy: np.ndarray) -> tuple[float, float]:
    edge = np.zeros_like(region)
    edge[:2, :] = edge[-2:, :] = edge[:, :2] = edge[:, -2:] = True
    exits = region & edge
    if exits.any():
        return _far_end(_geodesic(region, exits))
    # wholly in view: the two ends of its longest path; the source end holds gas more often
    ys, xs = np.nonzero(region)
    ends = []
    seed = (int(ys[0]), int(xs[0]))
    for _ in range(2):
        start = np.zeros_like(region)
        start[seed] = True
        d = _geodesic(region, start)
        seed = np.unravel_index(int(np.argmax(d)), region.shape)
        ends.append(((seed[1] + 0.5) * CELL_PX, (seed[0] + 0.5) * CELL_PX))
    return max(ends, key=lambda xy: near_mean(occupancy, xy))


def near_mean(occupancy: np.ndarray | None, xy: tuple[float, float],
              cells: int = HOLD_CELLS) -> float:
    """Mean occupancy of the cells within ``cells`` of the point ``xy`` (px); 0 without map."""
    if occupancy is None:
        return 0.0
    i, j = int(xy[1]) // CELL_PX, int(xy[0]) // CELL_PX
    h, w = occupancy.shape
    patch = occupancy[max(i - cells, 0):min(i + cells + 1, h),
                      max(j - cells, 0):min(j + cells + 1, w)]
    return float(patch.mean()) if patch.size else 0.0
