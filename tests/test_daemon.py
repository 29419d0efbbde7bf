"""``ogiflow run`` end to end with the simulated devices, then replay and export of its file.

The scene is small and coarse (fast to render) but goes through every real component:
pty anemometer, simulated cameras, clock models, pairer, shared-memory ring, two worker
processes running the chain, recorder, live view (saved to an .rrd) and health.
"""

from __future__ import annotations

import csv
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from appliance.config import load_config
from appliance.recording.reader import LogReader, read_metadata
from appliance.runtime.daemon import Appliance
from tests.conftest import SMALL_SCENE


def stop_when(app: Appliance, done: Callable[[object], bool], deadline_s: float = 200.0
              ) -> threading.Thread:
    """Stop ``app`` (running in this thread) once ``done(app.counters)`` holds."""

    def watch() -> None:
        t_end = time.monotonic() + deadline_s
        while not app.stop_event.wait(0.1) and time.monotonic() < t_end:
            if done(app.counters):
                break
        app.stop_event.set()

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    return t


def lines_until(stream: object, marker: str, timeout_s: float) -> list[str]:
    """Lines of a text stream up to and including the one containing ``marker``; fails
    after ``timeout_s`` instead of blocking forever on a silent process."""
    q: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:
        for line in stream:  # type: ignore[attr-defined]
            q.put(line)
        q.put(None)

    threading.Thread(target=pump, daemon=True).start()
    seen: list[str] = []
    t_end = time.monotonic() + timeout_s
    while True:
        try:
            line = q.get(timeout=max(0.0, t_end - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"no {marker!r} within {timeout_s} s; got {seen[-5:]}") from None
        if line is None:
            raise AssertionError(f"process ended before {marker!r}; got {seen[-5:]}")
        seen.append(line)
        if marker in line:
            return seen


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory, scene_cache: Path) -> dict:
    """One simulated run of a few seconds; its recording, counters and ground truth. The
    left camera's offset steps by 200 counts between every two frames (a flat-field
    shutter each frame: every frame pair a processed triple differences holds one)."""
    tmp = tmp_path_factory.mktemp("run")
    cfg = load_config(None, [*SMALL_SCENE, ("simulation.cache_dir", str(scene_cache)),
                             ("recording.dir", str(tmp / "rec")), ("live.mode", "save"),
                             ("live.file", str(tmp / "live.rrd")), ("recording.fields_every", 5),
                             ("cameras.left.options.shutter_every_s", 1 / 30)])
    app = Appliance(cfg, duration_s=240.0)
    # Stop on a condition, not after a fixed time: numba's cached solvers load slowly on a
    # busy machine, and the checks below need some results.
    stop_when(app, lambda c: c.results >= 12 and c.frames["left"] >= 150)
    assert app.run() == 0
    files = sorted((tmp / "rec").glob("ogiflow-*.mcap"))
    return {"tmp": tmp, "app": app, "files": files, "cache": scene_cache}


def test_every_frame_and_wind_sample_is_recorded(recorded: dict) -> None:
    app = recorded["app"]
    assert len(recorded["files"]) == 1  # closed and renamed: no .active file left
    assert not list((recorded["tmp"] / "rec").glob("*.active"))
    counts: Counter[str] = Counter()
    reader = LogReader(recorded["files"][0])
    for topic, _log, _pub, _data in reader:
        counts[topic] += 1
    assert not reader.truncated
    c = app.counters
    assert c.frames["left"] > 100 and c.frames["right"] > 100
    assert counts["/camera/left/image"] == c.frames["left"]
    assert counts["/camera/right/image"] == c.frames["right"]
    assert counts["/camera/left/frame_info"] == c.frames["left"]
    assert counts["/wind/raw"] == c.wind_samples > 50
    assert counts["/pairs"] == c.pairs
    assert counts["/sceneflow/summary"] == c.results > 0
    assert counts["/health"] >= 5
    assert counts["/sceneflow/velocity"] >= 1  # fields every 5th result
    assert c.result_errors == 0
    assert app.recorder.stats().messages_dropped == 0


def test_peak_memory_is_reported_for_the_daemon_and_every_worker(recorded: dict) -> None:
    app = recorded["app"]
    peaks = app.peak_rss_mb
    assert len(peaks) == 1 + app.cfg.processing.workers, peaks
    assert all(mb is not None and 50 < mb < 4000 for mb in peaks), peaks


def test_where_the_chain_spends_its_time_is_reported(recorded: dict) -> None:
    # the workers' own stage timings, as the final line and the keep-up warning give them
    med = recorded["app"].stage_times.medians()
    assert {"preprocess", "flow", "disparity", "segmentation", "total"} <= set(med), med
    assert all(v >= 0 for v in med.values()) and med["total"] >= med["flow"]
    assert recorded["app"].stage_times.describe().startswith("chain ")


