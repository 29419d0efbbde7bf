"""Leak-event messages: new / update only on a change, at most once per update_s / end."""

from __future__ import annotations

import itertools

import pytest

from appliance.alarms.throttle import EventThrottle, event_message, rate_class


def _ev(t_s: float, rate_kg_h: float | None = 1.5, source=(100.0, 80.0), flags=(),
        eid: int = 7, **extra) -> dict:
    return {"id": eid, "t_wall_ns": int(t_s * 1e9), "start_t_s": 0.0, "rate_kg_h": rate_kg_h,
            "rate_flags": list(flags), "source_xy": source, **extra}


def test_rate_classes() -> None:
    assert [rate_class(v) for v in (None, float("nan"), 0.05, 0.1, 0.5, 2.0, 99.0, 100.0,
                                    1e4)] == [
        "unknown", "unknown", "<0.1", "0.1-0.3", "0.3-1", "1-3", "30-100", ">=100", ">=100"]


def test_an_unchanging_event_sends_new_and_end_only() -> None:
    th = EventThrottle(update_s=1.0)
    out = [th.offer("start", _ev(0.0))]
    out += [th.offer("update", _ev(k / 15)) for k in range(1, 15 * 60)]  # 60 s at 15 Hz
    out.append(th.offer("end", _ev(60.0, end_t_s=59.9, end_reason="gas gone",
                                   peak_rate_g_s=0.6)))
    sent = [m for m in out if m is not None]
    assert [m["type"] for m in sent] == ["new", "end"]
    assert {m["id"] for m in sent} == {7}
    assert sent[-1]["state"] == "ended" and sent[-1]["peak_rate_g_s"] == 0.6
    assert sent[-1]["duration_s"] == pytest.approx(59.9)
    assert th.seen == 15 * 60 + 1 and th.passed == 2


def test_changes_go_out_at_most_once_per_update_s() -> None:
    th = EventThrottle(update_s=1.0)
    th.offer("start", _ev(0.0))
    # the rate class flips on every frame: at most one update a second
    sent = [th.offer("update", _ev(k / 15, rate_kg_h=0.5 if k % 2 else 2.0))
            for k in range(1, 15 * 10 + 1)]
    times = [m["t_wall_ns"] / 1e9 for m in sent if m is not None]
    assert 8 <= len(times) <= 10
    assert all(b - a >= 1.0 - 1e-9 for a, b in itertools.pairwise(times))


def test_each_kind_of_change_counts() -> None:
    for change in ({"rate_kg_h": 5.0}, {"source": (140.0, 80.0)}, {"flags": ("line_of_sight",)},
                   {"source": None}):
        th = EventThrottle(update_s=1.0)
        th.offer("start", _ev(0.0))
        assert th.offer("update", _ev(0.5, **change)) is None  # too soon
        msg = th.offer("update", _ev(1.2, **change))
        assert msg is not None and msg["type"] == "update", change
        assert th.offer("update", _ev(2.5, **change)) is None  # no further change
    th = EventThrottle(update_s=1.0, source_step_px=12.0)
    th.offer("start", _ev(0.0))
    assert th.offer("update", _ev(2.0, source=(108.0, 84.0))) is None  # moved < 12 px


def test_two_events_keep_their_own_ids() -> None:
    th = EventThrottle(update_s=0.0)
    a = th.offer("start", _ev(0.0, eid=1))
    th.offer("end", _ev(1.0, eid=1, end_t_s=1.0))
    b = th.offer("start", _ev(2.0, eid=2))
    assert (a["id"], b["id"]) == (1, 2)
    assert event_message("update", _ev(3.0, eid=2))["duration_s"] == pytest.approx(3.0)
