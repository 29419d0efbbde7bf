"""Semi-global matching around the depth gate's voting pixels
(:func:`processing.preprocess.depth_gate.out_of_band_motion`, step 1): on a half-size pyramid
level, over the voting pixels' bounding box and a margin only, with the columns a box needs
on its left padded so that SGBM matches up to the image's left edge."""

from __future__ import annotations

import cv2
import numpy as np

from processing.stereo.sgm import sgbm_disparity

#: Narrower images keep SGBM at full resolution: halved, SGBM's matching blocks cover too
#: much of a small picture (a 64 x 48 test recording lost its gas to the gate).
MIN_WIDTH_HALF_SGBM = 160
#: SGBM matches the voting pixels' bounding box grown by this margin, px (full resolution):
#: its costs carry information along paths of a few blocks (:func:`sgbm_around`).
SGBM_MARGIN_PX = 16


def coarse_sgbm(left: np.ndarray, right: np.ndarray, n_disp: int, factor: int,
                box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """SGBM disparity (px at full resolution) and validity over [0, n_disp) around the
    ``box`` (y0, y1, x0, x1; half-open, full resolution) of the voting pixels, computed on
    images reduced by ``factor`` (1 or 2) and brought back to (H, W); 0 and invalid
    farther than ``SGBM_MARGIN_PX`` from the box."""
    if factor not in (1, 2):
        raise ValueError(f"sgbm_downsample must be 1 or 2, got {factor!r}")
    h, w = left.shape
    if factor == 1 or w < MIN_WIDTH_HALF_SGBM:
        return sgbm_around(left, right, n_disp, box, 1)
    n_half = max(16, 16 * int(np.ceil(n_disp / 2 / 16.0)))
    n_half = min(n_half, 16 * max(1, ((w // 2) - 8) // 16))
    d, valid = sgbm_around(cv2.pyrDown(left), cv2.pyrDown(right), n_half, box, 2)
    d = cv2.resize(d * np.float32(2.0), (w, h), interpolation=cv2.INTER_NEAREST)
    valid = cv2.resize(valid.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    return d, valid.astype(bool)


def sgbm_around(left: np.ndarray, right: np.ndarray, n_disp: int,
                box: tuple[int, int, int, int], factor: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_padded_sgbm` of a view pair (h, w) reduced by ``factor`` over the full-resolution
    ``box`` grown by ``SGBM_MARGIN_PX``, placed in (h, w) arrays (0 and invalid elsewhere).

    SGBM's costs at a pixel gather its row and the rows above it along its paths, so its
    disparities near the box's edge differ a little from the whole image's (measured on
    60 triples of the bench's plume with a 16 px margin: of the pixels that can vote, a
    median of 98 % (at least 89 %) equally valid and on the same side of the band; the
    same gate on every triple) at half of the cost."""
    h, w = left.shape
    y0, y1, x0, x1 = box
    m = SGBM_MARGIN_PX
    inner = (max(0, (y0 - m) // factor), min(h, -(-(y1 + m) // factor)),
             max(0, (x0 - m) // factor), min(w, -(-(x1 + m) // factor)))
    d = np.zeros((h, w), np.float32)
    valid = np.zeros((h, w), bool)
    ya, yb, xa, xb = inner
    d[ya:yb, xa:xb], valid[ya:yb, xa:xb] = _padded_sgbm(left, right, n_disp, inner)
    return d, valid


def _padded_sgbm(left: np.ndarray, right: np.ndarray, n_disp: int,
                box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """SGBM over [0, n_disp) of the ``box`` (y0, y1, x0, x1; half-open) of a view pair,
    each row matched with the ``n_disp`` columns left of the box (or, where the image
    ends, columns of "no change", 0.5); the result is the box's, (y1 - y0, x1 - x0).

    OpenCV's SGBM returns nothing for the leftmost ``n_disp`` columns of what it is given
    (their candidates would reach left of the right image): on the whole image with the
    gate's 128 px range at half resolution that was the left 40 % of a 320 px image, and
    a warm object crossing there was never gated (measured: 0 of 2141 active pixels
    matched; its edges then set d' of the whole image to 0). A point at x - d >= 0 is
    inside the right image and matches as usual; only the padding itself stays unmatched
    (it has no texture)."""
    y0, y1, x0, x1 = box
    start = max(0, x0 - n_disp)
    pad = ((0, 0), (n_disp - (x0 - start), 0))
    d, valid = sgbm_disparity(np.pad(left[y0:y1, start:x1], pad, constant_values=0.5),
                              np.pad(right[y0:y1, start:x1], pad, constant_values=0.5),
                              min_disparity=0, num_disparities=n_disp)
    return d[:, n_disp:], valid[:, n_disp:]