def test_cold_starts_are_counted(recorded: dict) -> None:
    # Each worker's first triple starts cold and, at ring stride 2 on a machine that keeps
    # up, most later ones warm from the worker's previous triple: the count shows which.
    from appliance.recording.reader import iter_json

    c = recorded["app"].counters
    assert 1 <= c.cold_results <= c.results
    assert c.cold_results < c.results  # at least one warm start happened
    _reader, messages = iter_json(recorded["files"][0], ["/health"])
    health = [m["counters"] for _topic, m in messages]
    assert "cold_results" in health[-1]
    assert 0 <= health[-1]["cold_results"] <= c.cold_results


def test_a_cameras_offset_steps_are_levelled_counted_and_shown(recorded: dict) -> None:
    # Every processed triple's last frame pair holds one of the left camera's steps: each
    # is counted once, for the left camera alone, flagged in the summary, reported in the
    # health record and on the operator's page; the velocity reads as without them (the
    # comparison with the truth below).
    from appliance.live.status import health_words
    from appliance.recording.reader import iter_json

    c = recorded["app"].counters
    stereo = c.results - c.single_results
    assert c.offset_steps["left"] == stereo > 0 and c.offset_steps["right"] == 0
    _reader, messages = iter_json(recorded["files"][0], ["/sceneflow/summary", "/health"])
    messages = list(messages)
    flags = [m["flags"] for topic, m in messages if topic == "/sceneflow/summary"]
    assert len(flags) == c.results and all("offset_levelled" in f for f in flags)
    health = [m["counters"] for topic, m in messages if topic == "/health"]
    assert 0 < health[-1]["offset_steps_left"] <= stereo
    assert health[-1]["offset_steps_right"] == 0
    words = health_words(recorded["app"].health.snapshot())
    assert any(w.startswith(f"offset steps levelled since the start: left {stereo} (one per ")
               for w in words), words


def test_file_carries_config_geometry_and_parameters(recorded: dict) -> None:
    meta = read_metadata(recorded["files"][0])
    assert {"recording", "config", "calibration", "geometry", "processing"} <= set(meta)
    geometry = json.loads(meta["geometry"]["json"])
    assert geometry["image_size"] == [320, 240]
    assert json.loads(meta["processing"]["json"])["alpha"] == 0.05


def test_measured_gas_velocity_follows_the_simulated_truth(recorded: dict) -> None:
    comparison = recorded["app"].publisher.truth_comparison()
    assert comparison is not None and comparison["frames"] > 5
    # Coarse test scene and a few seconds only: a loose bound; the 120 s acceptance run
    # with the default scene is in docs/accuracy.md.
    assert comparison["magnitude_error_pct"] < 30
    assert comparison["direction_error_deg"] < 30


def test_live_view_was_saved(recorded: dict) -> None:
    rrd = recorded["tmp"] / "live.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 10_000


