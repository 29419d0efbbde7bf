"""Faults injected into the whole running daemon (simulated devices, small scene).

Each test runs :class:`Appliance` in this thread while a controller thread injects one fault
and stops the run once the appliance has come back (bounded waits on counters, never fixed
sleeps for the outcome). Printed figures (``-s``) are the ones in docs/operation.md.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import signal
import subprocess
import sys
import termios
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from appliance.config import load_config
from appliance.recording.reader import LogReader, iter_json
from appliance.recording.recorder import closed_files, unfinished_files
from appliance.runtime.daemon import Appliance
from appliance.runtime.health import status_line
from tests.conftest import SMALL_SCENE

ROOT = Path(__file__).resolve().parent.parent


def make_app(cache: Path, rec: Path, *extra: tuple[str, Any]) -> Appliance:
    cfg = load_config(None, [*SMALL_SCENE, ("simulation.cache_dir", str(cache)),
                             ("recording.dir", str(rec)), ("live.mode", "off"),
                             ("processing.enabled", False), ("health.interval_s", 0.2),
                             *extra])
    return Appliance(cfg, duration_s=300.0)


def wait_for(app: Appliance, cond: Callable[[], bool], what: str, timeout_s: float = 60.0
             ) -> float:
    """Wait (in the controller thread) until ``cond()``; returns the monotonic time it held."""
    t_end = time.monotonic() + timeout_s
    while not cond():
        if app.stop_event.is_set():
            raise AssertionError(f"the run ended before: {what}")
        if time.monotonic() > t_end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for: {what}")
        time.sleep(0.02)
    return time.monotonic()


def run_with(app: Appliance, scenario: Callable[[], None]) -> dict[str, Any]:
    """Run ``app`` here while ``scenario`` runs in a thread; stop when it returns."""
    out: dict[str, Any] = {}

    def control() -> None:
        try:
            scenario()
        except BaseException as exc:  # reported by the test thread
            out["error"] = exc
        finally:
            app.stop_event.set()

    t = threading.Thread(target=control, daemon=True)
    t.start()
    out["code"] = app.run()
    t.join(10)
    if "error" in out:
        raise out["error"]
    return out


def recorded_topics(rec: Path) -> Counter[str]:
    assert unfinished_files(rec) == []
    counts: Counter[str] = Counter()
    for path in closed_files(rec):
        reader = LogReader(path)
        counts.update(t for t, *_ in reader)
        assert not reader.truncated
    return counts


def test_camera_outage_loses_only_its_frames(scene_cache: Path, tmp_path: Path) -> None:
    """The left camera vanishes for 3 s and returns: the right camera and the recording go
    on, health names the outage, and only the outage's frames (plus the reconnection
    delay, printed) are missing."""
    outage_s = 3.0
    app = make_app(scene_cache, tmp_path / "rec",
                   ("cameras.left.options", {"outage_after_s": 2.0, "outage_s": outage_s,
                                             "label": f"left-{tmp_path.name}"}))
    c = app.counters
    seen: dict[str, Any] = {}

    def scenario() -> None:
        wait_for(app, lambda: c.camera_reconnects >= 1, "the outage to begin", 120)
        t_begin = time.monotonic()
        wait_for(app, lambda: "cam/left SILENT" in status_line(app.health.snapshot()),
                 "health to name the silent camera")
        right_before = c.frames["right"]
        left_before = c.frames["left"]
        t_back = wait_for(app, lambda: c.frames["left"] > left_before, "the camera's return")
        seen["recovery_s"] = t_back - t_begin - outage_s
        seen["right_during"] = c.frames["right"] - right_before
        wait_for(app, lambda: c.frames["left"] > left_before + 60, "frames after the return")

    assert run_with(app, scenario)["code"] == 0
    lost = c.frames_lost
    print(f"camera outage {outage_s} s: left frames lost {lost['left']} "
          f"({lost['left'] / 30:.2f} s at 30 Hz), right lost {lost['right']}, "
          f"recovery {seen['recovery_s']:.2f} s after the camera came back, "
          f"reconnect attempts {c.camera_reconnects}")
    assert lost["right"] == 0 and c.frame_queue_drops == 0
    assert seen["right_during"] > 20  # the other camera went on meanwhile
    # The outage's 90 frames, plus at most the reconnection back-off cap (0.1 s = 3 frames)
    # after it and a few frames of scheduling under load.
    assert outage_s * 30 - 3 <= lost["left"] <= outage_s * 30 + 10
    counts = recorded_topics(tmp_path / "rec")
    assert counts["/camera/left/image"] == c.frames["left"]
    assert counts["/camera/right/image"] == c.frames["right"]
    assert app.recorder.stats().messages_dropped == 0


def test_full_disk_pauses_recording_not_the_daemon(scene_cache: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """ENOSPC in the writer for 2 s: recording pauses (health says so), acquisition goes
    on, recording resumes when space returns, every file stays readable."""
    from tests.faults import FullDisk

    disk = FullDisk(monkeypatch)
    app = make_app(scene_cache, tmp_path / "rec")
    c = app.counters
    seen: dict[str, Any] = {}

    def paused() -> bool:
        return app.recorder.stats().paused

    def scenario() -> None:
        wait_for(app, lambda: c.frames["left"] > 30, "frames", 120)
        disk.full.set()
        t_full = time.monotonic()
        wait_for(app, paused, "the recorder to pause")
        wait_for(app, lambda: "RECORDING PAUSED" in status_line(app.health.snapshot()),
                 "health to say recording is paused")
        frames_at_pause = c.frames["left"]
        time.sleep(max(0.0, 2.0 - (time.monotonic() - t_full)))
        seen["frames_while_full"] = c.frames["left"] - frames_at_pause
        disk.full.clear()
        t_free = time.monotonic()
        wait_for(app, lambda: not paused(), "the recorder to resume", 30)
        seen["resume_s"] = time.monotonic() - t_free
        left = c.frames["left"]
        wait_for(app, lambda: c.frames["left"] > left + 30, "frames after resuming")

    assert run_with(app, scenario)["code"] == 0
    st = app.recorder.stats()
    dropped = st.drops_by_topic.get("/camera/left/image", 0)
    cut = st.messages_lost_in_cut_files
    print(f"full disk 2 s: recording resumed {seen['resume_s']:.2f} s after space returned; "
          f"{dropped} left frames not recorded while paused, {cut} messages of the open chunk "
          f"lost with the cut file ({st.files_recovered} recovered), camera frames lost "
          f"{c.frames_lost}")
    assert seen["frames_while_full"] > 20  # acquisition did not stop
    assert c.frames_lost == {"left": 0, "right": 0}
    counts = recorded_topics(tmp_path / "rec")  # no .active left, every file readable
    # Every frame is recorded, counted as dropped, or was in the chunk the full disk cut.
    missing = c.frames["left"] - counts["/camera/left/image"] - dropped
    assert 0 <= missing <= cut
    assert len(closed_files(tmp_path / "rec")) >= 2


def _pipe_bytes(conn: Any) -> int:
    """Bytes waiting in the pipe of a worker's results (``FIONREAD``)."""
    return int.from_bytes(fcntl.ioctl(conn.fileno(), termios.FIONREAD, b"\0" * 4), "little")


