"""Differential images shared between the streams of one camera pair (the daemon's workers).

Two workers alternating take the triples (t0, t1, t2) and (t1, t2, t3). When the first
left t1 on its own grid (no jitter, a rejected shift, registration off:
:mod:`processing.chain.state`), its D(t1) = I(t1) - I(t2), raw and denoised, is the second
one's D(t0). It depends only on its two frames, the shift applied to t2 and the chain's
settings, so the worker that computes it first hands it to the other, which then
differentiates and denoises one pair per camera instead of two, as a single worker does.
The results are the same numbers (tested); a miss - the other worker is not there yet, an
entry overwritten - only means computing it again.

Corrected frames are not shared: on the bench a frame's correction (0.06 ms) cost less than
handing it over (about 0.1 ms to copy it into and out of shared memory).

A key is a fixed-length tuple of floats (:func:`difference_key`), so that a table in shared
memory can hold it.
"""

from __future__ import annotations

import zlib
from collections.abc import Hashable
from typing import Protocol

import numpy as np

#: Floats in a key.
KEY_LENGTH = 6

ImageKey = tuple[float, ...]


class ImageShare(Protocol):
    """Images keyed by :func:`difference_key`, readable by every stream of the same camera
    pair and chain settings."""

    def get(self, key: ImageKey, count: int) -> tuple[np.ndarray, ...] | None:
        """Copies of the ``count`` arrays stored under ``key``, or None."""

    def put(self, key: ImageKey, arrays: tuple[np.ndarray, ...]) -> None:
        """Offer ``arrays`` (float32, the chain's image size) under ``key``; may be ignored."""


def difference_key(camera: int, t_from: float, t_to: float, shift: tuple[float, float],
                   settings: Hashable) -> ImageKey:
    """Key of camera ``camera``'s (0 left, 1 right) differential image of the frames
    captured at ``t_from`` and ``t_to`` (s), the later one shifted by ``shift`` (px),
    computed with ``settings`` (anything with a stable repr: the gas radiance, the contrast
    floor, the denoising weight)."""
    digest = float(zlib.crc32(repr(settings).encode()))
    return (float(camera), float(t_from), float(t_to), float(shift[0]), float(shift[1]),
            digest)
