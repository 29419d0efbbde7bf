"""MQTT alarms from the running daemon: a broker outage loses no frame and is counted.

Needs Debian's mosquitto (tools/install.sh --dev).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

from appliance.config import load_config
from appliance.runtime.daemon import Appliance
from tests.conftest import SMALL_SCENE
from tests.mosquitto import Broker, Subscriber


def test_broker_outage_mid_run_loses_no_frame(tmp_path: Path, scene_cache: Path) -> None:
    broker = Broker(tmp_path).start()
    sub = Subscriber(broker.port, "site/#")
    cfg = load_config(None, [
        *SMALL_SCENE, ("simulation.cache_dir", str(scene_cache)),
        ("recording.dir", str(tmp_path / "rec")), ("live.mode", "off"),
        ("alarms.mqtt.enabled", True), ("alarms.mqtt.port", broker.port),
        ("alarms.mqtt.topic_prefix", "site"), ("health.interval_s", 0.5)])
    app = Appliance(cfg, duration_s=240.0)
    report: dict = {}

    def outage() -> None:
        try:
            sub.wait_for(lambda m: m[0] == "site/status", timeout=120)
            broker.stop()
            t_kill = time.monotonic()
            time.sleep(5.0)
            report["counted"] = app._health_counters().get("alarm_disconnects", 0)
            broker.start()
            sub2 = Subscriber(broker.port, "site/#")
            sub2.wait_for(lambda m: m[0] == "site/status"
                          and json.loads(m[1])["state"] == "online", timeout=60)
            report["resumed_after_s"] = time.monotonic() - t_kill
            sub2.close()
        finally:
            app.stop_event.set()

    threading.Thread(target=outage, daemon=True).start()
    try:
        assert app.run() == 0
    finally:
        sub.close()
        broker.stop()
    c = app.counters
    assert report.get("counted") == 1 and report["resumed_after_s"] < 60
    assert c.frames_lost["left"] == c.frames_lost["right"] == 0
    assert c.frames["left"] > 100
    assert app.recorder.stats().messages_dropped == 0
