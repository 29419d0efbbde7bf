"""Rerun live view: .rrd output, blueprint, serve mode ports, and a stalled viewer never
stalling the producer."""

from __future__ import annotations

import dataclasses
import os
import socket
import subprocess
import sys
import textwrap
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from appliance.config import LiveConfig
from appliance.live.blueprint import blueprint
from appliance.live.colour import disparity_bgr, flow_bgr, to_u8
from appliance.live.status import OperatorStatus
from appliance.live.view import (
    LiveFrame,
    LiveScalars,
    LiveView,
    LiveViewError,
    health_scalars,
)
from appliance.runtime.health import HealthMonitor

ROOT = Path(__file__).resolve().parents[1]


def _cfg(**kw: object) -> LiveConfig:
    return dataclasses.replace(LiveConfig(), **kw)  # type: ignore[arg-type]


def _frame(i: int, rng: np.random.Generator) -> LiveFrame:
    return LiveFrame(
        frame=i, t_capture_ns=1_700_000_000_000_000_000 + i * 33_333_333,
        diff_left=rng.random((240, 320)), diff_right=rng.random((240, 320)).astype(np.float32),
        flow=rng.normal(size=(240, 320, 2)).astype(np.float32),
        disparity=np.where(rng.random((240, 320)) > 0.1, rng.random((240, 320)) * 30, np.nan),
        gas_mask=rng.random((240, 320)) > 0.7,
        points3d=rng.normal(size=(300, 3)) + np.array([0.0, 0.0, 8.0]),
        velocity3d=rng.normal(size=(300, 3)),
        gas_speed_m_s=1.0 + 0.01 * i, gas_angles_deg=(80.0, 95.0, 12.0),
        wind_speed_m_s=1.1, wind_angles_deg=(85.0, 90.0, float("nan")))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_save_mode_writes_a_verified_rrd(tmp_path: Path) -> None:
    path = tmp_path / "live" / "view.rrd"
    view = LiveView(_cfg(mode="save", file=path, queue_size=64)).start()
    assert view.url == str(path)
    rng = np.random.default_rng(0)
    mon = HealthMonitor()
    mon.stream("cam/left").tick()
    mon.count("skipped_pairs", 2)
    for i in range(10):
        assert view.push(_frame(i, rng))
    assert view.push(health_scalars(mon.snapshot()))
    assert view.push(LiveScalars(t_capture_ns=1, values={"bad": None, "x": 1.0}, prefix="misc"))
    assert view.close()
    st = view.stats()
    # Frames pushed faster than shown replace each other (the newest is shown); every item
    # is either shown or counted as dropped, and the last frame is never lost.
    assert st.pushed == 12 and st.errors == 0, st.last_error
    assert st.logged + st.dropped == 12 and st.logged >= 3
    result = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(path)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "verified without error" in result.stdout + result.stderr


def test_blueprint_names_every_view() -> None:
    origins: set[str] = set()

    def walk(node: object) -> None:
        if hasattr(node, "origin"):
            origins.add(str(node.origin))
            origins.add(str(node.contents))  # the 3D view names gas/velocity3d here
        elif getattr(node, "contents", None):
            for child in node.contents:
                walk(child)

    walk(blueprint().root_container)
    text = " ".join(sorted(origins))
    for origin in ("cam/left/diff", "cam/right/diff", "flow", "disparity", "gas/mask",
                   "gas/velocity3d", "plots/speed", "plots/angle/x", "plots/angle/y",
                   "plots/angle/z", "health"):
        assert origin in text, origin


