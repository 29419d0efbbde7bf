"""Where the control curtains go: downstream of the detected source, across the plume.

The source is where gas appears: the upstream end of the segmented plume along its mean
image-plane motion. Near the source the flow reads the gas too fast: new gas appearing there
breaks brightness constancy (docs/accuracy.md, Table 3), and the dense core of
a young plume, not yet carried at the wind's speed, moves slower than its edges, while the
flow of differential images follows the edges (the steady core changes little between
frames and gives the flow nothing to track; the smoothness term fills it in from the fast
edges). Measured against the simulator's truth on the ten ``eval emission`` sequences, the
curtain 12 px past the source read +6 % to +120 % (the flow alone: its rate with the true
flow was within 2 %), the ones past the first fifth of the plume within a few %. So the
first ``exclusion_fraction`` of the plume's length (at least ``exclusion_px``) is left out;
the curtains are evenly spaced over the rest of the plume, each perpendicular to the mean
motion and long enough to cut the whole plume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from processing.emission.curtains import Curtain

#: Defaults of :func:`place_curtains` in px of 320x240 frames (measured there).
EXCLUSION_PX = 12.0
MIN_PIXELS = 30
MARGIN_PX = 4.0


@dataclass(frozen=True)
class Placement:
    """Curtains of one frame and why there are none.

    Attributes
    ----------
    curtains : tuple of Curtain
        Oriented so that positive flux leaves the source.
    source_xy : (float, float) or None
        Detected source location in the left image, px.
    direction_xy : (float, float) or None
        Unit mean image-plane direction of the gas motion.
    reason : str
        Empty when curtains exist; otherwise why not ("no gas", "no motion",
        "plume too short").
    """

    curtains: tuple[Curtain, ...]
    source_xy: tuple[float, float] | None
    direction_xy: tuple[float, float] | None
    reason: str = ""


def place_curtains(gas_mask: np.ndarray, flow: np.ndarray, *, n_curtains: int = 5,
                   exclusion_px: float = EXCLUSION_PX, exclusion_fraction: float = 0.2,
                   min_pixels: int = MIN_PIXELS, margin_px: float = MARGIN_PX) -> Placement:
    """Curtains across the plume, downstream of its source.

    Parameters
    ----------
    gas_mask : ndarray, shape (H, W), bool
        Segmented gas (Eq. 9).
    flow : ndarray, shape (H, W, 2)
        Image-plane flow (u, v) of the gas, px per frame (its direction matters only).
    n_curtains : int
        Curtains per frame.
    exclusion_px : float
        Least distance downstream of the source without curtains, px.
    exclusion_fraction : float
        Share of the plume's length (2nd to 98th percentile along the motion) downstream
        of the source without curtains, in [0, 1) (module docstring).
    min_pixels : int
        Fewest gas pixels for a placement.
    margin_px : float
        Extra length on each side of the plume's width, and distance kept from the plume's
        downstream tip, px.

    Returns
    -------
    Placement
    """
    if not 0.0 <= exclusion_fraction < 1.0:
        raise ValueError(f"exclusion_fraction must be in [0, 1), got {exclusion_fraction!r}")
    mask = np.asarray(gas_mask, bool)
    at = np.flatnonzero(mask)
    if len(at) < min_pixels:
        return Placement((), None, None, "no gas")
    ys, xs = np.divmod(at, mask.shape[1])
    f = np.asarray(np.reshape(flow, (-1, 2))[at], np.float64)  # the gas pixels, then widened
    # the same sum and division; nanmean's NaN handling costs a third of the placement
    mean = np.nanmean(f, axis=0) if np.isnan(f).any() else f.mean(axis=0)
    norm = float(np.hypot(*mean))
    if not np.isfinite(norm) or norm < 1e-3:
        return Placement((), None, None, "no motion")
    d = mean / norm
    perp = np.array([-d[1], d[0]])
    pts = np.column_stack([xs, ys]).astype(np.float64)
    along = pts @ d
    across = pts @ perp
    lo, hi = np.percentile(along, [2.0, 98.0])
    upstream = along <= lo
    source = pts[upstream].mean(axis=0)
    first, last = lo + max(exclusion_px, exclusion_fraction * (hi - lo)), hi - margin_px
    if last - first < max(2.0, n_curtains):
        return Placement((), (float(source[0]), float(source[1])), (float(d[0]), float(d[1])),
                         "plume too short")
    h, w = mask.shape
    curtains = []
    for t in np.linspace(first, last, n_curtains):
        near = np.abs(along - t) <= 1.5
        a_lo, a_hi = ((across[near].min(), across[near].max()) if near.any()
                      else (across.min(), across.max()))
        a_lo, a_hi = a_lo - margin_px, a_hi + margin_px
        p0 = _clip_to_image(t * d + a_lo * perp, w, h)
        p1 = _clip_to_image(t * d + a_hi * perp, w, h)
        if np.hypot(*(p1 - p0)) < 1.0:
            continue
        curtains.append(Curtain((float(p0[0]), float(p0[1])), (float(p1[0]), float(p1[1])),
                                _orientation(p0, p1, d)))
    if not curtains:
        return Placement((), (float(source[0]), float(source[1])), (float(d[0]), float(d[1])),
                         "plume too short")
    return Placement(tuple(curtains), (float(source[0]), float(source[1])),
                     (float(d[0]), float(d[1])))


def _clip_to_image(p: np.ndarray, w: int, h: int) -> np.ndarray:
    return np.array([min(max(p[0], 0.0), w - 1.0), min(max(p[1], 0.0), h - 1.0)])


def _orientation(p0: np.ndarray, p1: np.ndarray, d: np.ndarray) -> float:
    """+1 when n = r x e points downstream (image-plane part (-e_y, e_x) along d)."""
    e = (p1 - p0) / np.hypot(*(p1 - p0))
    return 1.0 if (-e[1] * d[0] + e[0] * d[1]) >= 0 else -1.0
