"""The active region: where the gas is, so that the solvers need not iterate elsewhere.

The gas covers a small part of the frame (about a fifth in the field scene), yet the flow
(Eq. 5) and joint disparity (Eq. 6) solvers cost the same per pixel everywhere. On a warm
start, the region the solvers see is the bounding box of

- the current triple's active pixels: a left differential image (Eq. 2) or the previous
  flow well above the frame's robust spread, the same contrast the segmentation
  (Sec. 4.4) starts from, so that gas entering the frame is seen at once;
- the previous triple's gas mask;

both dilated by a margin that covers a frame's motion and the smoothness terms' reach.
Cold starts and scene changes solve the whole frame, and so does a box that would cover
most of it anyway. Outside the box nothing is solved: the fields there are not measured and
the chain marks them invalid.

The joint solver samples the right images at x - d. The right crop is therefore taken
``shift`` columns further left than the left crop, and the solver sees the disparity
d - shift: Eq. 6 depends on d only through that sample and through grad d, so the shift
changes nothing but the coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from processing.chain.state import WarmStart
from processing.preprocess.differential import PreprocessedTriple
from processing.segmentation.segment import robust_spread

if TYPE_CHECKING:
    from processing.chain.parameters import ChainParameters

#: Contrast over the robust spread above which a pixel counts as active (the
#: segmentation's own initial threshold, :func:`processing.segmentation.segment.initial_phi`).
ACTIVE_THRESHOLD = 2.0


@dataclass(frozen=True)
class Box:
    """A rectangle of the frame, rows ``y0:y1``, columns ``x0:x1`` (px, end exclusive), and
    the column shift of the right crop (px, >= 0)."""

    y0: int
    y1: int
    x0: int
    x1: int
    shift: int = 0

    @property
    def bounds(self) -> tuple[int, int, int, int]:
        """(y0, y1, x0, x1), px."""
        return self.y0, self.y1, self.x0, self.x1

    @property
    def left(self) -> tuple[slice, slice]:
        """Index of the box in the left image."""
        return slice(self.y0, self.y1), slice(self.x0, self.x1)

    @property
    def right(self) -> tuple[slice, slice]:
        """Index of the right crop: the same rows, ``shift`` columns to the left."""
        return slice(self.y0, self.y1), slice(self.x0 - self.shift, self.x1 - self.shift)

    def fraction(self, shape: tuple[int, int]) -> float:
        """Share of a (H, W) frame the box covers."""
        return (self.y1 - self.y0) * (self.x1 - self.x0) / float(shape[0] * shape[1])

    def mask(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) bool, True inside the box."""
        out = np.zeros(shape, bool)
        out[self.left] = True
        return out