def _pipe_full(conn: Any) -> bool:
    """The pipe holds at least 48 KiB and took no byte more in 0.5 s (its writer is blocked)."""
    n = _pipe_bytes(conn)
    time.sleep(0.5)
    return n >= 48 * 1024 and _pipe_bytes(conn) == n


def test_worker_killed_while_writing_a_result_is_replaced(scene_cache: Path,
                                                         tmp_path: Path) -> None:
    """SIGKILL of the worker in the middle of writing a result to the daemon (the worst moment:
    half a result in the pipe): the daemon starts a new worker, and processing resumes."""
    app = make_app(scene_cache, tmp_path / "rec", ("processing.enabled", True),
                   ("processing.workers", 1))
    c = app.counters
    seen: dict[str, Any] = {}
    release = threading.Event()

    def scenario() -> None:
        wait_for(app, lambda: c.results >= 2, "first results (numba loading)", 240)
        pool = app.pool
        handle = pool._handle

        def held(res: Any) -> None:  # the daemon takes a result and reads no further
            release.wait(120)
            handle(res)

        pool._handle = held
        # A full pipe with the daemon not reading: the worker is blocked inside a write of a
        # result (a pipe holds 64 KiB, less what separate small writes leave of its pages).
        (pipe,) = pool._results._readers
        wait_for(app, lambda: _pipe_full(pipe), "the worker blocked writing", 120)
        os.kill(app.pool.workers[0].pid, signal.SIGKILL)
        t_kill = time.monotonic()
        pool._handle = handle
        release.set()
        wait_for(app, lambda: c.worker_restarts == 1, "a new worker")
        # The torn result reads as the end of the dead worker's pipe: what comes next is
        # the new worker's.
        wait_for(app, lambda: pipe not in pool._results._readers, "the dead worker's pipe closed")
        before = c.results
        wait_for(app, lambda: c.results >= before + 2, "results from the new worker", 240)
        seen["resume_s"] = time.monotonic() - t_kill

    try:
        assert run_with(app, scenario)["code"] == 0
    finally:
        release.set()
    print(f"worker SIGKILL while writing a result: processing resumed after "
          f"{seen['resume_s']:.1f} s; camera frames lost {c.frames_lost}")
    assert c.frames_lost == {"left": 0, "right": 0} and c.frame_queue_drops == 0


