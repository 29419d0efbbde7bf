"""Differential images shared between the daemon's worker processes.

With two workers alternating, worker A's triple (t0, t1, t2) and worker B's next triple
(t1, t2, t3) share the differential image D(t1, t2) when t1 was not moved by the
registration (:mod:`processing.chain.images`). Measured on the bench's plume, a two-worker
triple spent 1.2 ms more on its differences than a one-worker triple (two differentiated
and denoised pairs per camera instead of one). Whoever computes such an image first
publishes it here and the other copies it out.

The table is a few slots of shared memory, each one key (:data:`KEY_LENGTH` floats) and up
to two images of the chain's size; a new entry takes the slot written longest ago. A miss
(the other worker is not there yet, its entry overwritten, an image of another size) only
means computing the image again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from processing.chain.binning import binned_size
from processing.chain.images import KEY_LENGTH, ImageKey

#: Slots of the table: each triple offers one difference per camera, the other worker wants
#: it about one frame later.
SLOTS = 8
#: Images a slot holds at most (a difference: raw and denoised).
PER_SLOT = 2
# A slot's header: the key, how many images it holds (0: empty), when it was last written.
_COUNT = KEY_LENGTH
_STAMP = KEY_LENGTH + 1
_HEADER = KEY_LENGTH + 2


@dataclass(frozen=True)
class ImageTable:
    """Shared arrays of a :class:`SharedImages` (from :func:`create_image_table`); passed to
    the worker processes as they start."""

    header: Any  # multiprocessing.Array of float64 with its lock
    data: Any  # multiprocessing.RawArray of float32
    shape: tuple[int, int]

    @property
    def lock(self) -> Any:
        """The table's lock (a plain lock: :func:`appliance.runtime.pool.free_if_orphaned`)."""
        return self.header.get_lock()


def create_image_table(ctx: Any, image_size: tuple[int, int], binning: int = 1,
                       slots: int = SLOTS) -> ImageTable:
    """A table for the images the chain works on with cameras of ``image_size`` (W, H) and
    ``binning`` (:func:`processing.chain.binning.binned_size`); ``ctx`` a multiprocessing
    context. Takes slots x 2 x H x W x 4 bytes (4.9 MB at 320x240)."""
    w, h = binned_size(image_size, binning)
    if h < 1 or w < 1 or slots < 1:
        raise ValueError(f"need a positive image size and slot count, got {image_size} "
                         f"binned {binning}, {slots}")
    header = ctx.Array("d", [0.0] * (slots * _HEADER), lock=ctx.Lock())
    data = ctx.RawArray("f", slots * PER_SLOT * h * w)
    return ImageTable(header, data, (h, w))


class SharedImages:
    """A :class:`processing.chain.images.ImageShare` over an :class:`ImageTable`."""

    def __init__(self, table: ImageTable) -> None:
        self._lock = table.lock
        # The raw array: the synchronized wrapper would take the (not re-entrant) lock again.
        self._header = np.frombuffer(table.header.get_obj(), np.float64).reshape(-1, _HEADER)
        h, w = table.shape
        self._data = np.frombuffer(table.data, np.float32).reshape(-1, PER_SLOT, h, w)
        self.shape = (h, w)

    def _find(self, key: ImageKey) -> int | None:
        hits = np.flatnonzero((self._header[:, _COUNT] > 0)
                              & np.all(self._header[:, :KEY_LENGTH] == key, axis=1))
        return int(hits[0]) if hits.size else None

    def get(self, key: ImageKey, count: int) -> tuple[np.ndarray, ...] | None:
        with self._lock:
            i = self._find(key)
            if i is None or int(self._header[i, _COUNT]) != count:
                return None
            return tuple(self._data[i, k].copy() for k in range(count))

    def put(self, key: ImageKey, arrays: tuple[np.ndarray, ...]) -> None:
        if (not 1 <= len(arrays) <= PER_SLOT or len(key) != KEY_LENGTH
                or any(a.shape != self.shape or a.dtype != np.float32 for a in arrays)):
            return  # not what this table holds: the other worker computes it itself
        with self._lock:
            if self._find(key) is not None:
                return
            stamps = self._header[:, _STAMP]
            i = int(np.argmin(stamps))
            self._header[i, _COUNT] = 0  # empty while it is written
            for k, a in enumerate(arrays):
                self._data[i, k] = a
            self._header[i, :KEY_LENGTH] = key
            self._header[i, _STAMP] = float(stamps.max()) + 1.0
            self._header[i, _COUNT] = len(arrays)
