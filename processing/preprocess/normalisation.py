"""Normalisation of differential images to [0, 1] with one shared scale (paper Sec. 4.1).

Why one shared, slowly varying scale and not per-frame min-max: the joint disparity energy
compares intensities across cameras (E1: left vs right at t0, E4: left vs right at t1) and
across frames (E2/E3: t0 vs t1). A per-frame min-max stretch divides each differential image
by its own extreme values - one hot pixel, a bird or a gust in one camera changes the stretch
of that image only, and the same gas structure then has different intensities in the left and
right image and in consecutive frames, violating exactly the constancy assumptions E1-E4
rest on. It also amplifies pure noise to full contrast in frames without gas. With a fixed
scale s (radiance units) the map I -> 0.5 + D / (2 s) is one affine function applied to every
image: 0.5 means "no change", and equal radiance changes give equal normalised values in
both cameras and in every frame. s is a setting (e.g. the expected gas contrast: a radiance
change of s maps to 1.0); :class:`DiffScaleTracker` offers an online robust estimate with slow
exponential forgetting, pooled over both cameras, whose value is held fixed within a triple.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from processing.preprocess import order_statistics
from processing.validation import as_float_image, check_positive


def normalise_difference(diff: np.ndarray, scale: float) -> np.ndarray:
    """Map a radiance difference to [0, 1] with the shared fixed scale.

    Parameters
    ----------
    diff : ndarray, shape (H, W), float
        Differential image D = I(t) - I(t+1) (Eq. 2) in radiance units.
    scale : float
        Radiance difference s > 0 that maps to 1.0 (and -s to 0.0). The same value must be
        used for both cameras and both differential images of a triple (module docstring).

    Returns
    -------
    ndarray, shape (H, W), float32
        clip(0.5 + D / (2 s), 0, 1): 0.5 is "no change".
    """
    d = as_float_image(diff, "diff")
    s = check_positive(scale, "scale")
    out = d * np.float32(0.5 / s)
    out += np.float32(0.5)
    np.clip(out, 0.0, 1.0, out=out)
    return out


def pooled_quantile(diffs: Sequence[np.ndarray], quantile: float = 0.999) -> float:
    """``quantile`` of |D| pooled over raw differential images (every 2nd pixel in each
    direction: plenty for a quantile and 4x cheaper), radiance units."""
    if not diffs:
        raise ValueError("need at least one differential image")
    pooled = np.concatenate(
        [np.abs(as_float_image(d, "diff")[::2, ::2]).ravel() for d in diffs]
    )
    return order_statistics.quantile(pooled, quantile)


def share_above(diff: np.ndarray, limit: float) -> float:
    """Share of the pixels of a raw differential image with |D| > ``limit`` (radiance
    units; every 2nd pixel in each direction, as :func:`pooled_quantile`), in [0, 1]."""
    sample = np.abs(as_float_image(diff, "diff")[::2, ::2])
    return float(np.count_nonzero(sample > limit)) / max(sample.size, 1)


class DiffScaleTracker:
    """Online robust estimate of the normalisation scale, shared by both cameras.

    After each triple, :meth:`update` takes the raw (radiance) differential images of BOTH
    cameras, pools them, and moves the scale towards ``headroom`` times their ``quantile``
    of |D| with exponential forgetting: ``s <- (1 - forgetting) s + forgetting * target``.
    The caller uses :attr:`scale` unchanged for all four differential images of a triple and
    updates afterwards, so within a triple E1-E4 see one affine map, and across triples the
    scale drifts by at most ``forgetting`` (relative) per frame.

    Parameters
    ----------
    initial : float
        Starting scale (radiance units), e.g. the expected gas contrast.
    forgetting : float
        Weight of the newest estimate, in (0, 1]; 0.01 at 30 Hz ~ 3 s memory.
    quantile : float
        Quantile of |D| (in (0, 1)) that the scale follows.
    headroom : float
        Multiplier on that quantile (>= 1 keeps most values unclipped).
    """

    def __init__(
        self,
        initial: float,
        *,
        forgetting: float = 0.01,
        quantile: float = 0.999,
        headroom: float = 1.0,
    ) -> None:
        self._scale = check_positive(initial, "initial")
        self.forgetting = check_positive(forgetting, "forgetting")
        if self.forgetting > 1.0:
            raise ValueError(f"forgetting must be in (0, 1], got {forgetting!r}")
        if not 0.0 < quantile < 1.0:
            raise ValueError(f"quantile must be in (0, 1), got {quantile!r}")
        self.quantile = float(quantile)
        self.headroom = check_positive(headroom, "headroom")

    @property
    def scale(self) -> float:
        """Current scale in radiance units (use it for both cameras)."""
        return self._scale

    def target(self, *diffs: np.ndarray) -> float:
        """The scale these raw differential images alone would ask for (radiance units)."""
        return self.headroom * pooled_quantile(diffs, self.quantile)

    def update(self, *diffs: np.ndarray, target: float | None = None) -> float:
        """Pool the raw differential images of both cameras and update the scale
        (``target``: their :meth:`target`, when the caller has it already)."""
        target = self.target(*diffs) if target is None else target
        if target > 0.0:
            self._scale = (1.0 - self.forgetting) * self._scale + self.forgetting * target
        return self._scale
