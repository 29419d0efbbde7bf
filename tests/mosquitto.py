"""A real MQTT broker for tests: Debian's ``mosquitto`` on 127.0.0.1 and a free port.

Needs the Debian package ``mosquitto`` (``tools/install.sh --dev`` installs it); a test that
uses :func:`broker` fails, not skips, when it is missing.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Broker:
    """mosquitto listening on 127.0.0.1:``port``; ``start``/``stop`` may repeat (outages)."""

    def __init__(self, directory: Path, port: int | None = None) -> None:
        if not Path(MOSQUITTO).exists():
            raise RuntimeError("mosquitto not found: install the Debian package 'mosquitto' "
                               "(tools/install.sh --dev)")
        self.port = port or free_port()
        self.conf = directory / "mosquitto.conf"
        self.conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\n"
                             "persistence false\n")
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout: float = 10.0) -> Broker:
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return self
            except OSError:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"mosquitto exited with {self.proc.returncode}") from None
                time.sleep(0.05)
        self.stop()
        raise RuntimeError(f"mosquitto did not listen on port {self.port} in {timeout} s")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)
        self.proc = None


class Subscriber:
    """Collects every message under a topic filter (paho, its own network thread)."""

    def __init__(self, port: int, topic: str) -> None:
        import paho.mqtt.client as mqtt

        self.messages: list[tuple[str, bytes, bool]] = []
        #: UNIX time at which each of :attr:`messages` arrived.
        self.arrived: list[float] = []
        subscribed = threading.Event()
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-sub")

        def on_message(c, u, m) -> None:
            self.arrived.append(time.time())
            self.messages.append((m.topic, m.payload, bool(m.retain)))

        self._client.on_message = on_message
        self._client.on_connect = lambda c, u, f, rc, p: c.subscribe(topic, qos=1)
        self._client.on_subscribe = lambda c, u, mid, rcs, p: subscribed.set()
        self._client.connect("127.0.0.1", port)
        self._client.loop_start()
        if not subscribed.wait(10.0):  # a message published before this would be missed
            self.close()
            raise RuntimeError(f"no SUBACK from the broker on port {port} in 10 s")

    def wait_for(self, predicate, timeout: float = 10.0) -> list[tuple[str, bytes, bool]]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hits = [m for m in list(self.messages) if predicate(m)]
            if hits:
                return hits
            time.sleep(0.02)
        raise AssertionError(f"no matching message in {timeout} s; got {self.messages[-5:]}")

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()
