"""Result publishing (runtime.publishing.ResultPublisher): what a worker result becomes in the
MCAP file and the live view - summary fields and flags, fields every N-th result, the wind in
the camera frame (none for a non-finite wind) and the comparison with the simulator's truth."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from appliance.recording import schemas as S
from appliance.runtime.publishing import ResultPublisher
from appliance.runtime.worker_result import WorkerResult
from drivers.anemometer.history import WindAt

H, W = 6, 8
WALL_OFFSET = 1_700_000_000_000_000_000


@dataclass
class _Record:
    topic: str
    schema: S.MessageSchema
    payload: bytes
    log_time: int
    publish_time: int | None


class FakeRecorder:
    def __init__(self) -> None:
        self.records: list[_Record] = []

    def record(self, topic: str, schema: S.MessageSchema, payload: bytes, log_time: int,
               publish_time: int | None = None) -> None:
        self.records.append(_Record(topic, schema, payload, log_time, publish_time))

    def topic(self, name: str) -> list[_Record]:
        return [r for r in self.records if r.topic == name]


class FakeLive:
    def __init__(self) -> None:
        self.items: list[Any] = []

    def push(self, item: Any) -> bool:
        self.items.append(item)
        return True


def _result(i: int, *, valid: bool = True, rejected: int = 0, error: str | None = None,
            velocity: tuple[float, float, float] = (1.0, 0.0, 1.0)) -> WorkerResult:
    t = 10_000_000_000 + i * 33_333_333
    v = np.array(velocity)
    speed = float(np.linalg.norm(v))
    summary = {"valid": valid, "pixel_count": 5 if valid else 0, "gas_pixel_count": 7,
               "mean_velocity": tuple(map(float, v)) if valid else None,
               "speed": speed if valid else None,
               "angles_deg": (45.0, 90.0, 45.0) if valid else None,
               "c_usf": 0.8 if valid else None, "flags": [] if valid else ["no_gas"]}
    mask = np.zeros((H, W), bool)
    mask[2:4, 3:6] = True
    return WorkerResult(
        worker=0, pair_indices=(i, i + 1, i + 2), t_mono_ns=(t, t + 33_333_333, t + 66_666_666),
        t_wall_ns=t + WALL_OFFSET, skipped=2, done_mono_ns=t + 66_666_666 + 40_000_000,
        error=error, summary=summary, rejected_shifts=rejected,
        diff_left=np.full((H, W), 128, np.uint8), diff_right=np.full((H, W), 128, np.uint8),
        flow=np.zeros((H, W, 2), np.float32), disparity=np.full((H, W), 4.0, np.float32),
        disparity_change=np.zeros((H, W), np.float32),
        velocity=np.tile(np.float32(v), (H, W, 1)), valid=np.ones((H, W), bool), gas_mask=mask,
        gas_flow=np.zeros((int(mask.sum()), 2), np.float32),
        points3d=np.zeros((6, 3), np.float32), velocity3d=np.tile(np.float32(v), (6, 1)))


def _wind(vector: tuple[float, float, float], span_ns: int = 10) -> Any:
    return lambda t: WindAt(host_ns=t, vector=np.array(vector, float), flag="ok",
                            span_ns=span_ns, vertical_measured=True)


def _publisher(rec: FakeRecorder | None, live: FakeLive | None, fields_every: int = 1,
               **kw: Any) -> ResultPublisher:
    return ResultPublisher(rec, live, lambda t: t + WALL_OFFSET, fields_every, **kw)


def test_summary_fields_match_the_schema_and_the_result() -> None:
    rec = FakeRecorder()
    pub = _publisher(rec, None, fields_every=1000)
    summary = pub.publish(_result(3, rejected=1))
    assert summary is not None
    (r,) = rec.topic("/sceneflow/summary")
    msg = json.loads(r.payload)
    assert msg == json.loads(json.dumps(summary))
    assert S.validate_json(S.SCENEFLOW_SUMMARY, msg) == []
    t1 = 10_000_000_000 + 4 * 33_333_333
    assert (msg["t_mono_ns"], msg["t_wall_ns"], msg["pair_index"]) == (t1, t1 + WALL_OFFSET, 4)
    assert r.log_time == t1 + WALL_OFFSET and r.publish_time == t1
    assert msg["gas_pixels"] == 7 and msg["skipped_pairs"] == 2 and msg["valid"] is True
    assert msg["mean_velocity_m_s"] == [1.0, 0.0, 1.0] and msg["c_usf"] == 0.8
    assert msg["latency_ms"] == pytest.approx(40.0)  # arrival of t2 to result
    # A registration that rejected a shift flags the frame (jitter not removed).
    assert msg["flags"] == ["registration_rejected"]


def test_invalid_frame_keeps_nulls_and_its_flags() -> None:
    rec = FakeRecorder()
    msg = _publisher(rec, None).publish(_result(0, valid=False))
    assert msg is not None and msg["valid"] is False and msg["flags"] == ["no_gas"]
    assert msg["mean_velocity_m_s"] is None and msg["speed_m_s"] is None
    assert S.validate_json(S.SCENEFLOW_SUMMARY, json.loads(rec.topic("/sceneflow/summary")[0]
                                                           .payload)) == []


def test_failed_result_is_counted_not_published() -> None:
    rec, live = FakeRecorder(), FakeLive()
    pub = _publisher(rec, live)
    assert pub.publish(_result(0, error="ValueError: boom")) is None
    assert pub.errors == 1 and pub.published == 0 and rec.records == [] and live.items == []


def test_full_fields_every_nth_result() -> None:
    rec = FakeRecorder()
    pub = _publisher(rec, None, fields_every=3)
    for i in range(7):
        pub.publish(_result(i))
    assert len(rec.topic("/sceneflow/summary")) == 7
    field_topics = ("/sceneflow/flow", "/sceneflow/disparity", "/sceneflow/velocity",
                    "/sceneflow/mask", "/cam/left/diff", "/cam/right/diff")
    for topic in field_topics:
        assert len(rec.topic(topic)) == 2, topic  # results 3 and 6
    (first, _) = rec.topic("/sceneflow/velocity")
    arr, names, stamp = S.grid_to_array(first.payload)
    assert stamp == first.log_time
    assert names == ("vx", "vy", "vz") and arr.shape == (H, W, 3)
    np.testing.assert_array_equal(arr[0, 0], [1.0, 0.0, 1.0])
    assert first.publish_time == 10_000_000_000 + 3 * 33_333_333  # t1 of the third result
    d, dnames, _ = S.grid_to_array(rec.topic("/sceneflow/disparity")[0].payload)
    assert dnames == ("d", "d_change") and d[0, 0, 0] == 4.0


def test_wind_in_camera_frame_is_recorded_and_shown() -> None:
    rec, live = FakeRecorder(), FakeLive()
    _publisher(rec, live, wind_at=_wind((0.0, 0.0, 2.0))).publish(_result(0))
    (r,) = rec.topic("/wind/camera")
    msg = json.loads(r.payload)
    assert S.validate_json(S.WIND_CAMERA, msg) == []
    assert msg["velocity_m_s"] == [0.0, 0.0, 2.0] and msg["speed_m_s"] == 2.0
    assert msg["angles_deg"] == [90.0, 90.0, 0.0] and msg["interpolated"] is True
    (item,) = live.items
    assert item.wind_speed_m_s == 2.0 and item.wind_angles_deg == (90.0, 90.0, 0.0)
    assert item.gas_speed_m_s == pytest.approx(np.sqrt(2.0))
    assert item.frame == 1


@pytest.mark.parametrize("vector", [(1.0, float("nan"), 0.0), (float("inf"), 0.0, 0.0)])
def test_non_finite_wind_is_no_wind_record(vector: tuple[float, float, float]) -> None:
    rec, live = FakeRecorder(), FakeLive()
    _publisher(rec, live, wind_at=_wind(vector)).publish(_result(0))
    assert rec.topic("/wind/camera") == []
    assert live.items[0].wind_speed_m_s is None and live.items[0].wind_angles_deg is None


def test_wind_not_ok_is_no_wind_record() -> None:
    rec = FakeRecorder()
    stale = lambda t: WindAt(t, np.full(3, np.nan), "stale", 0, True)  # noqa: E731
    _publisher(rec, None, wind_at=stale).publish(_result(0))
    assert rec.topic("/wind/camera") == []


def test_truth_comparison_over_valid_frames_with_truth() -> None:
    truth = {0: np.array([1.0, 0.0, 1.0]), 1: np.array([1.0, 0.0, 1.0]), 2: None}
    pub = _publisher(None, None, truth_for=lambda i: truth.get(i))
    assert pub.truth_comparison() is None
    pub.publish(_result(0, velocity=(1.1, 0.0, 1.1)))  # 10 % too fast, same direction
    pub.publish(_result(1, velocity=(1.1, 0.0, 1.1)))
    pub.publish(_result(2, velocity=(9.0, 9.0, 9.0)))  # no truth (scene loop wraps): ignored
    pub.publish(_result(3, valid=False))  # invalid frame: ignored
    cmp = pub.truth_comparison()
    assert cmp is not None and cmp["frames"] == 2
    assert cmp["truth_m_s"] == [1.0, 0.0, 1.0]
    assert cmp["magnitude_error_pct"] == pytest.approx(10.0)
    assert cmp["direction_error_deg"] == pytest.approx(0.0, abs=1e-6)
    pub2 = _publisher(None, None, truth_for=lambda i: np.array([1.0, 0.0, 0.0]))
    pub2.publish(_result(0, velocity=(0.0, 0.0, 1.0)))
    assert pub2.truth_comparison()["direction_error_deg"] == pytest.approx(90.0)


def test_rate_window_restarts_at_a_segment_border() -> None:
    """Reprocessing runs a segment alone in a task; a replay runs them in turn. The emission
    window restarts with the segment so that both write the same window fields."""
    from processing.emission.rate import FrameRate

    rec = FakeRecorder()
    pub = _publisher(rec, None)
    for i in range(3):
        res = _result(i)
        res.rate = FrameRate(2.0 + i, (2.0 + i,), "")
        pub.publish(res)
    pub.restart_rate_window()
    res = _result(3)
    res.rate = FrameRate(7.0, (7.0,), "")
    pub.publish(res)
    frames = [json.loads(r.payload)["emission_window_frames"]
              for r in rec.topic("/sceneflow/summary")]
    rates = [json.loads(r.payload)["emission_window_rate_g_s"]
             for r in rec.topic("/sceneflow/summary")]
    assert frames == [1, 2, 3, 1] and rates[2] == pytest.approx(3.0) and rates[3] == 7.0


def test_operator_status_shows_the_summaries_rate_window() -> None:
    """One 30 s window: the status panel (and MQTT) report the rate the summaries carry,
    also after a frame without an estimate (emission.every) and a segment restart."""
    from appliance.runtime.events import EventConfig
    from appliance.runtime.monitor import LeakMonitor
    from processing.emission.rate import FrameRate

    rec = FakeRecorder()
    monitor = LeakMonitor(EventConfig(), (W, H))
    pub = _publisher(rec, None, monitor=monitor)
    for i, rate in enumerate((2.0, None, 4.0)):
        res = _result(i)
        res.rate = None if rate is None else FrameRate(rate, (rate,), "")
        pub.publish(res)
    window = json.loads(rec.topic("/sceneflow/summary")[-1].payload)
    assert window["emission_window_rate_g_s"] == pytest.approx(3.0)
    assert monitor.status().rate_kg_h == pytest.approx(3.0 * 3.6)
    pub.restart_rate_window()
    res = _result(3)
    res.rate = FrameRate(7.0, (7.0,), "")
    pub.publish(res)
    assert monitor.status().rate_kg_h == pytest.approx(7.0 * 3.6)


def test_a_rate_of_gas_moving_along_the_line_of_sight_is_flagged_everywhere() -> None:
    """The window's mean out-of-plane angle and its flag reach the summary (MCAP, export),
    the operator's panel and the final line of ``ogiflow run``."""
    from appliance.live.status import status_markdown
    from appliance.runtime.banner import line_of_sight_words
    from appliance.runtime.events import EventConfig
    from appliance.runtime.monitor import LeakMonitor
    from processing.emission.rate import FrameRate

    rec = FakeRecorder()
    monitor = LeakMonitor(EventConfig(), (W, H))
    pub = _publisher(rec, None, monitor=monitor)
    for i, angle in enumerate((20.0, 40.0)):
        res = _result(i)
        res.rate = FrameRate(2.0, (2.0,), "", out_of_plane_deg=angle)
        pub.publish(res)
    last = json.loads(rec.topic("/sceneflow/summary")[-1].payload)
    assert last["emission_window_out_of_plane_deg"] == pytest.approx(30.0)
    assert last["emission_window_flags"] == []
    assert line_of_sight_words(pub.rate_window.estimate()) == ""
    for i in range(2, 8):
        res = _result(i)
        res.rate = FrameRate(2.0, (2.0,), "", out_of_plane_deg=80.0)
        pub.publish(res)
    last = json.loads(rec.topic("/sceneflow/summary")[-1].payload)
    assert last["emission_window_out_of_plane_deg"] == pytest.approx((20 + 40 + 6 * 80) / 8)
    assert last["emission_window_flags"] == ["line_of_sight"]
    assert "line_of_sight" in monitor.status().rate_flags
    assert "line of sight" in status_markdown(monitor.status())
    assert "FLAGGED line_of_sight" in line_of_sight_words(pub.rate_window.estimate())