def test_worker_killed_inside_the_rings_lock_is_replaced(scene_cache: Path,
                                                          tmp_path: Path) -> None:
    """The worker dies while it holds the lock the ring's readers share (the test takes the
    lock and never gives it back, as a worker killed inside ``take_newest`` would): the
    daemon gives the lock back, and the new worker's results come."""
    app = make_app(scene_cache, tmp_path / "rec", ("processing.enabled", True),
                   ("processing.workers", 1))
    c = app.counters
    seen: dict[str, float] = {}

    def scenario() -> None:
        wait_for(app, lambda: c.results >= 2, "first results (numba loading)", 240)
        (pipe,) = app.pool._results._readers
        assert app.ring.reader_lock.acquire(timeout=10)  # never released here
        os.kill(app.pool.workers[0].pid, signal.SIGKILL)
        t_kill = time.monotonic()
        wait_for(app, lambda: c.worker_restarts == 1, "a new worker")
        wait_for(app, lambda: pipe not in app.pool._results._readers,
                 "the dead worker's pipe closed")
        before = c.results
        wait_for(app, lambda: c.results >= before + 2, "results from the new worker", 240)
        seen["resume_s"] = time.monotonic() - t_kill

    assert run_with(app, scenario)["code"] == 0
    print(f"worker SIGKILL inside the ring's lock: processing resumed after "
          f"{seen['resume_s']:.1f} s; camera frames lost {c.frames_lost}")
    assert c.frames_lost == {"left": 0, "right": 0}
    # The lock works as a lock again: free now, taken once, given back once.
    assert app.ring.reader_lock.acquire(timeout=5)
    app.ring.reader_lock.release()


