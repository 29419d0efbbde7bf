"""Clock model: device clock -> host monotonic time from (device, arrival) pairs."""

from __future__ import annotations

import numpy as np
import pytest

from appliance.runtime.clock import ClockModel, lower_envelope_fit

P = 33_333_333


def _stream(
    n,
    *,
    drift_ppm=30.0,
    offset_ns=5_000_000_000_000,
    latency_ns=7_000_000,
    jitter_ns=2_000_000,
    seed=0,
    period_ns=P,
):
    """True capture times, device stamps and arrivals of ``n`` frames (int64 ns)."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    true = 10_000_000_000 + k * period_ns
    device = np.round(offset_ns + true * (1 + drift_ppm * 1e-6)).astype(np.int64)
    arrival = true + latency_ns + np.round(rng.exponential(jitter_ns, n)).astype(np.int64)
    return true, device, arrival


def test_envelope_fit_recovers_an_exact_line_and_stays_below_all_points() -> None:
    rng = np.random.default_rng(1)
    xs = np.sort(rng.uniform(0, 3e10, 500))
    ys = 12345.0 + (1 + 2e-5) * xs + rng.exponential(1e6, 500)
    c, b = lower_envelope_fit(xs, ys, 1e-3)
    assert np.all(ys - (c + b * xs) >= -1e-3)
    assert b == pytest.approx(1 + 2e-5, abs=2e-7)


def test_capture_time_error_is_microseconds_after_warmup() -> None:
    true, device, arrival = _stream(3000)
    m = ClockModel(latency_ns=7_000_000)
    est = np.array([m.update(int(a), int(d)) for a, d in zip(arrival, device, strict=True)])
    err = est[900:] - true[900:]  # after 30 s
    assert np.abs(err).max() < 100_000  # arrival jitter is 2 ms mean; the estimate is 100x better
    assert m.drift_ppm == pytest.approx(1e6 / (1 + 30e-6) - 1e6, abs=1.0)


def test_unknown_latency_remains_a_constant_bias() -> None:
    true, device, arrival = _stream(2000)
    m = ClockModel(latency_ns=0)
    est = np.array([m.update(int(a), int(d)) for a, d in zip(arrival, device, strict=True)])
    assert np.median(est[900:] - true[900:]) == pytest.approx(7_000_000, abs=100_000)


def test_clockless_device_is_smoothed_against_the_nominal_period() -> None:
    true, _, arrival = _stream(2000, drift_ppm=0.0)
    keep = np.ones(2000, bool)
    keep[[100, 101, 700, 1500]] = False  # dropped frames: gaps of two and three periods
    m = ClockModel(latency_ns=7_000_000, nominal_period_ns=P)
    est = np.array([m.update(int(a)) for a in arrival[keep]])
    err = est - true[keep]
    assert np.abs(err[900:]).max() < 200_000
    # the raw arrival jitter it removed was milliseconds
    assert np.abs(arrival[keep][900:] - 7_000_000 - true[keep][900:]).max() > 5_000_000


def test_device_clock_reset_restarts_the_estimate() -> None:
    true, device, arrival = _stream(1200)
    m = ClockModel(latency_ns=7_000_000)
    for a, d in zip(arrival[:600], device[:600], strict=True):
        m.update(int(a), int(d))
    # camera restarts: its clock starts again near zero, host time goes on
    restarted = device[600:] - device[600] + 1000
    est = [m.update(int(a), int(d)) for a, d in zip(arrival[600:], restarted, strict=True)]
    assert m.resets == 1
    assert abs(est[-1] - true[-1]) < 1_000_000


def test_host_stall_does_not_disturb_the_envelope() -> None:
    true, device, arrival = _stream(1500)
    arrival = arrival.copy()
    arrival[1000:1030] = np.maximum(arrival[1000:1030], arrival[1000] + 800_000_000)  # 0.8 s stall
    m = ClockModel(latency_ns=7_000_000)
    est = np.array([m.update(int(a), int(d)) for a, d in zip(arrival, device, strict=True)])
    assert m.resets == 0
    assert np.abs(est[1000:] - true[1000:]).max() < 100_000


def test_clockless_without_period_is_an_error() -> None:
    m = ClockModel()
    with pytest.raises(ValueError, match="nominal_period_ns"):
        m.update(123)
    with pytest.raises(ValueError):
        ClockModel(nominal_period_ns=0)


def test_clockless_late_frame_is_not_taken_for_a_drop() -> None:
    """Without device clock or frame ids: a frame 25 ms late (3/4 period) keeps its index,
    a dropped frame advances it by two, a frame 40 ms late costs that frame only."""
    true, _, arrival = _stream(2000, drift_ppm=0.0, jitter_ns=500_000)
    arrival = arrival.copy()
    arrival[1200] += 25_000_000  # late, still before frame 1201 is due
    arrival[1500] += 40_000_000  # later than the next frame's slot
    arrival[1501] = max(arrival[1501], arrival[1500])  # in-order delivery
    keep = np.ones(2000, bool)
    keep[1300] = False  # dropped
    m = ClockModel(latency_ns=7_000_000, nominal_period_ns=P)
    est = np.array([m.update(int(a)) for a in arrival[keep]])
    err = est - true[keep]
    idx = np.flatnonzero(keep)
    bad = idx[(np.abs(err) > 200_000) & (idx >= 100)]  # after the first few frames
    assert bad.tolist() == [1500]  # only the frame later than a whole slot
    assert m.misindexed == 1