def test_stalled_logging_never_blocks_the_producer(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    view = LiveView(_cfg(mode="save", file=tmp_path / "x.rrd", queue_size=8))
    gate = threading.Event()
    real_log = view._log

    def stuck(*args: object, **kwargs: object) -> None:  # a viewer that never reads
        gate.wait(60)
        real_log(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(view, "_log", stuck)
    view.start()
    rng = np.random.default_rng(1)
    item = _frame(0, rng)
    n = 5000
    results: list[bool] = []
    t = threading.Thread(target=lambda: results.extend(view.push(item) for _ in range(n)))
    t.start()
    t.join(30)  # bounded: the producer must finish although nothing is being logged
    assert not t.is_alive(), "push() blocked on a stalled viewer"
    st = view.stats()
    assert st.pushed == n == sum(results)  # frames replace each other: never refused
    assert st.logged == 0 and st.dropped >= n - 2  # one stuck in Rerun, one waiting
    assert not view.close(timeout=0.5)  # abandons the stuck thread instead of hanging
    gate.set()


STALLED_CHILD = textwrap.dedent("""
    import dataclasses, os, socket, sys, threading, time
    import numpy as np
    from appliance.config import LiveConfig
    from appliance.live.view import LiveFrame, LiveView
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    port = srv.getsockname()[1]
    conns = []
    threading.Thread(target=lambda: [conns.append(srv.accept()) for _ in range(8)],
                     daemon=True).start()  # accepts, never reads
    cfg = dataclasses.replace(LiveConfig(), mode="connect",
                              url=f"rerun+http://127.0.0.1:{port}/proxy", queue_size=8)
    view = LiveView(cfg).start()
    rng = np.random.default_rng(0)
    img = rng.random((240, 320))
    n = 3000
    done = threading.Event()
    def produce():
        for i in range(n):
            view.push(LiveFrame(frame=i, t_capture_ns=i, diff_left=img, diff_right=img,
                                gas_speed_m_s=1.0))
        done.set()
    t = threading.Thread(target=produce, daemon=True)
    t.start()
    t.join(60)
    st = view.stats()
    print("producer_done" if done.is_set() else "producer_blocked", st.pushed, st.dropped,
          st.logged, flush=True)
    view.close(timeout=0.5)
    os._exit(0)  # do not let Rerun's exit hook wait for the stalled peer
""")


def test_stalled_viewer_socket_never_blocks_the_producer() -> None:
    """A viewer endpoint that accepts the connection and never reads."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", STALLED_CHILD], capture_output=True,
                         text=True, env=env, timeout=180)
    words = out.stdout.split()
    assert words and words[0] == "producer_done", out.stdout + out.stderr
    pushed, dropped = int(words[1]), int(words[2])
    assert pushed == 3000 and dropped >= 2990


UNREACHABLE_CHILD = textwrap.dedent("""
    import dataclasses, os, sys, threading, time
    import numpy as np
    from appliance.config import LiveConfig
    from appliance.live.view import LiveFrame, LiveView
    port = int(sys.argv[1])  # nothing listens there: Rerun queues and retries
    cfg = dataclasses.replace(LiveConfig(), mode="connect",
                              url=f"rerun+http://127.0.0.1:{port}/proxy", queue_size=8)
    view = LiveView(cfg).start()
    rng = np.random.default_rng(0)
    img = rng.random((240, 320))
    for i in range(300):  # 10 s of frames at 30 Hz, sent in 3 s
        view.push(LiveFrame(frame=i, t_capture_ns=i, diff_left=img, diff_right=img,
                            gas_speed_m_s=1.0))
        time.sleep(0.01)
    st = view.stats()
    print(st.pushed, st.dropped, st.logged, st.slow_sends, flush=True)
    view.close(timeout=0.5)
    os._exit(0)  # do not let Rerun's exit hook wait for the viewer
""")


def test_unsent_frames_are_dropped_not_queued_inside_rerun() -> None:
    """A viewer that cannot take the stream: the live thread waits for each frame to be
    sent (at most DRAIN_TIMEOUT_S), so the frames arriving meanwhile are dropped and
    counted at push instead of piling up in Rerun's queue inside the daemon (measured
    before the wait: every frame logged, +220 MB in the daemon in a soak, and a displayed
    frame that fell further behind every second)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", UNREACHABLE_CHILD, str(_free_port())],
                         capture_output=True, text=True, env=env, timeout=120)
    words = out.stdout.split()
    assert len(words) == 4, out.stdout + out.stderr
    pushed, dropped, logged, slow = (int(w) for w in words)
    assert pushed == 300
    # Every frame shown waited for its send and timed out (nothing listens), so at most
    # the one in hand was not followed by a wait; the rest replaced each other.
    assert slow >= 1 and logged <= slow + 1, out.stdout
    assert dropped >= 280, out.stdout


