"""One camera keeps watch: a camera of the pair lost and back, single-camera sites.

Whole-daemon tests with simulated devices (the simulated release) and real footage (a
GasVid clip served at its own 1 frame/s by the replay-folder back end); bounded by counts
and frames, never by the machine's speed. The MQTT test needs Debian's mosquitto
(tools/install.sh --dev).
"""

from __future__ import annotations

import itertools
import json
import shutil
import time
from pathlib import Path
from typing import Any

import pytest

from appliance.config import ConfigError, load_config
from appliance.runtime.daemon import Appliance
from appliance.runtime.degraded import CameraWatch
from appliance.runtime.health import status_line
from drivers.camera.simulated import vanish
from tests.conftest import SMALL_SCENE
from tests.test_faults import recorded_topics, run_with, wait_for

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT / "data" / "ogi" / "gasvid" / "1238"
#: The clip's class-3 stretch (958.8 g/h at 9.8 m): frames 600-659, one a second.
CLASS3 = "frame06[0-5]?.jpg"


def test_camera_watch_loses_and_gets_back_a_camera() -> None:
    """Lost after lost_after_s without a frame (counted from the first frame of any camera
    when it never delivered), back at its next frame; degraded seconds counted."""
    s = 1_000_000_000
    w = CameraWatch({"left": True, "right": True}, 3.0, lambda t: t + 7)
    assert w.check(10 * s) == [] and w.mode == "stereo"  # no frame yet: nothing is lost
    w.frame("left", 10 * s)
    w.frame("right", 10 * s)
    w.frame("left", 14 * s)
    assert w.check(14 * s) == ["right"] and w.check(15 * s) == []
    assert (w.mode, w.survivor) == ("degraded", "left")
    assert w.status()["right"] == {"configured": True, "lost": True,
                                   "lost_since_wall_ns": 10 * s + 7}
    assert w.frame("right", 24 * s) and w.mode == "stereo" and w.survivor is None
    assert w.degraded_s(100 * s) == pytest.approx(10.0) and w.losses("right") == 1
    single = CameraWatch({"left": True, "right": False}, 3.0, lambda t: t)
    single.frame("left", 0)
    assert single.mode == "single_camera" and single.survivor == "left"
    assert single.degraded_s(10 * s) == 0.0


def test_a_window_across_a_loss_runs_on_the_survivor() -> None:
    """Stereo pairs and the left camera's frames alone: the window runs single-camera on
    the left; three pairs run stereo; no camera in all three slots is an error."""
    from appliance.runtime.ring import LEFT, RIGHT
    from appliance.runtime.single_camera import window_camera

    both = {"cameras": LEFT | RIGHT}
    assert window_camera([both, both, both]) is None
    assert window_camera([both, {"cameras": LEFT}, {"cameras": LEFT}]) == "left"
    assert window_camera([{"cameras": RIGHT}, both, both]) == "right"
    with pytest.raises(ValueError):
        window_camera([{"cameras": LEFT}, {"cameras": RIGHT}, both])


@pytest.mark.parametrize(("cameras", "key"), [
    ({"left": None, "right": None}, "cameras: no camera configured"),
    ({"left": None}, "cameras.left: null while cameras.right names a camera"),
])
def test_configs_without_a_usable_camera_are_refused(cameras: dict[str, Any], key: str
                                                     ) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(None, [(f"cameras.{k}", v) for k, v in cameras.items()])
    assert key in str(err.value) and "set cameras.left" in str(err.value)


