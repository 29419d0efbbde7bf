"""Bookkeeping of GigE Vision buffers: lost frames and arrival times (no Aravis needed).

Per buffer a GigE Vision camera gives the frame (block) id; GigE Vision 1.x block ids are
16 bit and skip 0 when they wrap. A gap in the ids is reported as ``Frame.lost``.

Arrival time: Aravis records the host wall-clock time of the frame's arrival in its stream
thread (``get_system_timestamp``); it is converted to the monotonic timeline (``monotonic_now
- (realtime_now - system_ts)``), which excludes the delay of our own thread waking up. If the
wall clock steps (NTP), the conversion is implausible and the monotonic time of the pop is
used instead.
"""

from __future__ import annotations

#: Largest plausible delay between a buffer's arrival and its pop, ns.
MAX_POP_DELAY_NS = 1_000_000_000


def frame_id_gap(previous: int | None, current: int) -> int:
    """Frames missing between two device frame ids (16-bit GigE Vision ids wrap to 1).

    A jump backwards that is not a wrap means the device restarted: nothing is counted.
    """
    if previous is None:
        return 0
    if current > previous:
        return current - previous - 1
    if previous >= 0xFF00 and current <= 0x00FF and previous <= 0xFFFF:
        return (0xFFFF - previous) + (current - 1)
    return 0


def arrival_mono_ns(system_ts_ns: int, mono_ns: int, real_ns: int) -> int:
    """Arrival time of a buffer on the monotonic timeline, ns.

    ``system_ts_ns`` is the host wall-clock arrival time Aravis stored; ``mono_ns`` and
    ``real_ns`` are the monotonic and the wall-clock time read together at the pop. A delay
    outside [0, :data:`MAX_POP_DELAY_NS`) means the wall clock stepped: ``mono_ns``.
    """
    delay = real_ns - system_ts_ns
    return mono_ns - delay if 0 <= delay < MAX_POP_DELAY_NS else mono_ns