class _Flag:
    """Stands in for the pool's shared ``fields_wanted`` value."""

    def __init__(self) -> None:
        self.value = 0


class _PictureLive(FakeLive):
    def __init__(self, wants: bool) -> None:
        super().__init__()
        self.wants = wants

    def wants_pictures(self) -> bool:
        return self.wants


def _light(i: int) -> WorkerResult:
    """A result as a worker packs it when no fields were asked for."""
    res = _result(i)
    for name in ("diff_left", "diff_right", "flow", "disparity", "disparity_change",
                 "velocity", "valid", "raw_left"):
        setattr(res, name, None)
    return res


def test_fields_are_asked_for_when_due_and_recorded_from_the_next_result_carrying_them(
) -> None:
    rec, flag = FakeRecorder(), _Flag()
    pub = _publisher(rec, None, fields_every=3)
    pub.fields_wanted = flag
    pub.publish(_light(0))
    assert flag.value == 0  # 1 of 3
    pub.publish(_light(1))
    assert flag.value == 1  # the next one is due: ask the workers now
    flag.value = 0  # a worker took the request, but two light results were in flight
    pub.publish(_light(2))
    pub.publish(_light(3))
    assert rec.topic("/sceneflow/velocity") == []  # due, but nothing to record
    assert flag.value == 1  # still asking
    pub.publish(_result(4))  # the first result with fields
    assert len(rec.topic("/sceneflow/velocity")) == 1
    assert len(rec.topic("/sceneflow/summary")) == 5  # every result's summary all the same
    flag.value = 0
    pub.publish(_light(5))
    assert flag.value == 0  # 1 of 3 again


def test_light_results_feed_the_monitor_and_plots_and_pictures_are_asked_for() -> None:
    flag = _Flag()
    live = _PictureLive(wants=True)
    pub = _publisher(None, live, fields_every=1000)
    pub.fields_wanted = flag
    pub.publish(_light(0))
    frame = live.items[-1]
    assert not frame.has_pictures and frame.gas_mask is not None
    assert frame.gas_speed_m_s == pytest.approx(np.sqrt(2))
    assert flag.value == 1  # the live view is ready for a picture
    flag.value = 0
    live.wants = False
    pub.publish(_result(1))
    assert live.items[-1].has_pictures and flag.value == 0
