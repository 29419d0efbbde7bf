"""Per-device clock model: map a camera's frame times onto the host monotonic timeline.

Model
-----
A frame captured at true host time ``t`` carries the device timestamp ``d = o + r t`` (device
clock offset ``o`` and rate ``r = 1 + drift``; drift is tens of ppm for a crystal) and reaches
the host at ``a = t + L + j`` where ``L`` is the fixed latency (exposure/readout end to the
host: transport, driver) and ``j >= 0`` the arrival jitter (network, USB, scheduling). So

    a = alpha + beta d + L + j,   with beta = 1 / r, alpha = -o / r, j >= 0.

Because the jitter is never negative, the points ``(d_i, a_i)`` lie on or above the line
``alpha + beta d + L``: the *lower envelope* of the arrivals tracks the true mapping, and the
frames that were delayed least define it. Over a sliding window (default 60 s: long
enough to average the jitter, short enough that a crystal's temperature-dependent drift is
constant within it) we fit the line that lies below every point and minimises the summed
vertical distance to them (a
linear programme whose optimum is the edge of the lower convex hull that spans the mean of
``d``; Moon, Skelly & Towsley, "Estimation and removal of clock skew from network delay
measurements", INFOCOM 1999). The capture time of a frame is then

    t_hat = alpha_hat + beta_hat d - L_known,

which removes the arrival jitter entirely and the latency as far as it is known
(``latency_ns``, per camera, from the camera's data sheet or a measurement). A latency that
is not configured stays in ``t_hat`` as a constant bias; for stereo pairing only the
*difference* of the two cameras' biases matters.

Devices without a clock (V4L2, RTSP, video files) use the same fit with ``d`` replaced by the
nominal frame time ``k P`` (``P`` the nominal frame period). ``k`` comes from the device frame
id when there is one; otherwise it is counted against the envelope: an arrival before the
envelope time of frame ``k + 2`` (less a margin of P/8) is frame ``k + 1`` however late,
because jitter is never negative; a later one means frames were dropped. A frame more than
7/8 of a period late is miscounted once, which the next frame reveals (``misindexed``); its
point is then left out of the fit, so the count does not stay shifted. This smooths the
arrival times against a steady frame clock and estimates its rate.

Resets: when the device clock goes backwards or jumps forwards (camera restarted, clock
reset), the arrival falls more than ``reset_threshold_ns`` below the envelope or ``d`` does
not increase; the window is then cleared and the estimate starts again (counted in
``resets``). Late arrivals (host stalls) only lie above the envelope and do not disturb it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockFit:
    """The current estimate: ``host_ns ~= host0 + intercept + slope * (x - x0)``.

    ``x`` is the device timestamp in ns (or the nominal frame time for clockless devices);
    ``slope - 1`` is the device clock's rate error against the host (positive: device clock
    slow), ``intercept`` and ``host0``/``x0`` are in ns.
    """

    x0: int
    host0: int
    intercept: float
    slope: float

    def host_time(self, x: int) -> float:
        """Envelope (least-delay arrival) time of device time ``x``, host ns."""
        return self.host0 + self.intercept + self.slope * (x - self.x0)


def lower_envelope_fit(
    xs: np.ndarray, ys: np.ndarray, max_rate_error: float
) -> tuple[float, float]:
    """Line ``y = c + b x`` below all points minimising the summed vertical gap.

    The sum of gaps is ``n (mean(y) - c - b mean(x))``, so the optimum is the line below the
    points that is highest at ``mean(x)``: with ``c(b) = min_i (y_i - b x_i)`` the value
    ``f(b) = min_i (y_i - b (x_i - mean x))`` is concave in ``b`` with subgradient
    ``-(x_i* - mean x)`` at the minimising point ``i*``; bisection on its sign finds the
    optimum (geometrically: the lower-hull edge spanning ``mean(x)``).

    Parameters
    ----------
    xs, ys : numpy.ndarray
        (N,) float64 points (ns, relative to a nearby origin).
    max_rate_error : float
        ``|b - 1|`` is limited to this (e.g. 1e-3 for 1000 ppm).

    Returns
    -------
    (c, b) : tuple of float
    """
    xc = xs - xs.mean()
    lo, hi = 1.0 - max_rate_error, 1.0 + max_rate_error
    for _ in range(48):  # interval 2e-3 / 2**48: far below any measurable rate
        b = 0.5 * (lo + hi)
        side = xc[int(np.argmin(ys - b * xc))]
        if side > 0:
            hi = b
        elif side < 0:
            lo = b
        else:
            lo = hi = b
            break
    b = 0.5 * (lo + hi)
    c = float(np.min(ys - b * xs))
    return c, b


class ClockModel:
    """Online estimate of one device's clock against host monotonic time.

    Parameters
    ----------
    latency_ns : int
        Known fixed latency from capture to host arrival, ns (subtracted from the envelope).
    nominal_period_ns : int or None
        Nominal frame period, ns; required for devices without timestamps.
    window_ns : int
        Length of the sliding fit window in device (or nominal) time, ns.
    min_span_ns : int
        Until the window spans this long the rate is fixed at 1 (a slope from a short span
        would be dominated by jitter); only the offset is estimated.
    max_drift_ppm : float
        Bound on the clock rate error, ppm (estimates are clamped).
    refit_every : int
        Refit the envelope every this many samples (and whenever a sample falls below it).
    reset_threshold_ns : int
        An arrival this far below the envelope means the device clock jumped: start over.

    Examples
    --------
    >>> m = ClockModel(latency_ns=5_000_000)
    >>> t = m.update(host_ns=1_000_000_000, device_ts_ns=42)
    """

    def __init__(
        self,
        *,
        latency_ns: int = 0,
        nominal_period_ns: int | None = None,
        window_ns: int = 60_000_000_000,
        min_span_ns: int = 2_000_000_000,
        max_drift_ppm: float = 1000.0,
        refit_every: int = 15,
        reset_threshold_ns: int = 500_000_000,
    ) -> None:
        if window_ns <= 0 or min_span_ns < 0 or refit_every < 1:
            raise ValueError("window_ns must be > 0, min_span_ns >= 0, refit_every >= 1")
        if nominal_period_ns is not None and nominal_period_ns <= 0:
            raise ValueError(f"nominal_period_ns must be > 0, got {nominal_period_ns}")
        self.latency_ns = int(latency_ns)
        self.nominal_period_ns = nominal_period_ns
        self.window_ns = int(window_ns)
        self.min_span_ns = int(min_span_ns)
        self.max_rate_error = max_drift_ppm * 1e-6
        self.refit_every = refit_every
        self.reset_threshold_ns = int(reset_threshold_ns)
        self.resets = 0
        self.misindexed = 0  # clockless devices: frames found counted a period too far
        self._refit_pending = False
        self._inferred = False
        self._pending: tuple[int, int] | None = None
        self._burst = False
        self._points: deque[tuple[int, int]] = deque()
        self._fit: ClockFit | None = None
        self._since_fit = 0
        # State of the frame counter used for clockless devices.
        self._k = -1
        self._last_host: int | None = None
        self._last_frame_id: int | None = None

    # -- public --------------------------------------------------------------------------
    def update(
        self, host_ns: int, device_ts_ns: int | None = None, device_frame_id: int | None = None
    ) -> int:
        """Add one frame's (device time, arrival) and return its capture time, host ns.

        Parameters
        ----------
        host_ns : int
            Host ``time.monotonic_ns()`` at arrival.
        device_ts_ns : int or None
            Device timestamp, ns; None for devices without a clock (then the nominal period
            must be set).
        device_frame_id : int or None
            Device frame id, used to count periods across dropped frames when there is no
            device clock.
        """
        x = self._x_for(host_ns, device_ts_ns, device_frame_id)
        last = self._pending or (self._points[-1] if self._points else None)
        # Arrived in less than half the device time that passed since the last frame, and
        # below the envelope by more than half that time, so that the envelope moves to it
        # and its stamp is its own arrival: a catch-up burst after a stall, which says little
        # of when it was captured. A timely frame after one delayed frame lies on or just
        # below the envelope (its stamp is good: 3 of 36,000 simulated frames with 20-120 ms
        # stalls would otherwise have been left unpaired); a burst lying above the envelope
        # is stamped from the envelope; both pair as usual.
        self._burst = (last is not None and self._fit is not None
                       and 2 * (host_ns - last[1]) < x - last[0]
                       and 2 * (self._fit.host_time(x) - host_ns) > x - last[0])
        if last is not None:
            residual = host_ns - self._fit.host_time(x) if self._fit else 0.0
            if x <= last[0] or residual < -self.reset_threshold_ns:
                self._reset()
                if device_ts_ns is None:
                    x = self._x_for(host_ns, None, device_frame_id)
        if self._inferred and self._fit is not None:
            # Index counted from the arrival: only the next frame shows whether this one was
            # late and miscounted, so its point joins the fit one frame later.
            if self._pending is not None:
                self._add(*self._pending)
            self._pending = (x, host_ns)
        else:
            if self._pending is not None:
                self._add(*self._pending)
                self._pending = None
            self._add(x, host_ns)
        if self._fit is None or self._refit_pending:
            self._refit()
        assert self._fit is not None
        return round(self._fit.host_time(x)) - self.latency_ns

    def _add(self, x: int, host_ns: int) -> None:
        """Put a point into the fit window (refit when it lies below the envelope)."""
        if self._fit is not None and host_ns < self._fit.host_time(x):
            self._refit_pending = True
        self._points.append((x, host_ns))
        while self._points[0][0] < x - self.window_ns:
            self._points.popleft()
        self._since_fit += 1
        if self._since_fit >= self.refit_every:
            self._refit_pending = True

    @property
    def provisional(self) -> bool:
        """True when the last frame's stamp is its own arrival, which nothing confirms.

        That is so while the fit rests on one frame alone (the first after a start or a
        reset), and for a frame of a catch-up burst: one that arrived in less than half the
        device time that passed since the previous frame and lies below the envelope by
        more than half that time, so that it sets the envelope itself. Such a capture time
        is late by however long the frame waited on its way: a first frame delivered 0.67 s
        late after a start stall was paired with the other camera's frame of 0.67 s later
        (measured), and such a pair yields a nonsense disparity. The first frame to arrive
        at its usual pace corrects the envelope. A burst that lies above the envelope (a
        stall once the envelope rests on timely frames) is stamped from the envelope and is
        not provisional.
        """
        return self._burst or len(self._points) + (self._pending is not None) <= 1

    @property
    def fit(self) -> ClockFit | None:
        """Current estimate, or None before the first sample."""
        return self._fit

    @property
    def drift_ppm(self) -> float:
        """Rate of the host clock against the device clock minus 1, ppm (0 before a fit)."""
        return 0.0 if self._fit is None else (self._fit.slope - 1.0) * 1e6

    @property
    def n_samples(self) -> int:
        """Samples in the current window."""
        return len(self._points)

    # -- internals -----------------------------------------------------------------------
    def _x_for(self, host_ns: int, device_ts_ns: int | None, device_frame_id: int | None) -> int:
        self._inferred = False
        if device_ts_ns is not None:
            return int(device_ts_ns)
        if self.nominal_period_ns is None:
            raise ValueError("a device without timestamps needs nominal_period_ns")
        period = self.nominal_period_ns
        if self._last_host is None or self._k < 0:
            step = 0
            self._k = 0
        elif (
            device_frame_id is not None
            and self._last_frame_id is not None
            and device_frame_id > self._last_frame_id
        ):
            step = device_frame_id - self._last_frame_id
        elif self._fit is not None and len(self._points) >= 2:
            # Count periods against the jitter-free envelope, where the next frame would
            # arrive with no delay, not against the previous (jittered) arrival. Jitter is
            # never negative, so an arrival before the envelope time of frame k+2 is frame
            # k+1, however late (up to a period minus the margin for envelope error); only
            # an arrival after it means frames were dropped.
            self._inferred = True
            expected = self._fit.host_time((self._k + 1) * period)
            step = 1 + math.floor((host_ns - expected + period / 8) / period)
            if step <= 0:
                # The previous frame came more than 7/8 of a period late and was counted one
                # period too far: this frame takes that index, the late point is discarded.
                self._pending = None
                self.misindexed += 1
                step = 0
        else:
            self._inferred = True
            step = max(1, round((host_ns - self._last_host) / period))
        self._k += step
        self._last_host = host_ns
        self._last_frame_id = device_frame_id
        return self._k * period

    def _reset(self) -> None:
        self.resets += 1
        self._points.clear()
        self._pending = None
        self._refit_pending = False
        self._fit = None
        self._since_fit = 0
        self._k = -1
        self._last_host = None
        self._last_frame_id = None

    def _refit(self) -> None:
        n = len(self._points)
        x0, y0 = self._points[0]
        xs = np.fromiter((p[0] - x0 for p in self._points), dtype=np.float64, count=n)
        ys = np.fromiter((p[1] - y0 for p in self._points), dtype=np.float64, count=n)
        if xs[-1] < self.min_span_ns:
            c, b = float(np.min(ys - xs)), 1.0
        else:
            c, b = lower_envelope_fit(xs, ys, self.max_rate_error)
        self._fit = ClockFit(x0=x0, host0=y0, intercept=c, slope=b)
        self._since_fit = 0
        self._refit_pending = False
