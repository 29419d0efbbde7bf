"""Registration shifts shared between triples and workers (paper Sec. 4.1's jitter removal).

The shift between two consecutive frames of a camera depends only on those two frames, so it
is estimated once: at stride 1 the t1 -> t2 shift of one triple is the t0 -> t1 shift of the
next, and the daemon's workers share one memo (``appliance.runtime.shiftshare``), so that with
two workers alternating each triple estimates one shift per camera, not two.
"""

from __future__ import annotations

from typing import Protocol

#: A registration shift (dx, dy) in px and whether it was rejected (then it is (0, 0)).
KnownShift = tuple[tuple[float, float], bool]


class ShiftMemo(Protocol):
    """Registration shifts between two frames of one camera, keyed by their capture times.

    A shift depends only on the two (corrected) frames, so whoever estimated it first can
    hand it to every later triple containing the same two frames; results are identical.
    """

    def get(self, camera: int, t_from: float, t_to: float) -> KnownShift | None:
        """The shift of frame ``t_to`` relative to frame ``t_from`` (s), or None."""

    def put(self, camera: int, t_from: float, t_to: float, shift: tuple[float, float],
            rejected: bool) -> None:
        """Remember a shift estimated by this process."""


class LocalShiftMemo:
    """A :class:`ShiftMemo` of one process: the last ``capacity`` shifts in a dict."""

    def __init__(self, capacity: int = 16) -> None:
        self.capacity = capacity
        self._items: dict[tuple[int, float, float], KnownShift] = {}

    def get(self, camera: int, t_from: float, t_to: float) -> KnownShift | None:
        return self._items.get((camera, t_from, t_to))

    def put(self, camera: int, t_from: float, t_to: float, shift: tuple[float, float],
            rejected: bool) -> None:
        self._items[(camera, t_from, t_to)] = ((float(shift[0]), float(shift[1])), rejected)
        while len(self._items) > self.capacity:
            del self._items[next(iter(self._items))]  # dicts keep insertion order
