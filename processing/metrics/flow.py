"""Accuracy metrics for 2-D optical flow (Baker et al., IJCV 2011; paper Table 1)."""

from __future__ import annotations

import numpy as np


def average_endpoint_error(
    flow: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None
) -> float:
    """Average endpoint error (AEE) in px: mean of |w - w_ref| over ``mask``.

    Parameters
    ----------
    flow, reference : ndarray, shape (H, W, 2)
        Computed and reference flow in px.
    mask : ndarray of bool, shape (H, W), optional
        Pixels with known reference flow; all pixels when omitted.

    Raises
    ------
    ValueError
        Mismatched shapes or an empty mask (an average over nothing is not a number).
    """
    if flow.shape != reference.shape or flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow {flow.shape} and reference {reference.shape} must be (H, W, 2)")
    err = np.linalg.norm(flow.astype(np.float64) - reference, axis=-1)
    if mask is not None:
        if mask.shape != flow.shape[:2]:
            raise ValueError(f"mask shape {mask.shape} does not match flow {flow.shape[:2]}")
        if not mask.any():
            raise ValueError("the mask selects no pixel")
        err = err[mask]
    return float(err.mean())