def test_wall_clock_step_does_not_touch_pairing(scene_cache: Path, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The wall clock jumps an hour ahead mid-run: stamps and pairs stay on monotonic time,
    so pairs keep coming at 30 Hz with steady wall stamps and nothing is lost."""
    app = make_app(scene_cache, tmp_path / "rec")
    c = app.counters
    real_ns, real_s = time.time_ns, time.time
    unpaired: dict[str, dict[str, int]] = {}

    def scenario() -> None:
        wait_for(app, lambda: c.pairs > 30, "pairs", 120)
        unpaired["before"] = dict(c.unpaired)
        monkeypatch.setattr(time, "time_ns", lambda: real_ns() + 3600 * 10**9)
        monkeypatch.setattr(time, "time", lambda: real_s() + 3600.0)
        pairs = c.pairs
        wait_for(app, lambda: c.pairs > pairs + 60, "pairs after the step")
        unpaired["after"] = dict(c.unpaired)

    assert run_with(app, scenario)["code"] == 0
    (path,) = closed_files(tmp_path / "rec")
    _r, msgs = iter_json(path, ["/pairs"])
    pairs = [m for _t, m in msgs]
    steps = [b["t_wall_ns"] - a["t_wall_ns"] for a, b in itertools.pairwise(pairs)]
    print(f"wall clock +1 h: {len(pairs)} pairs, largest wall-stamp step "
          f"{max(steps) / 1e6:.1f} ms, unpaired {unpaired}")
    assert [p["pair_index"] for p in pairs] == list(range(len(pairs)))
    assert max(steps) < 0.2e9 and min(steps) > 0
    assert c.frames_lost == {"left": 0, "right": 0}
    # Each camera's first frame is stamped from its arrival alone and not paired, and one
    # more may be cut off when the cameras start a few ms apart (a CI run had one); across
    # the step itself no frame may lose its partner.
    assert unpaired["after"] == unpaired["before"]
    assert sum(unpaired["before"].values()) <= 2 + 1


def test_anemometer_port_vanishes_and_returns(scene_cache: Path, tmp_path: Path) -> None:
    """The simulated sensor's pty is closed (cable pulled) for 2 s and comes back: the
    reader reopens the port and every frame the sensor sends after that is recorded.

    The return is the reader's own reopen (``connected_ns``), not the next sample counted:
    on a loaded machine the acquisition thread may count a sample read before the pull
    after the new pty exists, and what the sensor wrote before the reopen is flushed by
    the open (pyserial empties the input buffer: half-read stale frames)."""
    app = make_app(scene_cache, tmp_path / "rec")
    c = app.counters
    seen: dict[str, Any] = {}

    def scenario() -> None:
        wait_for(app, lambda: c.wind_samples > 20, "wind samples", 120)
        sensor = app.acquisition.anemometer.sensor
        reader = app.acquisition.anemometer.serial
        sensor.unplug()
        time.sleep(2.0)  # the outage itself: real time is what is simulated here
        sensor.replug()
        t_replug_ns = time.monotonic_ns()
        wait_for(app, lambda: (reader.connected_ns or 0) > t_replug_ns,
                 "the reader to reopen the port", 30)
        seen["t_back_ns"] = reader.connected_ns
        seen["reconnect_s"] = (seen["t_back_ns"] - t_replug_ns) / 1e9
        n = c.wind_samples
        wait_for(app, lambda: c.wind_samples > n + 40, "samples after the return")
        seen["t_end_ns"] = time.monotonic_ns()
        seen["sent"] = sensor.sent()

    assert run_with(app, scenario)["code"] == 0
    (path,) = closed_files(tmp_path / "rec")
    _r, msgs = iter_json(path, ["/wind/raw"])
    got = [(m["u"], m["v"], m["w"]) for _t, m in msgs if m["t_mono_ns"] >= seen["t_back_ns"]]
    window = [(f.u, f.v, f.w) for f in seen["sent"] if f.delivered
              and seen["t_back_ns"] + 0.1e9 <= f.host_ns <= seen["t_end_ns"] - 0.3e9]
    missing = Counter(window) - Counter(got)
    print(f"anemometer pty unplugged 2 s: reconnected {seen['reconnect_s']:.2f} s after the "
          f"return; {len(window)} frames sent after that, {sum(missing.values())} missing")
    assert len(window) > 20 and not missing


def shm_in_use() -> set[str]:
    """Names under /dev/shm that a running process maps (shared memory, semaphores), by
    inode: a semaphore is mapped under the temporary name it was created with."""
    inodes = set()
    for maps in Path("/proc").glob("[0-9]*/maps"):
        try:
            text = maps.read_text()
        except OSError:  # the process ended, or is not ours to read
            continue
        for line in text.splitlines():
            if "/dev/shm/" in line:
                inodes.add(int(line.split()[4]))
    names = set()
    for name in os.listdir("/dev/shm"):
        try:
            if Path("/dev/shm", name).stat().st_ino in inodes:
                names.add(name)
        except OSError:
            continue
    return names


def test_sigkill_then_recover_keeps_all_but_the_open_chunk(scene_cache: Path,
                                                           tmp_path: Path) -> None:
    """SIGKILL of the daemon (and its process group, as systemd would) mid-run, then
    ``ogiflow recover``: every frame up to the last completed chunk is kept."""
    rec = tmp_path / "rec"
    shm_before = set(os.listdir("/dev/shm"))
    args = [sys.executable, "-m", "appliance", "run", "--live", "off", "--record-dir", str(rec),
            "--set", f"simulation.cache_dir={scene_cache}", "--set", "health.interval_s=0.2",
            "--set", "processing.enabled=false", "--set", "recording.fsync_s=1"]
    for key, value in SMALL_SCENE:
        args += ["--set", f"{key}={value}"]
    proc = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        from tests.test_daemon import lines_until

        lines_until(proc.stderr, "ogiflow: running", 180)
        time.sleep(4.0)  # record a few seconds (the fault comes at an arbitrary moment)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)
        for _ in range(100):  # until the whole group is gone (its mappings with it)
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        # The ring and semaphores SIGKILL left; not what a daemon of another test process
        # (pytest -n) created meanwhile, which its processes still map.
        for name in set(os.listdir("/dev/shm")) - shm_before - shm_in_use():
            Path("/dev/shm", name).unlink(missing_ok=True)
    (cut,) = unfinished_files(rec)
    size = cut.stat().st_size
    out = subprocess.run([sys.executable, "-m", "appliance", "recover", str(cut)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    (path,) = closed_files(rec)
    counts: Counter[str] = Counter()
    last_health = None
    for topic, _log, _pub, data in LogReader(path):
        counts[topic] += 1
        if topic == "/health":
            last_health = data
    assert last_health is not None
    import json

    health = json.loads(last_health)["counters"]
    print(f"SIGKILL after ~4 s: cut file {size / 1e6:.1f} MB; recovered "
          f"{counts['/camera/left/image']} left frames; last recorded health counted "
          f"{health['frames_left']}")
    # Everything the last recorded health snapshot had counted is in the recovered file.
    assert counts["/camera/left/image"] >= health["frames_left"] > 60


def test_cpu_contention_loses_no_frame(scene_cache: Path, tmp_path: Path) -> None:
    """``stress-ng --cpu 2`` beside the daemon (needs the Debian package stress-ng;
    ``tools/install.sh --dev`` installs it): no frame lost, pairing unaffected."""
    import shutil

    exe = shutil.which("stress-ng")
    assert exe, "stress-ng missing: install the Debian package (tools/install.sh --dev)"
    app = make_app(scene_cache, tmp_path / "rec", ("processing.enabled", True),
                   ("processing.workers", 1))
    c = app.counters
    stress: list[subprocess.Popen[bytes]] = []

    def scenario() -> None:
        wait_for(app, lambda: c.frames["left"] > 30, "frames", 120)
        stress.append(subprocess.Popen([exe, "--cpu", "2", "--timeout", "60s", "--quiet"]))
        left = c.frames["left"]
        wait_for(app, lambda: c.frames["left"] > left + 300, "10 s of frames under stress")

    try:
        assert run_with(app, scenario)["code"] == 0
    finally:
        for p in stress:
            p.terminate()
            p.wait(10)
    frames = c.frames["left"] + c.frames["right"]
    paired = 100.0 * 2 * c.pairs / frames
    print(f"stress-ng --cpu 2: {frames} frames, lost {c.frames_lost}, queue drops "
          f"{c.frame_queue_drops}, recorder drops {app.recorder.stats().messages_dropped}, "
          f"paired {paired:.2f} % (unpaired {c.unpaired})")
    assert c.frames_lost == {"left": 0, "right": 0} and c.frame_queue_drops == 0
    assert app.recorder.stats().messages_dropped == 0
    # Pairing decides on arrival times with a 1 s grace: contention delays threads by far
    # less, so every frame finds its partner, but for each camera's first frame (stamped
    # from its arrival alone, not paired) and one more pair: a frame that comes less than
    # half a period after one delayed by the load and sets the envelope is taken for a
    # catch-up burst, left unpaired, and so is its partner (2 runs of 5 had one more pair).
    assert sum(c.unpaired.values()) <= 2 + 2
