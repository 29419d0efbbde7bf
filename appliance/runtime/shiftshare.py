"""Registration shifts shared between the daemon's worker processes.

With two workers alternating, worker A's triple (t0, t1, t2) and worker B's next triple
(t1, t2, t3) both need the t1 -> t2 shift of each camera; each shift depends only on its
two frames, so the first worker to estimate it publishes it here and the other reads it
(:class:`processing.chain.shifts.ShiftMemo`). Each triple then estimates one shift per camera
instead of two, with identical results. A miss (the other worker has not got there yet, a
slot overwritten) only means estimating it again.
"""

from __future__ import annotations

import math
from typing import Any

from processing.chain.shifts import KnownShift

#: Slots of the table: far more than the frames two workers have in flight.
SLOTS = 64
#: camera, t_from, t_to, dx, dy, rejected
_FIELDS = 6


def create_shift_table(ctx: Any, slots: int = SLOTS) -> Any:
    """A shared table for :class:`SharedShiftMemo` (``ctx``: a multiprocessing context).

    Its lock is a plain (not re-entrant) lock, so that the daemon can give it back when a
    worker died holding it (:func:`appliance.runtime.pool.free_if_orphaned`).
    """
    return ctx.Array("d", [math.nan] * (slots * _FIELDS), lock=ctx.Lock())


class SharedShiftMemo:
    """A :class:`processing.chain.shifts.ShiftMemo` over a table from :func:`create_shift_table`.

    Slot of a shift: its first frame's time in ms and its camera, modulo the slot count; a
    slot holds the exact times, so a stale or colliding entry never matches.
    """

    def __init__(self, table: Any) -> None:
        self._lock = table.get_lock()
        # The raw array: the synchronized wrapper would take the (not re-entrant) lock again.
        self._table = table.get_obj()
        self._slots = len(self._table) // _FIELDS

    def _slot(self, camera: int, t_from: float) -> int:
        return (round(t_from * 1000.0) * 2 + camera) % self._slots * _FIELDS

    def get(self, camera: int, t_from: float, t_to: float) -> KnownShift | None:
        i = self._slot(camera, t_from)
        with self._lock:
            row = self._table[i:i + _FIELDS]
        if row[0] != camera or row[1] != t_from or row[2] != t_to:
            return None
        return (row[3], row[4]), bool(row[5])

    def put(self, camera: int, t_from: float, t_to: float, shift: tuple[float, float],
            rejected: bool) -> None:
        i = self._slot(camera, t_from)
        row = [float(camera), t_from, t_to, float(shift[0]), float(shift[1]), float(rejected)]
        with self._lock:
            self._table[i:i + _FIELDS] = row
