"""Gas segmentation by a two-region level set (paper Sec. 4.4, Eq. 9).

The image domain is split into the gas region Omega_g (phi > 0) and the background Omega_bg
(phi < 0) by minimising

    E_ROI(phi) = nu int |grad H(phi)| - int H(phi) log q_g - int (1 - H(phi)) log q_bg

with q_i(I_diff, u, v) = q_i(I_diff) q_i(u) q_i(v), each factor a normal density whose mean
and variance are re-estimated from the current regions (weights H(phi) and 1 - H(phi))
during the descent, and H_eps(phi) = 1/2 (1 + 2/pi arctan(phi / eps)) the smoothed Heaviside
with delta_eps(phi) = eps / (pi (eps^2 + phi^2)).

Descent: the gradient flow dphi/dt = delta_eps(phi) [nu div(grad phi / |grad phi|) +
log q_g - log q_bg] is integrated with the semi-implicit scheme of Chan and Vese as written out
by Getreuer (IPOL 2012, "Chan-Vese Segmentation"): the curvature term is discretised with
the four half-point coefficients C1..C4; each new value is a convex combination of the old
value and its neighbours plus the force step, which is stable for large time steps. We
sweep in Jacobi order (Getreuer uses Gauss-Seidel) so that the numba loop vectorises: one
sweep takes ~0.7 ms at 320x240 on this machine. The region models are re-estimated before
every sweep (one fused numba pass for the weighted moments, with a polynomial arctan).
The data force is clipped to +-``force_clip`` so one outlier pixel cannot dominate.

Multi-scale: the features are area-downsampled by 2 per level; the descent starts on the
coarsest level, and phi is upsampled to initialise the next finer one (coarse-to-fine), so the
fine level only refines the boundary. Defaults: 4 levels (40x30 ... 320x240) with 20, 10, 4
and 2 sweeps, a few ms in total at 320x240 (``benchmarks/bench_preprocess.py``).

Initialisation (documented choice): a pixel starts as gas when the smoothed normalised
contrast max(|I_diff - 0.5| / s_I, |w| / s_w) exceeds ``init_threshold``, with s_I and s_w
robust spreads (scaled mean absolute values) over the whole frame, evaluated on the coarsest
level; if that gives an empty or a full region, a checkerboard of period 10 px is used
instead (Getreuer's default).

Which region is gas: the two-region model is symmetric, so after the descent the region with
the larger mean "activity" |I_diff - 0.5| / s_I + |w| / s_w is called gas (phi is flipped if
needed). Frames without gas: the model still splits the frame in two; the split is accepted
as gas only when the gas region's mean activity exceeds the background's by the factor
``min_activity_ratio``, otherwise the mask is empty (and phi is all negative).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from processing.segmentation.level_set import descend
from processing.validation import as_float_image, check_positive

#: Smallest accepted image side in pixels.
MIN_SEGMENT_SIZE = 8
#: ``known`` of the level-set kernels when the flow was measured everywhere (a 1 x 1 array
#: cannot be a level of an image of at least MIN_SEGMENT_SIZE px).
_EVERYWHERE = np.ones((1, 1), np.float32)

def _activity(diff: np.ndarray, flow: np.ndarray, measured: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """|I_diff - 0.5|, |w| and their robust spreads s_I, s_w over the frame (s_w over the
    ``measured`` pixels (H, W) bool, where the flow was solved, when given and not empty).

    The spreads are mean absolute values (x 1.2533, the Gaussian mean-absolute to standard
    deviation factor): cheaper than medians and only used to put the two features on one
    scale.
    """
    a = np.abs(diff - np.float32(0.5))
    m = np.sqrt(flow[..., 0] ** 2 + flow[..., 1] ** 2)
    if measured is None or not measured.any():
        return a, m, robust_spread(a), robust_spread(m)
    return a, m, robust_spread(a), robust_spread(m[measured])


def _side_activities(act: np.ndarray, pos: np.ndarray, measured: np.ndarray | None
                     ) -> tuple[float, float]:
    """Mean activity of the phi > 0 side ``pos`` and of the other, both (H, W); only over
    the ``measured`` pixels (bool) when given and both sides have some there."""
    if measured is not None and (pos & measured).any() and (~pos & measured).any():
        return float(act[pos & measured].mean()), float(act[~pos & measured].mean())
    return float(act[pos].mean()), float(act[~pos].mean())


def robust_spread(magnitude: np.ndarray) -> float:
    """Spread of a non-negative feature (|I_diff - 0.5|, |w|) over the frame: its mean
    (x 1.2533, the Gaussian mean-absolute to standard deviation factor), never 0."""
    return 1.2533 * float(magnitude.mean()) + 1e-6


def initial_phi(diff: np.ndarray, flow: np.ndarray, *, threshold: float = 2.0,
                known: np.ndarray | None = None) -> np.ndarray:
    """Initial embedding function (module docstring: thresholds, checkerboard fallback).

    Parameters
    ----------
    diff : ndarray, shape (H, W), float32
        Normalised differential image in [0, 1].
    flow : ndarray, shape (H, W, 2), float32
        Optical flow (u, v) in px/frame.
    threshold : float
        Threshold on the smoothed normalised contrast.
    known : ndarray, shape (H, W), float, optional
        Where the flow was measured (:func:`segment_gas`'s ``flow_known``).

    Returns
    -------
    ndarray, shape (H, W), float32
        +1 (gas) / -1 (background), lightly smoothed.
    """
    a, m, s_i, s_w = _activity(diff, flow, None if known is None else known > 0.5)
    score = np.maximum(a / s_i, m / s_w).astype(np.float32)
    score = cv2.GaussianBlur(score, (0, 0), 2.0)
    mask = score > threshold
    if not mask.any() or mask.all():
        y, x = np.mgrid[0 : diff.shape[0], 0 : diff.shape[1]]
        return (np.sin(np.pi * x / 5.0) * np.sin(np.pi * y / 5.0)).astype(np.float32)
    phi = np.where(mask, np.float32(1.0), np.float32(-1.0))
    return cv2.GaussianBlur(phi, (0, 0), 1.0)


def _all_background(phi: np.ndarray) -> np.ndarray:
    """An embedding function that is negative everywhere (no gas), shaped like ``phi``."""
    return (-np.abs(phi) - np.float32(1e-3)).astype(np.float32)


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_gas`.

    Attributes
    ----------
    mask : ndarray, shape (H, W), bool
        True on gas pixels (Omega_g).
    phi : ndarray, shape (H, W), float32
        Embedding function, > 0 inside the gas region (all negative when no gas was found).
    activity_ratio : float
        Mean activity of the gas region over that of the background (>= 1 by construction
        of the gas/background choice); compared with ``min_activity_ratio``.
    """

    mask: np.ndarray
    phi: np.ndarray
    activity_ratio: float


def segment_gas(
    diff: np.ndarray,
    flow: np.ndarray,
    *,
    nu: float = 0.5,
    eps: float = 1.0,
    dt: float = 0.5,
    n_levels: int = 4,
    iterations: tuple[int, ...] = (20, 10, 4, 2),
    sweeps_per_update: int = 1,
    force_clip: float = 20.0,
    init_threshold: float = 2.0,
    min_activity_ratio: float = 1.5,
    flow_known: np.ndarray | None = None,
) -> Segmentation:
    """Segment the gas region of a differential image with its optical flow (Eq. 9).

    Parameters
    ----------
    diff : ndarray, shape (H, W), float
        Normalised differential image I_diff in [0, 1] (0.5 = no change), left camera, t0.
    flow : ndarray, shape (H, W, 2), float
        Optical flow w_L = (u, v) in px/frame from I_diff(t0) to I_diff(t1) (Eq. 5).
    nu : float
        Weight of the length term (paper: 0.5).
    eps : float
        Width of the smoothed Heaviside and delta, in units of phi.
    dt : float
        Time step of the semi-implicit descent.
    n_levels : int
        Number of pyramid levels (factor 2 each), >= 1.
    iterations : tuple of int
        Region-model updates per level, coarsest first; the last value repeats if there
        are more levels than entries. Each update is followed by ``sweeps_per_update``
        Gauss-Seidel sweeps of phi.
    sweeps_per_update : int
        Sweeps of phi between two re-estimations of the Gaussian region models.
    force_clip : float
        Clip of the per-pixel log-likelihood ratio.
    init_threshold : float
        See :func:`initial_phi`.
    min_activity_ratio : float
        Gas accepted only if its mean activity is at least this multiple of the
        background's (module docstring); 0 disables the check.
    flow_known : ndarray, shape (H, W), bool or float in [0, 1], optional
        Where ``flow`` was measured (the chain's active region). The motion features u, v
        count only there: their region models are estimated from those pixels, their
        log-likelihood ratios act only there, and the flow's robust spread and the
        regions' activities (which side is gas) are taken there. None: everywhere.

    Returns
    -------
    Segmentation

    Raises
    ------
    ValueError
        Wrong shapes or dtypes, NaN/inf, too small, or bad parameters.
    """
    d = as_float_image(diff, "diff", min_size=MIN_SEGMENT_SIZE)
    if not isinstance(flow, np.ndarray) or flow.shape != (*d.shape, 2):
        got = getattr(flow, "shape", type(flow).__name__)
        raise ValueError(f"flow must have shape {(*d.shape, 2)}, got {got}")
    if not np.issubdtype(flow.dtype, np.floating) or not np.all(np.isfinite(flow)):
        raise ValueError("flow must be a finite floating-point array")
    fl = np.ascontiguousarray(flow, dtype=np.float32)
    nu = check_positive(nu, "nu", allow_zero=True)
    eps = check_positive(eps, "eps")
    dt = check_positive(dt, "dt")
    force_clip = check_positive(force_clip, "force_clip")
    if int(n_levels) < 1 or not iterations or any(int(n) < 0 for n in iterations):
        raise ValueError("n_levels must be >= 1 and iterations a non-empty tuple of counts >= 0")
    if int(sweeps_per_update) < 1:
        raise ValueError(f"sweeps_per_update must be >= 1, got {sweeps_per_update}")

    if flow_known is not None and np.shape(flow_known) != d.shape:
        raise ValueError(f"flow_known must have shape {d.shape}, got {np.shape(flow_known)}")
    # With flow_known, a fourth plane: the pyramid then carries the measured share of each
    # coarse pixel. Without, the kernels take a 1 x 1 sentinel (no plane to read).
    planes = [d, fl[..., 0], fl[..., 1]]
    if flow_known is not None:
        planes.append(np.asarray(flow_known, np.float32))
    pyramid = [np.stack(planes)]
    for _ in range(int(n_levels) - 1):
        prev = pyramid[-1]
        if min(prev.shape[1:]) < 2 * MIN_SEGMENT_SIZE:
            break
        size = (prev.shape[2] // 2, prev.shape[1] // 2)
        pyramid.append(np.stack([cv2.resize(c, size, interpolation=cv2.INTER_AREA) for c in prev]))
    pyramid.reverse()  # coarsest first

    coarse = pyramid[0]
    phi = initial_phi(coarse[0], np.dstack([coarse[1], coarse[2]]), threshold=init_threshold,
                      known=None if flow_known is None else coarse[3])
    for level, feats in enumerate(pyramid):
        if phi.shape != feats.shape[1:]:
            phi = cv2.resize(phi, (feats.shape[2], feats.shape[1]), interpolation=cv2.INTER_LINEAR)
        phi = np.ascontiguousarray(phi, dtype=np.float32)
        known = _EVERYWHERE if flow_known is None else np.ascontiguousarray(feats[3])
        descend(np.ascontiguousarray(feats[:3]), phi, known, nu, dt, eps, force_clip,
                int(iterations[min(level, len(iterations) - 1)]), int(sweeps_per_update))

    # Which side is gas: larger mean activity (module docstring).
    measured = None if flow_known is None else pyramid[-1][3] > 0.5
    a, m, s_i, s_w = _activity(d, fl, measured)
    act = a / s_i + m / s_w
    pos = phi > 0
    n_pos = int(pos.sum())
    if n_pos == 0 or n_pos == pos.size:
        return Segmentation(np.zeros(d.shape, bool), _all_background(phi), 1.0)
    act_pos, act_neg = _side_activities(act, pos, measured)
    if act_neg > act_pos:
        phi = -phi
        pos = ~pos
        act_pos, act_neg = act_neg, act_pos
    ratio = act_pos / max(act_neg, 1e-12)
    if ratio < min_activity_ratio:
        return Segmentation(np.zeros(d.shape, bool), _all_background(phi), ratio)
    return Segmentation(pos, phi.astype(np.float32, copy=False), ratio)
