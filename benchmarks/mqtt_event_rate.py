"""Event messages per second of leak event in a default run, against Debian's mosquitto.

Runs ``ogiflow run --duration S`` with the default configuration (MQTT on, to a broker on
127.0.0.1 and a free port), counts the messages on ``<prefix>/event`` by event and type and
divides by the events' durations; prints one JSON line::

    python -m benchmarks.mqtt_event_rate --duration 90
"""

from __future__ import annotations

import argparse
import collections
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.mosquitto import Broker, Subscriber

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=90.0)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        broker = Broker(Path(tmp)).start()
        sub = Subscriber(broker.port, "ogiflow/#")
        try:
            run = subprocess.run(
                [sys.executable, "-m", "appliance", "run", "--duration", str(args.duration),
                 "--live", "off", "--record-dir", str(Path(tmp) / "rec"), "--log-level",
                 "WARNING", "--set", "live.page.port=0", "--set", "alarms.mqtt.enabled=true",
                 "--set", f"alarms.mqtt.port={broker.port}"],
                cwd=ROOT, capture_output=True, text=True, check=False)
            time.sleep(2.0)
        finally:
            sub.close()
            broker.stop()
    topics = collections.Counter(t for t, _p, _r in sub.messages)
    events: dict[int, list[dict]] = collections.defaultdict(list)
    for t, payload, _r in sub.messages:
        if t == "ogiflow/event":
            m = json.loads(payload)
            events[m["id"]].append(m)
    per_event = []
    for eid, msgs in events.items():
        dur = msgs[-1].get("duration_s") or 0.0
        per_event.append({"id": eid, "messages": len(msgs),
                          "types": dict(collections.Counter(m["type"] for m in msgs)),
                          "duration_s": round(dur, 1),
                          "per_s": round(len(msgs) / dur, 3) if dur else None})
    final = [x for x in run.stderr.splitlines() if x.startswith("ogiflow: stopped.")]
    print(json.dumps({"exit": run.returncode, "topics": dict(topics), "events": per_event,
                      "final": final[-1] if final else run.stderr[-500:]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