def test_right_camera_lost_for_15_s_and_back(scene_cache: Path, tmp_path: Path) -> None:
    """The simulated release with the right camera gone for 15 s once a leak event is open
    (the CLI's ``outage_after_s: 30, outage_s: 40``, shorter: 15 s is still well past the
    event's end window, so a lost event would show): the left camera loses no
    frame, the single-camera chain keeps processing into the same leak event, status and
    health say which camera is lost and since when, and stereo resumes by itself."""
    cfg = load_config(None, [
        *SMALL_SCENE, ("simulation.cache_dir", str(scene_cache)),
        ("recording.dir", str(tmp_path / "rec")), ("live.mode", "off"),
        ("health.interval_s", 0.5),
        ("cameras.right.options", {"label": f"right-{tmp_path.name}"})])
    app = Appliance(cfg, duration_s=600.0)
    c = app.counters
    seen: dict[str, Any] = {}

    def mode() -> str:
        return app.watch.mode if app.watch is not None else ""

    def scenario() -> None:
        wait_for(app, lambda: app.monitor is not None
                 and app.monitor.detector.current is not None,
                 "a leak event before the outage", 240)
        assert mode() == "stereo"
        seen["event"] = app.monitor.detector.current.id
        # The outage starts once the event is open, however long that took on this machine.
        vanish(f"right-{tmp_path.name}", 15.0)
        wait_for(app, lambda: mode() == "degraded", "the right camera to be lost", 120)
        single_before = c.single_results
        wait_for(app, lambda: c.single_results >= single_before + 10,
                 "single-camera results during the outage", 120)
        # The MQTT status takes the health line at its own interval: wait for it (bounded)
        # rather than race it (ten single-camera results can come within 0.3 s).
        wait_for(app, lambda: any(w.startswith("DEGRADED: right camera lost")
                                  for w in app.monitor.status().health),
                 "the MQTT status to say degraded", 120)
        snap = app.health.snapshot()
        seen["snapshot"] = snap
        seen["status"] = status_line(snap)
        seen["mqtt"] = app.monitor.status().health
        wait_for(app, lambda: mode() == "stereo", "the right camera's return", 120)
        pairs = c.pairs
        wait_for(app, lambda: c.pairs >= pairs + 30, "stereo pairs after the return")
        stereo = c.results - c.single_results
        wait_for(app, lambda: c.results - c.single_results >= stereo + 5,
                 "stereo results after the return", 120)
        seen["current"] = app.monitor.detector.current

    assert run_with(app, scenario)["code"] == 0
    snap = seen["snapshot"]
    right = snap.cameras["right"]
    assert snap.mode == "degraded" and right["lost"] and right["lost_since_wall_ns"] > 0
    assert not snap.cameras["left"]["lost"]
    assert "DEGRADED: right camera lost since" in seen["status"]
    assert any(w.startswith("DEGRADED: right camera lost") for w in seen["mqtt"])
    # the same event before, during and after the outage
    assert seen["current"] is not None and seen["current"].id == seen["event"]
    assert [e.end_reason for e in app.monitor.detector.finished if e.id == seen["event"]] == [
        "appliance stopped"]  # ended by the shutdown, not during the run
    assert c.frames_lost["left"] == 0 and c.frame_queue_drops == 0
    assert c.single_frames > 0 and app.watch.degraded_s(time.monotonic_ns()) > 0
    counts = recorded_topics(tmp_path / "rec")
    assert counts["/camera/left/image"] == c.frames["left"]
    assert counts["/camera/right/image"] == c.frames["right"]
    print(f"right camera out 15 s: left frames {c.frames['left']} (lost "
          f"{c.frames_lost['left']}), single-camera frames {c.single_frames}, results "
          f"{c.results} ({c.single_results} single-camera), event {seen['event']} kept")


def _clip(tmp_path: Path) -> Path:
    """The class-3 stretch of the clip in a folder of its own, with its labels.json (the
    folder's frame rate)."""
    folder = tmp_path / "clip"
    folder.mkdir()
    for f in sorted(CLIP.glob(CLASS3)):
        (folder / f.name).symlink_to(f)
    shutil.copy(CLIP / "labels.json", folder / "labels.json")
    return folder