def test_a_slow_viewer_sees_the_newest_frame_and_every_status(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames at 100 Hz, a status at 5 Hz, a live thread that needs 0.1 s per frame: each
    frame shown is the newest one pushed (a queue of 8 showed frames 0.8 s old and let
    the frames crowd out the status: the browser's "Newest frame" fell 25 -> 48 s behind)."""
    view = LiveView(_cfg(mode="save", file=tmp_path / "x.rrd"))
    shown_lag: list[int] = []
    statuses: list[int] = []
    newest = [0]

    def slow_frame(f: LiveFrame) -> None:
        shown_lag.append(newest[0] - f.frame)
        time.sleep(0.1)

    monkeypatch.setattr(view, "_log_frame", slow_frame)
    monkeypatch.setattr(view, "_log_status", lambda s: statuses.append(s.t_capture_ns))
    view.start()
    for i in range(200):
        newest[0] = i
        view.push(LiveFrame(frame=i, t_capture_ns=i))
        if i % 20 == 0:
            view.push(OperatorStatus(t_capture_ns=i))
        time.sleep(0.01)
    assert view.close()
    assert len(statuses) >= 9, statuses  # 10 pushed; at most the last one replaced
    assert len(shown_lag) >= 5 and max(shown_lag) <= 10, shown_lag  # queue of 8: ~80


def test_serve_mode_serves_and_frees_its_ports() -> None:
    grpc_port, web_port = _free_port(), _free_port()
    view = LiveView(_cfg(mode="serve", grpc_port=grpc_port, web_port=web_port)).start()
    try:
        assert view.url.startswith(f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp")
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as r:
            assert r.status == 200
        assert view.push(LiveScalars(t_capture_ns=1, values={"x": 1.0}))
        # A second appliance on the same ports fails clearly instead of silently.
        with pytest.raises(LiveViewError, match=f"live.grpc_port {grpc_port} on 127.0.0.1"):
            LiveView(_cfg(mode="serve", grpc_port=grpc_port, web_port=_free_port())).start()
    finally:
        view.close()
    with socket.socket() as s:  # the server is gone with the view
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", grpc_port))


def _environ_of(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode().split("=", 1) for item in raw if b"=" in item)


@pytest.mark.parametrize("preset", [None, "250"])
def test_rerun_allocator_returns_freed_memory_at_once(monkeypatch: pytest.MonkeyPatch,
                                                      preset: str | None) -> None:
    # mimalloc (inside the Rerun SDK and the viewer server) otherwise kept the memory of a
    # browser session for the rest of the run (appliance/memory.py); a site's value wins.
    monkeypatch.setenv("MIMALLOC_PURGE_DELAY", preset or "")  # restored after the test
    if preset is None:
        monkeypatch.delenv("MIMALLOC_PURGE_DELAY")
    view = LiveView(_cfg(mode="serve", grpc_port=_free_port(), web_port=_free_port())).start()
    try:
        assert view._server is not None
        server_env = _environ_of(view._server.process.pid)
    finally:
        view.close()
    expected = preset or "0"
    assert server_env.get("MIMALLOC_PURGE_DELAY") == expected
    assert os.environ.get("MIMALLOC_PURGE_DELAY") == expected  # this process's SDK


def test_busy_web_port_is_reported_before_starting() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        with pytest.raises(LiveViewError, match=f"live.web_port {port}"):
            LiveView(_cfg(mode="serve", grpc_port=_free_port(), web_port=port)).start()


def test_off_mode_does_nothing() -> None:
    view = LiveView(_cfg(mode="off")).start()
    assert not view.push(LiveScalars(t_capture_ns=1, values={}))
    assert view.close()
    assert view.stats().dropped == 0


def test_display_conversions() -> None:
    assert to_u8(np.array([[0.0, 0.5, 1.5]])).tolist() == [[0, 128, 255]]
    assert to_u8(np.array([[True, False]])).tolist() == [[255, 0]]
    assert to_u8(np.array([[100, 300]], np.uint16)).tolist() == [[0, 255]]
    flow = np.zeros((4, 4, 2), np.float32)
    flow[0, 0] = (3.0, 0.0)
    bgr = flow_bgr(flow)
    assert bgr.shape == (4, 4, 3) and bgr[1, 1].sum() == 0 and bgr[0, 0].max() == 255
    assert flow_bgr(flow, max_magnitude=6.0)[0, 0].max() == 127  # half the fixed scale
    assert flow_bgr(flow, max_magnitude=1.0)[0, 0].max() == 255  # saturates
    flow[1, 1] = np.nan
    assert flow_bgr(flow)[1, 1].sum() == 0  # NaN shows as no motion
    disp = np.array([[1.0, np.nan], [2.0, 3.0]])
    out = disparity_bgr(disp)
    assert out.shape == (2, 2, 3) and out[0, 1].sum() == 0


def test_a_frame_without_pictures_never_replaces_one_with_them(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Workers send the full fields only when asked (``worker_result.pack_result``): the one
    frame with pictures must reach the screen even when plot-only frames follow it."""
    view = LiveView(_cfg(mode="save", file=tmp_path / "x.rrd"), max_image_hz=1000.0)
    shown: list[tuple[int, bool]] = []
    gate = threading.Event()

    def slow_frame(f: LiveFrame) -> None:
        gate.wait(10)
        shown.append((f.frame, f.has_pictures))
        view._last_image_ns = time.monotonic_ns()  # what showing its pictures does

    monkeypatch.setattr(view, "_log_frame", slow_frame)
    view.start()
    img = np.zeros((4, 4), np.uint8)
    assert view.push(LiveFrame(frame=0, t_capture_ns=0))  # taken at once, waits in the gate
    time.sleep(0.2)
    assert view.wants_pictures()
    assert view.push(LiveFrame(frame=1, t_capture_ns=1, diff_left=img, raw_left=img))
    assert not view.wants_pictures()  # one is waiting
    assert not view.push(LiveFrame(frame=2, t_capture_ns=2))  # refused, counted
    assert view.stats().dropped == 1
    gate.set()
    deadline = time.monotonic() + 10
    while len(shown) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert view.close()
    assert shown == [(0, False), (1, True)]
