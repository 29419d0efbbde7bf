"""Stereo pairing: match left and right frames by capture time.

The two OGI cameras are not triggered together (paper Sec. 4.1), so each left frame is
paired with the right frame nearest in (clock-corrected) capture time, if it lies within a
tolerance (default half a frame period). Rules:

- each frame is used at most once;
- pairs never cross: if (L_i, R_j) and (L_k, R_m) are pairs with i < k then j < m
  (frames are consumed in time order);
- a pair is formed only when both frames are each other's nearest neighbour among the
  frames that are still free: ``L`` is paired with the first right frame ``R`` at or after
  it unless ``L``'s successor is strictly closer to ``R``;
- a frame that cannot be paired is reported as unpaired for its side.

Decisions are made as soon as they are certain. The pairer waits for a frame's successor
only when the successor could still change the decision; it knows the successor cannot when
(a) frames of one camera are at least ``min_interval_ns`` apart, or (b) the host clock
``now_ns`` shows that any frame still in flight has a capture time later than
``now_ns - max_delay_ns``. (b) also releases the frames of one camera while the other is
stopped, so a camera that stops and restarts (its sequence numbers and device clock reset)
costs unpaired frames for that time and nothing else.

Pure logic, no threads and no clocks of its own: the daemon feeds it (capture time, item)
per side with the host's arrival time as ``now_ns``; offline code calls :meth:`flush`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")

SIDES: tuple[str, str] = ("left", "right")


@dataclass(frozen=True)
class StereoPair(Generic[T]):
    """A left and a right item whose capture times lie within the tolerance.

    ``left_ns``/``right_ns`` are the capture times used for pairing (host monotonic ns).
    """

    left: T
    right: T
    left_ns: int
    right_ns: int

    @property
    def time_ns(self) -> int:
        """Time of the pair: the mean of both capture times, host ns."""
        return (self.left_ns + self.right_ns) // 2

    @property
    def residual_ns(self) -> int:
        """Right minus left capture time, ns (what the non-triggered pair leaves)."""
        return self.right_ns - self.left_ns


@dataclass
class PairingStats:
    """Counters since creation."""

    pairs: int = 0
    unpaired_left: int = 0
    unpaired_right: int = 0
    out_of_order: int = 0  # frames older than their side's previous one (counted as unpaired)
    max_abs_residual_ns: int = 0

    def unpaired(self, side: str) -> int:
        """Unpaired frames of ``side``."""
        return self.unpaired_left if side == "left" else self.unpaired_right


class StereoPairer(Generic[T]):
    """Online pairer of two time-stamped streams.

    Parameters
    ----------
    period_ns : int
        Nominal frame period, ns (33_333_333 at 30 Hz).
    tolerance_ns : int or None
        Largest allowed ``|right - left|`` of a pair, ns; default half a period.
    min_interval_ns : int or None
        Frames of one camera are never closer than this, ns; default 0.75 period. Lets the
        pairer decide without waiting for the next frame. 0 disables the shortcut.
    max_delay_ns : int
        Upper bound of (arrival - capture time) of any frame, ns (latency + jitter +
        acquisition thread); used with ``now_ns`` to know that no earlier frame is in flight.
    max_queue : int
        Frames kept per side at most while waiting; older ones are released as unpaired.
    """

    def __init__(
        self,
        period_ns: int,
        *,
        tolerance_ns: int | None = None,
        min_interval_ns: int | None = None,
        max_delay_ns: int = 200_000_000,
        max_queue: int = 256,
    ) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        self.period_ns = int(period_ns)
        self.tolerance_ns = int(period_ns // 2 if tolerance_ns is None else tolerance_ns)
        if self.tolerance_ns < 0:
            raise ValueError(f"tolerance_ns must be >= 0, got {tolerance_ns}")
        self.min_interval_ns = int(
            period_ns * 3 // 4 if min_interval_ns is None else min_interval_ns
        )
        self.max_delay_ns = int(max_delay_ns)
        self.max_queue = int(max_queue)
        self.stats = PairingStats()
        self._queues: dict[str, deque[tuple[int, T]]] = {s: deque() for s in SIDES}
        self._last_ns: dict[str, int | None] = {s: None for s in SIDES}
        self._unpaired: list[tuple[str, int, T]] = []

    # -- public --------------------------------------------------------------------------
    def push(
        self, side: str, time_ns: int, item: T, now_ns: int | None = None
    ) -> list[StereoPair[T]]:
        """Add a frame of ``side`` with capture time ``time_ns``; return the pairs now certain.

        ``now_ns`` is the host monotonic time of the call (normally the frame's arrival);
        without it, decisions that need the clock wait for later pushes or :meth:`flush`.
        """
        if side not in SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        time_ns = int(time_ns)
        last = self._last_ns[side]
        if last is not None and time_ns <= last:
            # Clock went backwards for this camera (e.g. restart not yet settled): the frame
            # cannot be placed without crossing pairs already made.
            self.stats.out_of_order += 1
            self._release(side, time_ns, item)
        else:
            self._last_ns[side] = time_ns
            queue = self._queues[side]
            queue.append((time_ns, item))
            if len(queue) > self.max_queue:
                t, it = queue.popleft()
                self._release(side, t, it)
        return self._process(now_ns)

    def poll(self, now_ns: int) -> list[StereoPair[T]]:
        """Decide what the passing of time makes certain (call when no frame arrives)."""
        return self._process(now_ns)

    def flush(self) -> list[StereoPair[T]]:
        """Decide everything as if no more frames will come (end of a recording)."""
        return self._process(None, final=True)

    def take_unpaired(self) -> list[tuple[str, int, T]]:
        """Return and forget the frames released unpaired since the last call:
        ``(side, time_ns, item)`` in release order."""
        out, self._unpaired = self._unpaired, []
        return out

    def pending(self, side: str) -> int:
        """Frames of ``side`` waiting for a decision."""
        return len(self._queues[side])

    # -- internals -----------------------------------------------------------------------
    def _release(self, side: str, time_ns: int, item: T) -> None:
        if side == "left":
            self.stats.unpaired_left += 1
        else:
            self.stats.unpaired_right += 1
        self._unpaired.append((side, time_ns, item))

    def _horizon(self, now_ns: int | None, final: bool) -> float:
        """Every frame not yet pushed has a capture time after this (ns)."""
        if final:
            return math.inf
        if now_ns is None:
            return -math.inf
        return now_ns - self.max_delay_ns

    def _process(self, now_ns: int | None, final: bool = False) -> list[StereoPair[T]]:
        horizon = self._horizon(now_ns, final)
        tol = self.tolerance_ns
        left, right = self._queues["left"], self._queues["right"]
        out: list[StereoPair[T]] = []
        while left or right:
            if not (left and right):
                side = "left" if left else "right"
                queue = left or right
                t, item = queue[0]
                if t + tol < horizon:  # no partner can still arrive
                    queue.popleft()
                    self._release(side, t, item)
                    continue
                break
            a_side = "left" if left[0][0] <= right[0][0] else "right"
            a_q, b_q = (left, right) if a_side == "left" else (right, left)
            ta, a = a_q[0]
            tb, b = b_q[0]
            d = tb - ta
            if d > tol:  # every free frame of the other side is later still
                a_q.popleft()
                self._release(a_side, ta, a)
                continue
            if len(a_q) > 1:
                if abs(a_q[1][0] - tb) < d:  # b prefers a's successor
                    a_q.popleft()
                    self._release(a_side, ta, a)
                    continue
            elif not (ta + self.min_interval_ns >= tb + d or horizon >= tb + d):
                break  # a's successor might still be closer to b: wait for it
            a_q.popleft()
            b_q.popleft()
            if a_side == "left":
                pair = StereoPair(left=a, right=b, left_ns=ta, right_ns=tb)
            else:
                pair = StereoPair(left=b, right=a, left_ns=tb, right_ns=ta)
            self.stats.pairs += 1
            self.stats.max_abs_residual_ns = max(self.stats.max_abs_residual_ns, abs(d))
            out.append(pair)
        return out
