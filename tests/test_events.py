"""Leak-event logic (appliance.runtime.events): offline, on synthetic per-frame evidence."""

from __future__ import annotations

import numpy as np
import pytest

from appliance.runtime.events import (
    EventConfig,
    EvidenceStream,
    FrameEvidence,
    LeakDetector,
    evidence_from_fields,
    zone_mask,
)

FPS = 15.0


def _leak(t: float, k: int, rng: np.random.Generator) -> FrameEvidence:
    return FrameEvidence(t, k, 900, 0.8, (40.0 + rng.normal(0, 2), 120.0 + rng.normal(0, 2)),
                         rate_g_s=2.0, velocity_m_s=(1.0, 0.0, 0.2))


def _quiet(t: float, k: int) -> FrameEvidence:
    return FrameEvidence(t, k, 20, 0.1, None)


def _run(frames: list[FrameEvidence], cfg: EventConfig | None = None):
    det = LeakDetector(cfg)
    transitions = [tr for ev in frames for tr in det.update(ev)]
    det.close(frames[-1].t_s, frames[-1].frame, "end of data")
    return det, transitions


def test_a_steady_leak_is_one_event_with_start_and_end() -> None:
    rng = np.random.default_rng(0)
    frames = [(_leak(k / FPS, k, rng) if 5.0 <= k / FPS < 25.0 else _quiet(k / FPS, k))
              for k in range(int(40 * FPS))]
    det, transitions = _run(frames)
    assert [e.id for e in det.finished] == [1]
    ev = det.finished[0]
    start_t = next(e.start_t_s for kind, e in transitions if kind == "start")
    assert start_t == pytest.approx(5.0, abs=0.1)  # back-dated to the first positive frame
    assert ev.end_t_s == pytest.approx(25.0, abs=0.1) and ev.end_reason == "gas gone"
    assert ev.mean_rate_g_s == pytest.approx(2.0) and ev.peak_rate_g_s == pytest.approx(2.0)
    assert ev.source_xy == pytest.approx((40.0, 120.0), abs=1.0)
    assert 0.6 < ev.confidence <= 1.0


def test_detection_delay_is_the_minimum_duration() -> None:
    rng = np.random.default_rng(1)
    det = LeakDetector(EventConfig(min_duration_s=2.0))
    for k in range(int(20 * FPS)):
        t = k / FPS
        ev = _leak(t, k, rng) if t >= 5.0 else _quiet(t, k)
        if any(kind == "start" for kind, _ in det.update(ev)):
            assert t - 5.0 == pytest.approx(2.0, abs=0.1)
            return
    pytest.fail("no event started")


def test_a_moving_warm_object_raises_no_event() -> None:
    # Coherent motion and many pixels, but its "source" travels with it (3 px per frame).
    frames = [FrameEvidence(k / FPS, k, 1200, 0.95, (10.0 + 3.0 * k % 300, 100.0))
              for k in range(int(60 * FPS))]
    det, transitions = _run(frames)
    assert det.finished == [] and transitions == []


def test_flicker_below_the_start_fraction_raises_no_event() -> None:
    rng = np.random.default_rng(2)
    frames = [(_leak(k / FPS, k, rng) if rng.random() < 0.3 else _quiet(k / FPS, k))
              for k in range(int(120 * FPS))]
    det, _ = _run(frames)
    assert det.finished == []


def test_hysteresis_keeps_an_intermittent_leak_as_one_event() -> None:
    rng = np.random.default_rng(3)
    frames = []
    for k in range(int(60 * FPS)):
        t = k / FPS
        on = 5.0 <= t < 45.0 and (t < 10.0 or rng.random() < 0.5)
        frames.append(_leak(t, k, rng) if on else _quiet(t, k))
    det, _ = _run(frames)
    assert len(det.finished) == 1 and det.finished[0].end_t_s == pytest.approx(45.0, abs=0.5)


def test_min_rate_and_close_at_shutdown() -> None:
    rng = np.random.default_rng(4)
    frames = [_leak(k / FPS, k, rng) for k in range(int(10 * FPS))]
    det, _ = _run(frames, EventConfig(min_rate_g_s=5.0))
    assert det.finished == []  # 2 g/s is below the threshold
    det, _ = _run(frames)
    assert len(det.finished) == 1 and det.finished[0].end_reason == "end of data"


def test_zones_and_evidence_from_fields() -> None:
    h, w = 120, 160
    zones = zone_mask((h, w), ignore=[((0, 0), (80, 0), (80, h), (0, h))])
    assert not zones[:, :79].any() and zones[:, 81:].all()
    mask = np.zeros((h, w), bool)
    mask[50:70, 20:140] = True
    flow = np.zeros((h, w, 2))
    flow[..., 0] = 1.5
    ev = evidence_from_fields(1.0, 3, mask, flow, zones, rate_g_s=1.0)
    assert ev.gas_pixels == 20 * (140 - 81)  # only the part right of the ignore zone (x > 80)
    assert ev.coherence == pytest.approx(1.0)
    assert ev.source_xy is not None and 80 <= ev.source_xy[0] <= 84 and ev.rate_g_s == 1.0
    # the same from the flow at the gas pixels only (what a live worker sends)
    sparse = evidence_from_fields(1.0, 3, mask, flow[mask], zones, rate_g_s=1.0)
    for name in ("gas_pixels", "coherence", "source_xy", "resultant", "flow_px", "on_border"):
        assert getattr(sparse, name) == getattr(ev, name), name
    np.testing.assert_array_equal(sparse.coverage, ev.coverage)
    with pytest.raises(ValueError, match="gas pixels"):
        evidence_from_fields(1.0, 3, mask, flow[mask][1:], zones)
    watch = zone_mask((h, w), watch=[((0, 0), (10, 0), (10, 10), (0, 10))])
    assert watch.sum() == 121


