"""Health counters, snapshots (valid against the MCAP schema), reporter thread and systemd."""

from __future__ import annotations

import json
import logging
import socket
import time
from pathlib import Path

import pytest

from appliance.recording import schemas as S
from appliance.runtime.health import (
    HealthMonitor,
    HealthReporter,
    HealthSnapshot,
    StreamCounter,
    disk_free_source,
    log_sink,
    mcap_sink,
    status_line,
)
from appliance.runtime.sdnotify import SdNotifier, Watchdog


def test_rates_drops_latencies_counters_gauges(tmp_path: Path) -> None:
    now = [100.0]  # an injected clock: the rate is exact whatever the machine's load
    mon = HealthMonitor(stall_s=5.0, clock=lambda: now[0])
    left = mon.stream("cam/left")
    mon.snapshot()  # starts the rate interval
    for i in range(30):
        left.tick(now=100.0 + i * 0.01)
    left.drop(2)
    lat = mon.latency("processing")
    for ms in (10.0, 30.0):
        lat.add(ms)
    mon.count("skipped_pairs", 3)
    mon.add_counters(lambda: {"recorder_drops": 0, "serial_errors": 4})
    mon.add_gauges(lambda: {"ring_occupancy": 0.25, "broken": float("nan")})
    mon.add_gauges(disk_free_source(tmp_path / "not" / "yet"))
    now[0] = 100.5
    snap = mon.snapshot()
    s = snap.streams["cam/left"]
    assert s.count == 30 and s.drops == 2
    assert s.rate_hz == pytest.approx(60.0)  # 30 items in 0.5 s
    assert s.last_age_s == pytest.approx(0.5 - 0.29)
    assert snap.latencies["processing"] == {"count": 2, "mean_ms": 20.0, "max_ms": 30.0}
    assert snap.counters == {"skipped_pairs": 3, "recorder_drops": 0, "serial_errors": 4}
    assert snap.gauges["ring_occupancy"] == 0.25 and snap.gauges["broken"] is None
    assert snap.gauges["disk_free_gb"] is not None and snap.gauges["disk_free_gb"] > 0
    assert not snap.stalled
    # the interval resets: no new latencies -> None
    snap2 = mon.snapshot()
    assert snap2.latencies["processing"]["mean_ms"] is None
    assert S.validate_json(S.HEALTH, snap.to_dict()) == []
    S.encode_json(S.HEALTH, snap2.to_dict())  # encodes without error
    assert "cam/left" in status_line(snap)


def test_stream_rate_over_intervals() -> None:
    c = StreamCounter()
    c.rate(10.0)
    c.tick(30, now=10.5)
    assert c.rate(11.0) == 30.0
    c.tick(15, now=11.5)
    assert c.rate(13.0) == 7.5
    assert c.rate(13.0) == 0.0  # no time passed


def test_failing_source_does_not_break_snapshots() -> None:
    mon = HealthMonitor()

    def broken() -> dict[str, int]:
        raise RuntimeError("device gone")

    mon.add_counters(broken)
    mon.count("x")
    assert mon.snapshot().counters == {"x": 1}


def test_stall_detected_from_frame_streams() -> None:
    mon = HealthMonitor(stall_s=0.05)
    cam = mon.stream("cam/left")
    cam.tick()
    assert not mon.snapshot().stalled
    mon.stream("wind").tick()  # wind alone does not count as acquisition
    cam.last_mono = time.monotonic() - 1.0
    snap = mon.snapshot()
    assert snap.stalled
    assert status_line(snap).startswith("STALLED")


def test_log_sink_logs_periodically_and_on_stall_changes(
        caplog: pytest.LogCaptureFixture) -> None:
    sink = log_sink(logging.getLogger("test.health"), every=3)
    snaps = [HealthSnapshot(t_mono_ns=0, t_wall_ns=0, uptime_s=float(i), stalled=i in (4, 5))
             for i in range(7)]
    with caplog.at_level(logging.INFO, logger="test.health"):
        for snap in snaps:
            sink(snap)
    # snapshot 0 and 3 (every 3rd), 4 (stall begins: a warning), 6 (every 3rd, recovered)
    assert [r.levelname for r in caplog.records] == ["INFO", "INFO", "WARNING", "INFO"]
    assert caplog.records[2].getMessage() == "health: STALLED: no frames"


def test_mcap_sink_records_valid_health_json() -> None:
    got: list[tuple] = []

    class FakeRecorder:
        def record(self, *args: object) -> bool:
            got.append(args)
            return True

    mon = HealthMonitor()
    mon.stream("cam/left").tick()
    mcap_sink(FakeRecorder())(mon.snapshot())
    ((topic, schema, payload, log_time),) = got
    assert topic == "/health" and schema is S.HEALTH
    assert S.validate_json(S.HEALTH, json.loads(payload)) == []
    assert isinstance(log_time, int)


def test_reporter_feeds_sinks_status_and_watchdog(tmp_path: Path) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    addr = str(tmp_path / "n.sock")
    sock.bind(addr)
    sock.settimeout(5)
    notifier = SdNotifier(addr)
    wd = Watchdog(notifier, period_s=0.05, stall_s=60)
    mon = HealthMonitor()
    mon.stream("cam/left").tick()
    got: list[HealthSnapshot] = []

    def bad_sink(_: HealthSnapshot) -> None:
        raise OSError("disk full")

    rep = HealthReporter(mon, 0.05, [bad_sink, got.append], notifier, wd).start()
    messages = set()
    deadline = time.monotonic() + 10
    while not {"WATCHDOG=1", "STATUS"} <= messages and time.monotonic() < deadline:
        msg = sock.recv(4096).decode()
        messages.add(msg.split("=")[0] if msg.startswith("STATUS=") else msg)
    rep.stop()
    sock.close()
    assert {"WATCHDOG=1", "STATUS"} <= messages
    assert got and isinstance(got[0], HealthSnapshot)
