"""Temporal coherence of the disparity change across consecutive triples (beyond the paper).

V_Z rests on d', the change of disparity within one frame interval (Eq. 4): at 5.5 m with
b = 0.3 m and 30 Hz, 0.1 px of d' is about 0.4 m/s. The joint solver (Eq. 6) estimates d'
from one triple only, and its gas-region mean scatters by about 0.1 px from one triple to
the next while the gas moves steadily (measured on the robustness matrix's field scenes:
V_Z 0.2-0.9 m/s per triple for a steady 0.9 m/s). The gas is the same from one triple to
the next, one frame later and displaced by the flow, so the previous triple's (already
smoothed) d' is carried along the flow onto the current grid and blended in:

    d'_s(x, t) = (1 - a) d'(x, t) + a d'_s(x - w(x), t - 1)

a first-order (exponential) filter along the gas's paths, with memory 1 / (1 - a) frames
(a = 0.7: about 3 frames, 0.1 s at 30 Hz). Where the previous value is unknown (new gas,
outside the image) d' is kept as it is.

The filter starts as a running mean: while the history holds n triples, a is at most
n / (n + 1), so each of them and this triple weigh alike until the memory is filled
(:func:`history_weight`). Started at a alone, the first triple's d' - the one with no
history, and under noise often the farthest off - kept a share of 0.7, 0.49, 0.34 over the
next three triples instead of 1/2, 1/3, 0.23.
"""

from __future__ import annotations

import cv2
import numpy as np

from processing.validation import check_same_shape


def carry_along_flow(previous: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The previous frame's field at the positions the gas came from, x - w(x).

    Parameters
    ----------
    previous : ndarray, shape (H, W), float32
        A field on the previous triple's t0 grid.
    flow : ndarray, shape (H, W, 2), float32
        w = (u, v) in px per frame on the current grid.

    Returns
    -------
    (aligned, inside) : (ndarray float32, ndarray bool)
        ``previous`` sampled bilinearly at x - w, and where that position lies inside the
        image.
    """
    h, w = previous.shape
    if flow.shape != (h, w, 2):
        raise ValueError(f"flow must have shape {(h, w, 2)}, got {flow.shape}")
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx = xs - flow[..., 0]
    my = ys - flow[..., 1]
    aligned = cv2.remap(np.ascontiguousarray(previous, dtype=np.float32), mx, my,
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    return aligned, inside


def history_weight(weight: float, n_triples: int) -> float:
    """The share a of the history in d'_s when it holds ``n_triples`` (>= 0) consecutive
    triples: ``weight``, but at most n / (n + 1) (module docstring).

    Parameters
    ----------
    weight : float
        The filter's a in [0, 1) (``ChainParameters.temporal_weight``).
    n_triples : int
        Triples whose d' the history averages; 0: none.

    Returns
    -------
    float
        min(weight, n / (n + 1)), in [0, 1).
    """
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"weight must be in [0, 1), got {weight!r}")
    if n_triples < 0:
        raise ValueError(f"n_triples must be >= 0, got {n_triples!r}")
    return min(weight, n_triples / (n_triples + 1.0))


def smooth_disparity_change(d_change: np.ndarray, previous: np.ndarray | None,
                            flow: np.ndarray, weight: float) -> np.ndarray:
    """d'_s of the module docstring.

    Parameters
    ----------
    d_change : ndarray, shape (H, W), float32
        This triple's d' from the joint solver, px.
    previous : ndarray or None
        The previous consecutive triple's d'_s (None: no history, d' is returned).
    flow : ndarray, shape (H, W, 2)
        This triple's w_L, px per frame.
    weight : float
        a in [0, 1): the share of the history.

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"weight must be in [0, 1), got {weight!r}")
    dd = np.asarray(d_change, dtype=np.float32)
    if previous is None or weight == 0.0:
        return dd
    check_same_shape(dd, previous, "d_change", "previous")
    aligned, inside = carry_along_flow(previous, flow)
    a = np.float32(weight)
    return np.where(inside, (1 - a) * dd + a * aligned, dd).astype(np.float32)