def test_evidence_stream_keeps_the_source_of_a_plume_whose_direction_wobbles() -> None:
    """A round plume base: the per-frame direction swings +-35 deg, so the upstream end along
    each frame's own direction jumps; along the smoothed direction it stays put."""
    h, w = 120, 160
    yy, xx = np.mgrid[:h, :w]
    mask = ((xx - 40) ** 2 + (yy - 60) ** 2 < 25 ** 2) | ((np.abs(yy - 60) < 15) & (xx > 40))
    stream = EvidenceStream()
    raw, smooth = [], []
    for k in range(150):
        a = np.deg2rad(35.0 if k % 2 else -35.0)
        flow = np.zeros((h, w, 2))
        flow[..., 0], flow[..., 1] = np.cos(a), np.sin(a)
        raw.append(evidence_from_fields(k / 30, k, mask, flow).source_xy)
        smooth.append(stream(k / 30, k, mask, flow).source_xy)

    def spread(points: list) -> float:
        p = np.asarray(points[100:])  # after the average settled
        return float(np.hypot(*(p.max(axis=0) - p.min(axis=0))))
    assert spread(raw) > 25.0  # the fixed-source rule would reject every other frame
    assert spread(smooth) < 3.0


def test_source_rule_under_gas_accepts_a_jumping_plume_end_and_rejects_a_moving_object() -> None:
    """Fields through evidence_from_fields: a plume whose segmented base reaches the image edge
    on every other frame (its upstream end jumps 40 px) still starts an event, because gas
    covers its source; a warm object moving across the image never does."""
    h, w = 120, 160
    yy, xx = np.mgrid[:h, :w]
    flow = np.zeros((h, w, 2))
    flow[..., 0] = 1.0
    plume = (np.abs(yy - 60) < 12) & (xx > 45)
    edge = plume | ((np.abs(yy - 70) < 6) & (xx < 50))
    cfg = EventConfig(min_gas_pixels=100, min_duration_s=1.0)
    det = LeakDetector(cfg)
    for k in range(int(6 * FPS)):
        det.update(evidence_from_fields(k / FPS, k, edge if k % 2 else plume, flow))
    assert det.current is not None
    det = LeakDetector(cfg)
    for k in range(int(6 * FPS)):
        blob = (xx - (10 + 2.5 * k)) ** 2 + (yy - 60) ** 2 < 12 ** 2
        det.update(evidence_from_fields(k / FPS, k, blob, flow))
    assert det.current is None and not det.finished


def test_a_source_that_travels_with_its_flow_starts_no_event() -> None:
    """Motion as a gas descriptor: a slow warm object whose upstream end moves on at the
    speed of its own flow (0.5 px per frame, within max_source_shift_px over the start
    window, so the fixed-source rule alone let it start) raises no event; the same gas with
    its source fixed at the leak does."""
    def frames(source_speed: float) -> list[FrameEvidence]:
        return [FrameEvidence(k / FPS, k, 900, 0.95, (100.0 + source_speed * k, 120.0),
                              flow_px=(0.5, 0.0)) for k in range(int(6 * FPS))]
    det, _ = _run(frames(0.5))
    assert det.finished == []
    det, _ = _run(frames(0.0))
    assert len(det.finished) == 1


def test_a_long_event_keeps_constant_size_and_exact_statistics() -> None:
    # A leak that lasts until it is repaired: weeks of results. The event keeps running
    # sums and a bounded source window, not a list per result (which grew the daemon by
    # tens of MB an hour in a soak with the simulated leak on).
    from appliance.runtime.events import SOURCE_WINDOW, LeakEvent

    rng = np.random.default_rng(3)
    ev = LeakEvent(id=1, start_t_s=0.0, start_frame=0)
    rates, vels, cohs = [], [], []
    for k in range(20_000):
        rate = float(rng.uniform(1.0, 3.0))
        vel = tuple(float(x) for x in rng.normal(0.0, 1.0, 3))
        coh = float(rng.uniform(0.5, 1.0))
        positive = k % 4 != 0
        ev.add(FrameEvidence(k / FPS, k, 900, coh, (float(k % 300), 10.0), rate_g_s=rate,
                             velocity_m_s=vel, wind_m_s=vel), positive)
        if positive:
            rates.append(rate)
            vels.append(vel)
            cohs.append(coh)
    assert len(ev._sources) == SOURCE_WINDOW
    assert not any(isinstance(v, list) for v in vars(ev).values())
    assert ev.mean_rate_g_s == pytest.approx(np.mean(rates), rel=1e-9)
    assert ev.peak_rate_g_s == pytest.approx(max(rates))
    assert ev.mean_velocity_m_s == pytest.approx(tuple(np.mean(vels, axis=0)), rel=1e-9)
    assert ev.mean_wind_m_s == pytest.approx(tuple(np.mean(vels, axis=0)), rel=1e-9)
    assert ev.confidence == pytest.approx(len(cohs) / 20_000 * np.mean(cohs), rel=1e-9)
    assert ev.frames == 20_000 and ev.positive_frames == len(rates)
