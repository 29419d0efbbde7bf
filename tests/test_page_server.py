"""The operator's page server on its own: routes, bad requests, per-client queues, a busy
port, and the status JSON (the whole-daemon and browser checks are in test_page_browser)."""

from __future__ import annotations

import http.client
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from appliance.config import ConfigError, load_config
from appliance.live.items import LiveFrame
from appliance.live.status import OperatorStatus
from appliance.page.hub import FRAMES_KEPT, PageHub
from appliance.page.server import PageServer

ROOT = Path(__file__).resolve().parents[1]


def _frame(i: int, t_ns: int) -> LiveFrame:
    rng = np.random.default_rng(i)
    raw = rng.integers(1000, 3000, (48, 64), dtype=np.uint16)
    mask = np.zeros((48, 64), bool)
    mask[10:20, 30:50] = True
    pix = np.array([[35.0, 15.0], [40.0, 12.0]])
    vel = np.array([[1.0, -0.5, 0.2], [0.8, -0.4, 0.1]])
    return LiveFrame(frame=i, t_capture_ns=t_ns, raw_left=raw, gas_mask=mask, pixels=pix,
                     velocity3d=vel, raw_capture_ns=t_ns - 33_000_000)


def _wait(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


@pytest.fixture
def served() -> Iterator[tuple[PageServer, PageHub]]:
    cfg = load_config(None, [("live.page.port", 0)]).live.page
    hub = PageHub(max_image_hz=1000.0, jpeg_quality=80).start()
    server = PageServer(cfg, hub, metrics=lambda: (b"ogiflow_up 1\n", "text/plain")).start()
    yield server, hub
    server.close()
    hub.close()


def _get(server: PageServer, path: str, method: str = "GET", **kw) -> tuple[int, bytes, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    conn.request(method, path, **kw)
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, body, dict(r.getheaders())


def _raw(server: PageServer, data: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
        s.sendall(data)
        return s.recv(4096)


def test_page_status_and_frames_are_served(served) -> None:
    server, hub = served
    status, body, headers = _get(server, "/")
    assert status == 200 and b'data-testid="leak-state"' in body
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    for path in ("/page.js", "/page.css"):
        assert _get(server, path)[0] == 200
    s = json.loads(_get(server, "/status.json")[1])
    assert s["leak"]["state"] == "NO LEAK" and s["newest_frame"] is None
    t0 = time.time_ns()
    hub.push(OperatorStatus(t_capture_ns=t0, leak={"id": 3, "start_t_s": t0 / 1e9 - 75,
                                                    "source_xy": (40.0, 15.0)},
                            rate_kg_h=float("nan"), wind_m_s=(1.0, 0.0, 0.5),
                            health=["all devices delivering"],
                            health_snapshot={"streams": {"cam/left": {"rate_hz": 30.0}}}))
    assert hub.push(_frame(1, t0))
    _wait(lambda: hub.newest_frame() is not None)
    s = json.loads(_get(server, "/status.json")[1])
    assert s["leak"]["state"] == "LEAK" and s["leak"]["event"]["id"] == 3
    assert s["leak"]["words"] == "LEAK for 1 min 15 s"
    assert s["rate"]["kg_h"] is None  # NaN is no JSON: null
    assert s["health"]["snapshot"]["streams"]["cam/left"]["rate_hz"] == 30.0
    assert s["wind"]["speed_m_s"] == pytest.approx(np.hypot(1.0, 0.5))
    f = s["newest_frame"]
    assert f["t_capture_ns"] == t0 - 33_000_000 and (f["width"], f["height"]) == (64, 48)
    status, jpg, headers = _get(server, f["url"])
    assert status == 200 and jpg[:2] == b"\xff\xd8" and headers["Content-Type"] == "image/jpeg"
    assert headers["X-Capture-Time-Ns"] == str(f["t_capture_ns"])
    for i in range(2, FRAMES_KEPT + 3):  # older pictures are forgotten
        hub.push(_frame(i, t0 + i))
        _wait(lambda i=i: hub.newest_frame().frame == i)
    assert _get(server, f["url"])[0] == 404
    assert _get(server, "/metrics")[1] == b"ogiflow_up 1\n"


def test_bad_requests_are_rejected(served) -> None:
    server, _hub = served
    assert _get(server, "/nothing/here")[0] == 404
    assert _get(server, "/frame/../status.json")[0] == 404
    assert _get(server, "/frame/abc.jpg")[0] == 404
    assert _get(server, "/status.json", method="POST", body=b"{}")[0] == 405
    assert _get(server, "/status.json", method="PUT", body=b"x")[0] == 405
    assert _get(server, "/status.json", headers={"X-Big": "a" * 10_000})[0] == 400
    many = {f"X-H{i}": "1" for i in range(40)}
    assert _get(server, "/status.json", headers=many)[0] == 400
    assert _get(server, "/", headers={"Content-Length": "100000"})[0] == 413
    assert b" 400 " in _raw(server, b"GET /" + b"a" * 10_000 + b" HTTP/1.1\r\nHost: x\r\n\r\n")
    assert b" 400 " in _raw(server, b"\x16\x03\x01 not http at all\r\n\r\n")
    assert b" 400 " in _raw(server, b"GET / HTTP/1.1\r\nHost x\r\n\r\n")
    assert _get(server, "/status.json")[0] == 200  # still serving
    assert server.stats().bad_requests >= 5  # counted, not logged one by one


def _read_events(resp: http.client.HTTPResponse, n: int) -> list[tuple[str, dict]]:
    out, kind = [], None
    while len(out) < n:
        line = resp.readline().decode().rstrip("\n")
        if line.startswith("event: "):
            kind = line[7:]
        elif line.startswith("data: "):
            out.append((kind, json.loads(line[6:])))
    return out


def test_a_stalled_client_drops_for_itself_only(served) -> None:
    server, hub = served
    t0 = time.time_ns()
    hub.push(_frame(0, t0))
    _wait(lambda: hub.newest_frame() is not None)
    stalled = socket.socket()
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
    stalled.connect(("127.0.0.1", server.port))
    stalled.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    conn.request("GET", "/events")
    resp = conn.getresponse()
    assert resp.status == 200 and resp.headers["Content-Type"] == "text/event-stream"
    first = _read_events(resp, 2)  # at once: the status and the newest picture
    assert [k for k, _ in first] == ["status", "frame"] and first[1][1]["frame"] == 0
    _wait(lambda: server.stats().clients == 2)
    frames: list[int] = []

    def read() -> None:  # a browser that keeps reading
        try:
            while True:
                frames.extend(m["frame"] for k, m in _read_events(resp, 1) if k == "frame")
        except (OSError, ValueError, http.client.HTTPException):
            return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    # 12 MB of status messages, far more than the stalled socket's buffers take
    big = ["x" * 40_000]
    for i in range(300):
        n = hub.stats().statuses
        hub.push(OperatorStatus(t_capture_ns=t0 + i, health=big))
        _wait(lambda n=n: hub.stats().statuses > n)
    for i in range(1, 101):  # then pictures one by one: the reading client misses none
        hub.push(_frame(i, t0 + i))
        _wait(lambda i=i: frames and frames[-1] == i)
    assert frames[-100:] == list(range(1, 101))
    stats = server.stats()
    assert stats.client_drops > 150 and stats.queue_depth <= 2  # the stalled one's, bounded
    conn.close()
    stalled.close()
    _wait(lambda: server.stats().clients == 0)


def test_a_busy_port_is_a_configuration_error(tmp_path: Path) -> None:
    busy = socket.create_server(("127.0.0.1", 0))
    port = busy.getsockname()[1]
    try:
        cfg = load_config(None, [("live.page.port", port)]).live.page
        hub = PageHub()
        with pytest.raises(ConfigError, match=f"live.page.port: {port} on 127.0.0.1"):
            PageServer(cfg, hub).start()
        # the daemon: exit 2 before any device opens (no recording folder, no scene)
        rec = tmp_path / "rec"
        out = subprocess.run([sys.executable, "-m", "appliance", "run", "--duration", "5",
                              "--live", "off", "--record-dir", str(rec), "--set",
                              f"live.page.port={port}", "--set",
                              f"simulation.cache_dir={tmp_path / 'cache'}"],
                             cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert out.returncode == 2, out.stderr[-2000:]
        assert "live.page.port" in out.stderr and not rec.exists()
        assert not (tmp_path / "cache").exists()
    finally:
        busy.close()


def test_page_settings_are_checked() -> None:
    for bad in (("live.page.bind", "not-an-address"), ("live.page.port", 70000),
                ("live.page.max_image_hz", 0)):
        with pytest.raises(ConfigError, match=bad[0].replace(".", r"\.")):
            load_config(None, [bad])
    with pytest.raises(ConfigError, match="Rerun viewer's port"):
        load_config(None, [("live.page.port", 9090)])
    assert load_config(None, [("live.page.enabled", False), ("live.page.port", 9090)])

