"""MQTT alarms against a real broker (Debian's mosquitto on 127.0.0.1, a free port)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from appliance.alarms.mqtt import MqttConfig, MqttSink
from tests.mosquitto import Broker, Subscriber, free_port


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    b = Broker(tmp_path).start()
    yield b
    b.stop()


def _json(m: tuple[str, bytes, bool]) -> dict:
    return json.loads(m[1])


def test_status_events_and_summaries_arrive(broker: Broker) -> None:
    sub = Subscriber(broker.port, "site/#")
    sink = MqttSink(MqttConfig(port=broker.port, topic_prefix="site",
                               summary_interval_s=0.0)).start()
    try:
        sink.status({"health": "ok"})
        sink.event("start", {"id": 1, "t_wall_ns": 10**18, "start_t_s": 1e9,
                             "rate_kg_h": 2.5})
        for k in range(5):  # frames of the event with nothing new: held back
            sink.event("update", {"id": 1, "t_wall_ns": 10**18 + k * 10**8,
                                  "start_t_s": 1e9, "rate_kg_h": 2.5})
        sink.summary({"speed_m_s": 1.2})
        sink.event("end", {"id": 1, "t_wall_ns": 10**18 + 10**9, "start_t_s": 1e9,
                           "end_t_s": 1e9 + 0.9, "end_reason": "gas gone"})
        status = sub.wait_for(lambda m: m[0] == "site/status")
        assert _json(status[0])["state"] == "online"
        ends = sub.wait_for(lambda m: m[0] == "site/event" and _json(m)["type"] == "end")
        kinds = [_json(m)["type"] for m in sub.messages if m[0] == "site/event"]
        assert kinds == ["new", "end"] and _json(ends[0])["id"] == 1
        assert _json(ends[0])["duration_s"] == pytest.approx(0.9)
        sub.wait_for(lambda m: m[0] == "site/summary" and _json(m)["speed_m_s"] == 1.2)
        assert sink.stats().connected and sink.stats().dropped == 0
    finally:
        sink.close()
        sub.close()
    # The goodbye is retained: a dashboard connecting later sees "offline".
    late = Subscriber(broker.port, "site/status")
    try:
        msg = late.wait_for(lambda m: m[2])  # retained
        assert _json(msg[0])["state"] == "offline" and _json(msg[0])["reason"] == "stopped"
    finally:
        late.close()


def test_last_will_says_offline_when_the_appliance_dies(broker: Broker) -> None:
    code = textwrap.dedent(f"""
        import time
        from appliance.alarms.mqtt import MqttConfig, MqttSink
        s = MqttSink(MqttConfig(port={broker.port}, topic_prefix="dies", client_id="dies"))
        s.start(); s.status({{"health": "ok"}})
        print("up", flush=True); time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            cwd=Path(__file__).resolve().parents[1])
    sub = Subscriber(broker.port, "dies/status")
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"up"
        sub.wait_for(lambda m: _json(m)["state"] == "online")
        proc.kill()
        offline = sub.wait_for(lambda m: _json(m)["state"] == "offline")
        assert _json(offline[0])["reason"] == "connection lost"
    finally:
        proc.kill()
        proc.wait(timeout=5)
        sub.close()


def test_broker_down_never_blocks_and_messages_resume(tmp_path: Path) -> None:
    port = free_port()
    broker = Broker(tmp_path, port)
    sink = MqttSink(MqttConfig(port=port, topic_prefix="out", queue_size=50)).start()
    try:
        t0 = time.monotonic()
        for k in range(200):  # the broker is down: every call returns at once
            sink.event("start", {"id": 100 + k})
        assert time.monotonic() - t0 < 1.0
        s = sink.stats()
        assert not s.connected and s.queued == 50 and s.dropped == 150
        broker.start()
        sub = Subscriber(port, "out/#")
        sink.event("start", {"id": 2})
        sub.wait_for(lambda m: _json(m).get("id") == 2, timeout=40)
        assert sink.stats().connected and sink.stats().outage_s > 0
        # Broker killed mid-run, back after 3 s: the outage is counted, messages resume.
        broker.stop()
        time.sleep(3.0)
        sink.event("start", {"id": 3})  # queued during the outage
        assert sink.stats().disconnects == 1 and not sink.stats().connected
        published = sink.stats().published
        broker.start()
        sub.close()
        sub = Subscriber(port, "out/#")
        sink.event("start", {"id": 4})
        sub.wait_for(lambda m: _json(m).get("id") == 4, timeout=40)
        s = sink.stats()
        # id 3 went out before id 4 (the queue is FIFO), whoever was subscribed then.
        assert s.published >= published + 2 and s.queued == 0 and s.outage_s >= 3.0
        sub.close()
    finally:
        sink.close(timeout=0.5)
        broker.stop()