def test_single_camera_site_on_real_footage(tmp_path: Path) -> None:
    """cameras.right: null with a GasVid clip: frames served at the footage's 1 frame/s,
    every frame recorded, every triple through the single-camera chain, and the leak
    events `ogiflow eval detection` finds on the same frames, over MQTT (real mosquitto)
    and as clips."""
    from appliance.evaluation.detection import DetectionSettings, detect_folder
    from appliance.evaluation.footage import FootageSettings, find_sets
    from appliance.recording.reader import LogReader
    from appliance.recording.recorder import closed_files
    from tests.mosquitto import Broker, Subscriber

    folder = _clip(tmp_path)
    frames = find_sets(tmp_path)["clip"]
    assert len(frames) == 60
    broker = Broker(tmp_path).start()
    sub = Subscriber(broker.port, "site/#")
    cfg = load_config(None, [
        ("cameras.left", {"backend": "replay_folder", "options": {"path": str(folder)}}),
        ("cameras.right", None), ("live.mode", "off"), ("processing.workers", 1),
        # the pre-processing of `ogiflow eval detection` (FootageSettings' defaults)
        ("processing.parameters", {"diff_scale": 5.0, "denoise_lambda": 10.0,
                                   "max_jitter_px": 1.0}),
        ("recording.dir", str(tmp_path / "rec")), ("recording.raw_rotate_s", 10.0),
        ("alarms.mqtt.enabled", True), ("alarms.mqtt.port", broker.port),
        ("alarms.mqtt.topic_prefix", "site"), ("health.interval_s", 0.5)])
    app = Appliance(cfg, duration_s=600.0)
    c = app.counters

    def scenario() -> None:
        wait_for(app, lambda: c.frames["left"] == 60, "the clip's 60 frames", 240)
        wait_for(app, lambda: c.results + c.result_errors + c.skipped_pairs >= 58,
                 "every triple", 120)

    try:
        assert run_with(app, scenario)["code"] == 0
        offline = detect_folder("clip", frames, DetectionSettings(
            fps=1.0, footage=FootageSettings()))
        assert offline["events"], "eval detection finds no event on the class-3 clip"
        sub.wait_for(lambda m: m[0] == "site/event" and json.loads(m[1])["type"] == "end",
                     timeout=60)
        messages = [(t, json.loads(p)) for t, p, _ in sub.messages]
    finally:
        sub.close()
        broker.stop()
    assert c.frames_lost["left"] == 0 and c.single_frames == 60 and c.pairs == 0
    assert c.results == c.single_results == 58 and c.result_errors == 0
    # served at the footage's rate: recorded one a second
    times = []
    for path in closed_files(tmp_path / "rec" / "raw"):
        times += [t for _, t, _, _ in LogReader(path, topics=["/camera/left/image"])]
    steps = {round((b - a) / 1e9, 6) for a, b in itertools.pairwise(sorted(times))}
    assert len(times) == 60 and steps == {1.0}
    # the daemon's events are the offline ones (pair index = frame number - 600 + 1: the
    # daemon numbers a triple by its middle pair, eval detection by its first frame), to
    # the frame and the source to the bit. Same code in two processes, the worker and this
    # test, either of which may be the one that compiles the kernels on a fresh clone: they
    # compute the same numbers (tests/test_compile_determinism.py).
    first = frames[0][0]
    live = app.monitor.detector.finished
    expected = [(e["start_frame"] - first + 1, e["end_frame"] - first + 1)
                for e in offline["events"]]
    assert len(live) == len(expected), (live, expected)
    for e, (start, end), off in zip(live, expected, offline["events"], strict=True):
        assert (e.start_frame, e.end_frame) == (start, end), (e, start, end)
        assert tuple(e.source_xy) == tuple(off["source_xy"]), (e, off)
    kinds = [(m["type"], m["id"]) for t, m in messages if t == "site/event"]
    for e in live:
        assert ("new", e.id) in kinds and ("end", e.id) in kinds
    status = [m for t, m in messages if t == "site/status" and "mode" in m]
    assert status and status[-1]["mode"] == "single_camera"
    clips = list((tmp_path / "rec" / "events").rglob("*.mcap"))
    assert clips, "no event clip recorded"
    print(f"GasVid class 3 through the daemon: {len(times)} frames at 1/s, {c.results} "
          f"single-camera results, events {[(e.start_frame, e.end_frame) for e in live]}, "
          f"{len(clips)} clip files")
