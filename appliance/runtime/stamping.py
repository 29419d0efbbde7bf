"""Stereo stamping: camera frames -> time-stamped stereo pairs (paper Sec. 4.1).

A clock model per camera (device clock against host monotonic time, arrival jitter
removed) and the time-based pairer. ``ogiflow run`` and ``ogiflow replay`` both use
:class:`StereoStamper`, so a replayed recording is paired exactly as it was live.
"""

from __future__ import annotations

from typing import Any

from appliance.runtime.clock import ClockModel
from appliance.runtime.pairing import StereoPairer

SIDES = ("left", "right")


class StereoStamper:
    """Clock model per camera + stereo pairer (paper Sec. 4.1: cameras not triggered).

    Parameters
    ----------
    frame_rate_hz : float
        Nominal frame rate of both cameras.
    tolerance_s : float or None
        Pairing tolerance; None = half a frame period.
    max_delay_s : float
        How long a frame waits for its partner before it is released unpaired.
    """

    def __init__(self, frame_rate_hz: float, tolerance_s: float | None = None,
                 max_delay_s: float = 0.2) -> None:
        period = int(1e9 / frame_rate_hz)
        #: Nominal frame period, ns.
        self.period_ns = period
        self.pairer: StereoPairer[Any] = StereoPairer(
            period, tolerance_ns=None if tolerance_s is None else int(tolerance_s * 1e9),
            max_delay_ns=int(max_delay_s * 1e9))
        self.clocks = {s: ClockModel(nominal_period_ns=period) for s in SIDES}
        #: Frames per side left out of pairing because their stamp was provisional.
        self.provisional = dict.fromkeys(SIDES, 0)

    def push(self, side: str, frame: Any, now_ns: int | None) -> list[Any]:
        """Stamp one frame (capture time from its clock model) and return new pairs."""
        clock = self.clocks[side]
        t = clock.update(frame.host_ns, frame.device_ts_ns, frame.device_frame_id)
        if clock.provisional:
            # Stamped from its arrival alone (ClockModel.provisional): not paired, counted
            # as unpaired; the recording keeps the frame.
            self.provisional[side] += 1
            return [] if now_ns is None else self.poll(now_ns)
        return self._forget_unpaired(self.pairer.push(side, t, frame, now_ns=now_ns))

    def poll(self, now_ns: int) -> list[Any]:
        return self._forget_unpaired(self.pairer.poll(now_ns))

    def _forget_unpaired(self, pairs: list[Any]) -> list[Any]:
        # The pairer keeps released frames (images included) until taken; nobody here needs
        # them beyond the counts in pairer.stats, and keeping them grows memory by a whole
        # camera's frame rate while the other camera is out.
        self.pairer.take_unpaired()
        return pairs

    def flush(self) -> list[Any]:
        return self.pairer.flush()

    def unpaired(self) -> dict[str, int]:
        return {s: self.pairer.stats.unpaired(s) + self.provisional[s] for s in SIDES}
