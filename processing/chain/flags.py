"""What a stereo triple's pre-processing tells about the disturbances of the scene.

The per-frame summary carries these as flags (:data:`processing.chain.summary.FLAGS`) so that an
operator knows when a number is weak: jitter that was measured and removed, jitter that could
not be measured (no static texture), and a gas signal close to the camera noise.
"""

from __future__ import annotations

import numpy as np

from processing.preprocess.differential import PreprocessedTriple
from processing.preprocess.order_statistics import median, quantile
from processing.preprocess.registration import CHECKED_ABOVE_PX

#: Flags of a triple whose data do not fix the constant part of d and d' (see
#: :func:`processing.stereo.constant_mode.constant_mode_step`).
UNTRUSTED_FOR_CONSTANT_MODE = frozenset({"registration_rejected", "low_contrast"})

#: A shift below this (px) counts as no jitter for the ``jitter_corrected`` flag: the
#: registration's bound below which a shift changes no differential image measurably.
JITTER_FLAG_PX = CHECKED_ABOVE_PX
#: Peak-to-noise ratio of the raw differential image below which ``low_contrast`` is
#: flagged: the strongest change is within this many noise standard deviations.
LOW_CONTRAST_RATIO = 6.0


def preprocess_flags(left: PreprocessedTriple, right: PreprocessedTriple) -> list[str]:
    """Summary flags (:data:`processing.chain.summary.FLAGS`) of a stereo triple's pre-processing.

    ``registration_rejected``: a jitter estimate was not applied (no static texture), or a
    paused registration did not estimate a shift (``ChainParameters.registration_pause_after``);
    ``jitter_corrected``: a shift of at least :data:`JITTER_FLAG_PX` was removed;
    ``low_contrast``: :func:`contrast_ratio` of the left camera below
    :data:`LOW_CONTRAST_RATIO`; ``offset_levelled``: a camera's offset stepped between the
    triple's last two frames and was levelled out of D(t1)
    (:func:`processing.preprocess.differential.levelled_difference`).
    """
    flags = []
    if left.rejected_shifts or right.rejected_shifts:
        flags.append("registration_rejected")
    shifts = [*left.shifts, *right.shifts]
    if any(float(np.hypot(*s)) >= JITTER_FLAG_PX for s in shifts):
        flags.append("jitter_corrected")
    if contrast_ratio(left) < LOW_CONTRAST_RATIO:
        flags.append("low_contrast")
    if left.offset_step1 or right.offset_step1:
        flags.append("offset_levelled")
    return flags


def contrast_ratio(triple: PreprocessedTriple) -> float:
    """Strongest change over noise in the raw (not denoised) D(t0): the 0.999 quantile of
    |D| over 1.4826 x its median absolute value (the noise where nothing moves)."""
    a = np.abs(triple.raw0[::2, ::2])
    noise = 1.4826 * median(a)
    peak = quantile(a, 0.999)
    return peak / noise if noise > 0 else float("inf")
