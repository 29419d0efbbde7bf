"""What the chain returns for one triple, and the frame interval of Eq. 4 it used."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from processing.chain.summary import GasSummary


@dataclass(frozen=True)
class SceneFlowResult:
    """Everything the chain computed for one triple; fields of the left view, (H, W).

    Attributes
    ----------
    times_s : (float, float, float)
        Capture times of the three pairs in s (any common origin).
    dt_s : float
        Frame interval used in Eq. 4, (t2 - t0) / 2.
    diff_left, diff_right : (ndarray, ndarray)
        Normalised differential images at t0 and t1, float32 in [0, 1].
    flow : ndarray, shape (H, W, 2), float32
        w_L in px (Eq. 5).
    disparity, disparity_change : ndarray, float32
        d_L and d'_L in px (Eq. 6; x_R = x_L - d).
    velocity : ndarray, shape (H, W, 3), float32
        V in m/s, left camera frame (X right, Y down, Z forward) (Eq. 4); 0 where invalid.
    position : ndarray, shape (H, W, 3), float32
        Virtual gas surface (X, Y, Z) in m; 0 where invalid.
    valid : ndarray of bool
        Pixels where V is defined (d > 0, d + d' > 0, finite).
    u_sf : ndarray, float32
        Quality U_SF (Eq. 7) at the gas pixels (NaN elsewhere); ``u_sf_valid`` marks gas
        pixels whose warps stayed inside.
    gas_mask : ndarray of bool
        Segmented gas region Omega_g (Eq. 9); ``phi`` is its embedding function.
    summary : GasSummary
        Mean velocity, speed, directional angles, pixel counts, c_USF (Eq. 8).
    diff_scale : float
        Normalisation scale used for this triple.
    shifts_left, shifts_right : ((dx, dy), (dx, dy))
        Jitter removed (t0->t1, t1->t2) in px.
    rejected_shifts : int
        Registration estimates (of 4) not applied because they exceeded max_jitter_px:
        non-zero means the background offers no static texture to register on.
    timings_ms : dict
        Wall time per stage in ms, and "total".
    warm : bool
        True when the solvers started from the previous triple (:mod:`processing.chain.state`).
    region : (int, int, int, int) or None
        Rows y0:y1 and columns x0:x1 (px) the solvers worked on (the active region,
        :mod:`processing.chain.region`); outside it nothing is measured and ``valid`` is
        False. None: the whole frame.
    offset_steps : (float, float)
        The step of the left and the right camera's offset levelled out of D(t1)
        (:attr:`processing.preprocess.differential.PreprocessedTriple.offset_step1`),
        radiance units (counts without a characteristic curve); 0.0: none.
    """

    times_s: tuple[float, float, float]
    dt_s: float
    diff_left: tuple[np.ndarray, np.ndarray]
    diff_right: tuple[np.ndarray, np.ndarray]
    flow: np.ndarray
    disparity: np.ndarray
    disparity_change: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    valid: np.ndarray
    u_sf: np.ndarray
    u_sf_valid: np.ndarray
    gas_mask: np.ndarray
    phi: np.ndarray
    summary: GasSummary
    diff_scale: float
    shifts_left: tuple[tuple[float, float], tuple[float, float]]
    shifts_right: tuple[tuple[float, float], tuple[float, float]]
    rejected_shifts: int
    timings_ms: dict[str, float]
    warm: bool = False
    region: tuple[int, int, int, int] | None = None
    offset_steps: tuple[float, float] = (0.0, 0.0)


def frame_interval(times_s: Sequence[float]) -> float:
    """dt of Eq. 4 from three capture times: (t2 - t0) / 2, checked to be increasing."""
    if len(times_s) != 3:
        raise ValueError(f"need 3 capture times (t0, t1, t2), got {len(times_s)}")
    t0, t1, t2 = (float(t) for t in times_s)
    if not (np.isfinite([t0, t1, t2]).all() and t0 < t1 < t2):
        raise ValueError(f"capture times must be finite and increasing, got {(t0, t1, t2)}")
    return (t2 - t0) / 2.0
