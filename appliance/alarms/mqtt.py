"""Alarms over MQTT (paho-mqtt): status, leak events and 1 Hz summaries for the plant.

Topics under ``<prefix>``:

- ``<prefix>/status``: retained, QoS 1. ``{"state": "online", "health": {...}}`` while the
  appliance runs; the broker publishes the last will ``{"state": "offline"}`` when the
  connection dies without a goodbye (power loss, crash), so a dashboard sees a dead box;
- ``<prefix>/event``: QoS 1, ``{"type": "new" | "update" | "end", "id": ...}`` per leak event:
  ``new`` when it opens, ``update`` only when its state, source or rate class changed (at
  most once per ``update_s``), ``end`` with the final figures
  (:mod:`appliance.alarms.throttle`; payloads in docs/operator-page.md);
- ``<prefix>/summary``: QoS 0, the latest per-frame summary, at most once a second.

The daemon must never wait for a broker. Every public method only appends to a bounded
queue in memory and returns; a sender thread publishes while connected (paho's own network
thread, ``loop_start``, reconnects with back-off). When the broker is down or unreachable,
events and status wait in the queue (oldest dropped and counted when it is full), summaries
keep only the newest few, and the outage is counted for the health report.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from appliance.alarms.sink import AlarmSink, SinkStats
from appliance.alarms.throttle import EventThrottle
from appliance.threads import NamedThread

log = logging.getLogger("ogiflow.alarms")


@dataclass(frozen=True)
class MqttConfig:
    """Config section ``alarms.mqtt``.

    Attributes
    ----------
    host, port : str, int
        Broker address.
    topic_prefix : str
        Topics are ``<prefix>/status``, ``<prefix>/event``, ``<prefix>/summary``.
    client_id : str
        MQTT client id (unique per appliance on the broker).
    keepalive_s : int
        MQTT keep-alive; the broker declares the appliance offline after 1.5 x this
        without traffic.
    tls : bool
        Connect with TLS (``ca_file`` or the system's CAs; optional client certificate).
    ca_file, cert_file, key_file : Path or None
        TLS files.
    username : str or None
        Broker user; the password is read from ``password_file`` (kept out of the config).
    password_file : Path or None
    queue_size : int
        Events and status messages kept while the broker is unreachable.
    summary_interval_s : float
        Least time between two summaries.
    update_s : float
        Least time between two messages of one leak event (frame time), s.
    """

    host: str = "127.0.0.1"
    port: int = 1883
    topic_prefix: str = "ogiflow"
    client_id: str = "ogiflow"
    keepalive_s: int = 30
    tls: bool = False
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None
    username: str | None = None
    password_file: Path | None = None
    queue_size: int = 1000
    summary_interval_s: float = 1.0
    update_s: float = 1.0


def _payload(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, separators=(",", ":"), default=str).encode()


class MqttSink(AlarmSink):
    """Publishes status, events and summaries to an MQTT broker without ever blocking.

    Parameters
    ----------
    cfg : MqttConfig
    """

    def __init__(self, cfg: MqttConfig) -> None:
        self.cfg = cfg
        self._events: collections.deque[tuple[str, bytes, int, bool]] = collections.deque()
        self._summaries: collections.deque[bytes] = collections.deque(maxlen=5)
        self._cond = threading.Condition()
        self._stop = False
        self._connected = False
        self._stats = SinkStats()
        self._down_since: float | None = time.monotonic()
        self._last_summary = 0.0
        self._status: bytes | None = None
        self.throttle = EventThrottle(cfg.update_s)
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=cfg.client_id,
                        protocol=mqtt.MQTTv311)
        c.will_set(self.topic("status"), _payload({"state": "offline",
                                                    "reason": "connection lost"}),
                   qos=1, retain=True)
        if cfg.username is not None:
            password = (cfg.password_file.read_text().strip()
                        if cfg.password_file is not None else None)
            c.username_pw_set(cfg.username, password)
        if cfg.tls:
            c.tls_set(ca_certs=str(cfg.ca_file) if cfg.ca_file else None,
                      certfile=str(cfg.cert_file) if cfg.cert_file else None,
                      keyfile=str(cfg.key_file) if cfg.key_file else None)
        c.reconnect_delay_set(min_delay=1, max_delay=30)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        self._client = c
        self._sender = NamedThread(target=self._send_loop, name="mqtt-sender",
                                   daemon=True)

    def topic(self, name: str) -> str:
        return f"{self.cfg.topic_prefix}/{name}"

    # ------------------------------------------------------------------ life cycle

    def start(self) -> MqttSink:
        """Connect in the background (a broker that is down is retried, never waited for)."""
        self._client.connect_async(self.cfg.host, self.cfg.port, keepalive=self.cfg.keepalive_s)
        self._client.loop_start()
        self._sender.start()
        return self

    def close(self, timeout: float = 2.0) -> None:
        """Say goodbye (retained ``offline``), flush briefly, disconnect."""
        self._enqueue(self.topic("status"), _payload({"state": "offline",
                                                       "reason": "stopped"}), 1, True)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self._connected and self._events:
            time.sleep(0.02)
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._sender.join(timeout=1.0)
        try:
            self._client.disconnect()
        finally:
            self._client.loop_stop()

    # ------------------------------------------------------------------ AlarmSink

    def status(self, status: dict[str, Any]) -> None:
        payload = _payload({"state": "online", **status})
        self._status = payload
        self._enqueue(self.topic("status"), payload, 1, True)

    def event(self, kind: str, event: dict[str, Any]) -> None:
        msg = self.throttle.offer(kind, event)
        if msg is not None:
            self._enqueue(self.topic("event"), _payload(msg), 1, False)

    def summary(self, summary: dict[str, Any]) -> None:
        now = time.monotonic()
        if now - self._last_summary < self.cfg.summary_interval_s:
            return
        self._last_summary = now
        with self._cond:
            if len(self._summaries) == self._summaries.maxlen:
                self._stats.dropped += 1
            self._summaries.append(_payload(summary))
            self._cond.notify()

    def stats(self) -> SinkStats:
        s = self._stats
        down = 0.0 if self._down_since is None else time.monotonic() - self._down_since
        return SinkStats(connected=self._connected, published=s.published, dropped=s.dropped,
                         queued=len(self._events) + len(self._summaries),
                         disconnects=s.disconnects, outage_s=s.outage_s + down)

    # ------------------------------------------------------------------ internals

    def _enqueue(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        with self._cond:
            if len(self._events) >= self.cfg.queue_size:
                self._events.popleft()
                self._stats.dropped += 1
            self._events.append((topic, payload, qos, retain))
            self._cond.notify()

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason_code: Any,
                    properties: Any) -> None:
        if getattr(reason_code, "is_failure", False):
            log.warning("MQTT broker %s:%d refused the connection: %s", self.cfg.host,
                        self.cfg.port, reason_code)
            return
        with self._cond:
            self._connected = True
            if self._down_since is not None:
                self._stats.outage_s += time.monotonic() - self._down_since
                self._down_since = None
            if self._status is not None:  # the retained status again, e.g. after a restart
                self._events.appendleft((self.topic("status"), self._status, 1, True))
            self._cond.notify_all()
        log.info("MQTT connected to %s:%d", self.cfg.host, self.cfg.port)

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason_code: Any,
                       properties: Any) -> None:
        with self._cond:
            if self._connected:
                self._stats.disconnects += 1
                self._down_since = time.monotonic()
            self._connected = False
        log.warning("MQTT disconnected from %s:%d (%s); messages are queued",
                    self.cfg.host, self.cfg.port, reason_code)

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._stop and not (self._connected and
                                              (self._events or self._summaries)):
                    self._cond.wait(0.5)
                if self._stop:
                    return
                if self._events:
                    topic, payload, qos, retain = self._events.popleft()
                else:
                    topic, payload, qos, retain = (self.topic("summary"),
                                                   self._summaries.popleft(), 0, False)
            info = self._client.publish(topic, payload, qos=qos, retain=retain)
            if info.rc == 0:
                self._stats.published += 1
            else:  # lost the connection meanwhile: put it back, wait for the reconnect
                with self._cond:
                    if topic.endswith("/summary"):
                        self._stats.dropped += 1
                    else:
                        self._events.appendleft((topic, payload, qos, retain))
                    self._connected = self._client.is_connected()
                time.sleep(0.05)