def test_replay_reprocesses_every_triple_and_export_writes_csv(recorded: dict,
                                                                tmp_path: Path) -> None:
    src = recorded["files"][0]
    out = tmp_path / "replayed.mcap"
    code = cli.main(["replay", str(src), "--fast", "--out", str(out), "--param", "alpha=0.1",
                     "--fields-every", "50"])
    assert code == 0
    counts: Counter[str] = Counter(t for t, *_ in LogReader(out))
    pairs = counts["/pairs"]
    assert pairs >= recorded["app"].counters.pairs - 2
    assert counts["/sceneflow/summary"] == pairs - 2  # every triple, nothing skipped
    assert json.loads(read_metadata(out)["processing"]["json"])["alpha"] == 0.1
    assert cli.main(["export", str(out), "--to", "csv", "--out", str(tmp_path / "x")]) == 0
    with open(tmp_path / "x_summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == pairs - 2
    assert {"vx_m_s", "speed_m_s", "angle_x_deg", "valid", "flags"} <= set(rows[0])
    # The replay computes the emission rate too, and the export carries it.
    assert {"emission_rate_g_s", "emission_window_rate_kg_h"} <= set(rows[0])
    assert any(r["emission_window_rate_g_s"] not in ("", None) for r in rows)
    assert cli.main(["export", str(out), "--to", "npz", "--out", str(tmp_path / "y")]) == 0
    assert (tmp_path / "y.npz").is_file()
    with np.load(tmp_path / "y.npz") as z:
        assert "summary_emission_rate_g_s" in z.files


def test_summaries_carry_the_emission_rate_and_its_truth(recorded: dict) -> None:
    """Every summary of the simulated run has the frame's and the window's rate (g/s and
    kg/h, or null with a reason) and the simulator's true release; the end comparison
    exists. Coarse test scene, a few seconds: only a loose bound on the value (docs/accuracy.md
    reports the 120 s run of the default configuration)."""
    from appliance.recording.reader import iter_json

    _r, msgs = iter_json(recorded["files"][0], ["/sceneflow/summary"])
    rows = [m for _t, m in msgs]
    assert rows and all("emission_window_rate_g_s" in m and "emission_reason" in m
                        for m in rows)
    assert all(m["emission_true_rate_g_s"] > 0 for m in rows
               if m.get("emission_true_rate_g_s") is not None)
    rated = [m for m in rows if m["emission_rate_g_s"] is not None]
    assert rated, [m["emission_reason"] for m in rows]
    assert all(m["emission_rate_kg_h"] == pytest.approx(3.6 * m["emission_rate_g_s"])
               for m in rated)
    comparison = recorded["app"].publisher.rate_comparison()
    assert comparison is not None
    measured, true, _err = comparison
    assert 0.0 < measured < 5.0 * true


def test_replay_refuses_to_overwrite_and_names_bad_params(recorded: dict, tmp_path: Path) -> None:
    src = recorded["files"][0]
    existing = tmp_path / "exists.mcap"
    existing.write_bytes(b"x")
    assert cli.main(["replay", str(src), "--out", str(existing)]) == cli.EXIT_USAGE
    assert cli.main(["replay", str(src), "--out", str(tmp_path / "o.mcap"),
                     "--param", "alhpa=1"]) == cli.EXIT_USAGE


def test_config_error_exits_2_and_names_the_key(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--set", "recording.rotat_mb=5", "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "recording.rotat_mb" in err and "rotate_mb" in err


def test_sigterm_finalises_files_and_exits_0(recorded: dict, tmp_path: Path) -> None:
    """SIGTERM as systemd sends it: exit 0 with every file closed (no .active left)."""
    cache = recorded["cache"]  # the scene is already rendered
    args = [sys.executable, "-m", "appliance", "run", "--live", "off",
            "--record-dir", str(tmp_path / "rec"), "--set", f"simulation.cache_dir={cache}"]
    for key, value in SMALL_SCENE:
        args += ["--set", f"{key}={value}"]
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parent.parent,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stderr is not None
    try:
        lines_until(proc.stderr, "ogiflow: running", 180)
        time.sleep(3.0)
    finally:
        proc.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()  # its workers end with it: no daemon outlives the test
        proc.wait()
        raise
    stop_s = time.monotonic() - t0
    print(f"shutdown after SIGTERM took {stop_s:.2f} s")
    assert proc.returncode == 0
    files = list((tmp_path / "rec").glob("ogiflow-*"))
    assert files and all(f.suffix == ".mcap" for f in files)
    assert not LogReader(files[0]).truncated


def test_a_signal_inside_the_wait_for_the_stop_event_does_not_deadlock() -> None:
    """A signal handler runs in the main thread, possibly while it holds the stop event's
    lock inside ``wait()``. The handler must not take that lock (it used to call
    ``stop_event.set()``, and a SIGTERM once left the daemon hanging); the wait loop then
    stops the run."""
    app = Appliance(load_config(None, list(SMALL_SCENE)), duration_s=1.0)
    done = threading.Event()

    def signal_while_holding_the_lock() -> None:
        with app.stop_event._cond:  # where Event.wait() is when the signal comes
            app.signals.on_signal(signal.SIGTERM, None)
        done.set()

    threading.Thread(target=signal_while_holding_the_lock, daemon=True).start()
    assert done.wait(5.0), "the signal handler waited for the lock its own thread holds"
    assert not app.stop_event.is_set() and app.signals.signalled == signal.SIGTERM
    app.signals.take()
    assert app.stop_event.is_set()


def test_a_dead_thread_fails_the_run_with_exit_1(recorded: dict, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """run() is not always 0: a pairing thread that dies ends the run with exit code 1 (so
    systemd restarts the service) instead of leaving an appliance that records nothing."""
    from appliance.runtime.acquisition import Acquisition

    def broken(self: Acquisition) -> None:
        raise RuntimeError("injected fault")

    monkeypatch.setattr(Acquisition, "pairing_loop", broken)
    cfg = load_config(None, [*SMALL_SCENE, ("simulation.cache_dir", str(recorded["cache"])),
                             ("recording.dir", str(tmp_path / "rec")), ("live.mode", "off"),
                             ("processing.enabled", False)])
    app = Appliance(cfg, duration_s=60.0)
    assert app.run() == 1
    assert any("pairing" in f and "injected fault" in f for f in app.failures)
    assert list((tmp_path / "rec").glob("ogiflow-*.mcap"))  # files still finalised


def test_runtime_fault_exits_1_config_error_exits_2(monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A full /dev/shm at run time (OSError) is not a configuration error: exit 1."""
    def full_shm(self: Appliance) -> int:
        raise OSError(28, "No space left on device", "/dev/shm/ogiflow-ring")

    monkeypatch.setattr(Appliance, "run", full_shm)
    assert cli.main(["run", "--live", "off", "--duration", "1"]) == 1
    assert "No space left on device" in capsys.readouterr().err
    assert cli.main(["run", "--set", "cameras.left.backend=simulted", "--duration", "1"]) == 2
    assert "did you mean 'simulated'?" in capsys.readouterr().err