def measured_area(shape: tuple[int, int], box: Box | None, border_px: int
                  ) -> np.ndarray | None:
    """Where the chain measures, (H, W) bool: inside the solvers' ``box`` and off the border
    strip of ``border_px`` the registration's warps filled with mirrored values
    (:attr:`processing.preprocess.differential.PreprocessedTriple.border_px`); None when that
    is the whole frame.

    A strip is no measurement: under 0.3-0.7 px of jitter its mirrored rows changed from one
    frame to the next by more than the gas does on a textured background, and the level set
    called them gas (measured on a development scene of the wide matrix: up to 2,900 false
    gas pixels in one triple, along the image's rows 0-6).
    """
    if box is None and border_px <= 0:
        return None
    inside = np.ones(shape, bool) if box is None else box.mask(shape)
    b = min(border_px, min(shape) // 2)
    if b > 0:
        inside[:b] = inside[-b:] = False
        inside[:, :b] = inside[:, -b:] = False
    return inside


def active_pixels(diffs: tuple[np.ndarray, ...], flow: np.ndarray | None) -> np.ndarray:
    """Pixels whose contrast stands out of the frame's spread.

    Parameters
    ----------
    diffs : tuple of ndarray, shape (H, W), float32
        Normalised differential images in [0, 1] (0.5 = no change).
    flow : ndarray, shape (H, W, 2), float32, or None
        The previous triple's flow in px/frame (moving gas, even where it is faint now).

    Returns
    -------
    ndarray, shape (H, W), bool
    """
    active = np.zeros(diffs[0].shape, bool)
    features = [np.abs(d - np.float32(0.5)) for d in diffs]
    if flow is not None:
        # cv2.magnitude on the two planes: np.hypot over the interleaved (H, W, 2) layout
        # took 0.29 ms at 320x240, this 0.07 ms (measured).
        u, v = (np.ascontiguousarray(flow[..., k], dtype=np.float32) for k in (0, 1))
        features.append(cv2.magnitude(u, v))
    for f in features:
        score = cv2.GaussianBlur(f.astype(np.float32), (0, 0), 2.0)
        active |= score > ACTIVE_THRESHOLD * robust_spread(f)
    return active


def bounding_box(mask: np.ndarray, margin_px: int, align: int = 8) -> Box | None:
    """Bounding box of ``mask`` grown by ``margin_px`` on every side, edges on multiples of
    ``align`` px (fewer distinct level sizes for the solvers' workspaces), clipped to the
    frame; None for an empty mask."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return None
    h, w = mask.shape
    y0 = max(0, (int(rows[0]) - margin_px) // align * align)
    x0 = max(0, (int(cols[0]) - margin_px) // align * align)
    y1 = min(h, -(-(int(rows[-1]) + 1 + margin_px) // align) * align)
    x1 = min(w, -(-(int(cols[-1]) + 1 + margin_px) // align) * align)
    return Box(y0, y1, x0, x1)


def right_shift(box: Box, disparity: np.ndarray) -> Box:
    """``box`` with the right crop's column shift: the smallest disparity inside the box
    (px, rounded down), at most ``x0`` so the crop stays in the frame."""
    d_min = float(np.min(disparity[box.left]))
    shift = int(min(max(np.floor(d_min), 0.0), box.x0))
    return Box(box.y0, box.y1, box.x0, box.x1, shift)


def choose_region(diffs: tuple[np.ndarray, ...], previous_flow: np.ndarray,
                  previous_disparity: np.ndarray, previous_mask: np.ndarray | None, *,
                  margin_px: int, max_fraction: float, min_size: int = 16) -> Box | None:
    """The box the solvers see on a warm start, or None for the whole frame.

    Parameters
    ----------
    diffs : tuple of ndarray, shape (H, W), float32
        This triple's left differential images.
    previous_flow : ndarray, shape (H, W, 2)
        The previous triple's w_L, px.
    previous_disparity : ndarray, shape (H, W)
        The previous triple's d_L, px (the right crop's shift).
    previous_mask : ndarray, shape (H, W), bool, or None
        The previous triple's gas mask.
    margin_px : int
        Margin around the active pixels, px.
    max_fraction : float
        A box covering more of the frame than this is not worth cropping: None.
    min_size : int
        Smallest box side, px (the solvers' pyramids need a few levels).

    Returns
    -------
    Box or None
    """
    active = active_pixels(diffs, previous_flow)
    if previous_mask is not None:
        active |= previous_mask
    box = bounding_box(active, margin_px)
    shape = diffs[0].shape
    if box is None or box.fraction(shape) > max_fraction:
        return None
    if box.y1 - box.y0 < min_size or box.x1 - box.x0 < min_size:
        return None
    return right_shift(box, previous_disparity)


def crop_inputs(box: Box | None, pl: PreprocessedTriple, pr: PreprocessedTriple,
                warm: WarmStart | None, blanked: tuple[np.ndarray, np.ndarray] | None,
                history: tuple[np.ndarray | None, int]
                ) -> tuple[PreprocessedTriple, PreprocessedTriple, WarmStart | None,
                           tuple[np.ndarray, np.ndarray] | None, tuple[np.ndarray | None, int]]:
    """The solvers' inputs inside ``box`` (None: the whole frame, unchanged).

    Left differential images (Eq. 2), warm fields, the gate's blanked masks and the d'
    history (previous d'_L, frames back) on the box; the right images and blanked mask
    ``box.shift`` columns further left, and the warm disparity less that shift.
    """
    if box is None:
        return pl, pr, warm, blanked, history

    def cut(a: np.ndarray, index: tuple[slice, slice]) -> np.ndarray:
        return np.ascontiguousarray(a[index])

    lft, rgt = box.left, box.right
    cl = replace(pl, diff0=cut(pl.diff0, lft), diff1=cut(pl.diff1, lft))
    cr = replace(pr, diff0=cut(pr.diff0, rgt), diff1=cut(pr.diff1, rgt))
    cwarm = None if warm is None else WarmStart(
        cut(warm.flow, lft), cut(warm.disparity, lft) - np.float32(box.shift),
        cut(warm.change, lft), warm.steps)
    cblank = None if blanked is None else (cut(blanked[0], lft), cut(blanked[1], rgt))
    previous, steps = history
    return cl, cr, cwarm, cblank, (None if previous is None else cut(previous, lft), steps)


def paste_fields(box: Box | None, flow: np.ndarray, d: np.ndarray, dd: np.ndarray,
                 warm: WarmStart | None
                 ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray],
                            tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Whole-frame w_L (H, W, 2), d_L and d'_L (H, W), px, from the box's, twice.

    The triple's fields: outside the box no motion and the previous d_L (not a
    measurement: the chain marks it invalid). The next triple's start: outside the box the
    fields this triple started from, kept. A box that grows into pixels the previous one
    left out then starts them from their last solved motion, not from none: from zero the
    few warm levels did not catch up, and the gas's flow in the box read 0.79 of the
    whole frame's (a development scene of the wide matrix, s43, ideal).
    """
    if box is None:
        return (flow, d, dd), (flow, d, dd)
    assert warm is not None
    shape = warm.disparity.shape
    full_flow = np.zeros((*shape, 2), np.float32)
    full_flow[box.left] = flow
    full_d = np.array(warm.disparity, np.float32, copy=True)
    full_d[box.left] = d + np.float32(box.shift)
    full_dd = np.zeros(shape, np.float32)
    full_dd[box.left] = dd
    start_flow = np.array(warm.flow, np.float32, copy=True)
    start_flow[box.left] = flow
    start_dd = np.array(warm.change, np.float32, copy=True)
    start_dd[box.left] = dd
    return (full_flow, full_d, full_dd), (start_flow, full_d, start_dd)


def flow_blanked(blanked: tuple[np.ndarray, np.ndarray] | None,
                 depth_blanked: tuple[np.ndarray, np.ndarray] | None,
                 params: ChainParameters, box: Box | None) -> np.ndarray | None:
    """The left pixels (on the solvers' ``box``) where the flow has no data term: every
    blanked one with ``params.flow_drop_blanked``, else those the opaque-edge gate added.

    The opaque-edge gate blanks the moving edges of an object inside the gas's depth band:
    thin static "no change" borders inside the plume, which held the gas's flow to a
    fraction of its motion up to tens of pixels away (docs/evaluation-sceneflow.md).
    """
    if blanked is None:
        return None
    if params.flow_drop_blanked:
        mask = blanked[0]
    elif depth_blanked is None:
        mask = blanked[0]  # only the opaque-edge gate blanked
    elif blanked is depth_blanked:
        # the opaque-edge gate hands the depth gate's masks back when it blanks nothing
        return None
    else:
        mask = blanked[0] & ~depth_blanked[0]
    return mask if box is None else np.ascontiguousarray(mask[box.left])
