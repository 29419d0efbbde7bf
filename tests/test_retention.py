"""Retention for months: raw frames in a rolling buffer, data for months, event clips.

A simulated run with the split layout and tiny quotas: the raw buffer deletes its oldest
files while the leak event's clip keeps them (hard links) and the data folder keeps every
summary.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from pathlib import Path

from appliance.config import load_config
from appliance.recording.reader import LogReader
from appliance.runtime.daemon import Appliance
from tests.conftest import SMALL_SCENE


def _topics(files: list[Path]) -> Counter[str]:
    counts: Counter[str] = Counter()
    for f in files:
        for topic, *_rest in LogReader(f):
            counts[topic] += 1
    return counts


def test_split_layout_keeps_every_summary_and_the_event_clip(tmp_path: Path,
                                                             scene_cache: Path) -> None:
    rec = tmp_path / "rec"
    scene = [kv for kv in SMALL_SCENE if kv[0] != "recording.split"]
    cfg = load_config(None, [
        *scene, ("simulation.cache_dir", str(scene_cache)), ("recording.dir", str(rec)),
        ("live.mode", "off"), ("recording.split", True), ("recording.raw_rotate_s", 2.0),
        ("recording.raw_quota_gb", 0.03), ("recording.pre_trigger_s", 2.0),
        ("recording.post_trigger_s", 2.0), ("recording.fields_every", 5),
        ("events.min_gas_pixels", 30), ("events.min_duration_s", 1.0)])
    app = Appliance(cfg, duration_s=240.0)

    def stop_when_buffer_rolled() -> None:
        """Stop once the raw buffer has deleted a file that the event's clip keeps."""
        t_end = time.monotonic() + 200
        while not app.stop_event.wait(0.5) and time.monotonic() < t_end:
            clips = sorted((rec / "events").glob("*/ogiflow-*.mcap"))
            if any(not (rec / "raw" / c.name).exists() for c in clips):
                break
        app.stop_event.set()

    threading.Thread(target=stop_when_buffer_rolled, daemon=True).start()
    assert app.run() == 0
    raw = sorted((rec / "raw").glob("ogiflow-*.mcap"))
    data = sorted((rec / "data").glob("ogiflow-*.mcap"))
    clips = sorted(p for p in (rec / "events").iterdir() if p.is_dir())
    assert raw and data and len(clips) >= 1
    assert app.recorder.raw.stats().files_deleted >= 1  # the rolling buffer rolled
    # Every summary, pair and wind sample is in the long-term data; no frame is.
    d = _topics(data)
    c = app.counters
    assert d["/sceneflow/summary"] == c.results > 0 and d["/pairs"] == c.pairs
    assert d["/wind/raw"] == c.wind_samples and d["/camera/left/image"] == 0
    assert d["/events"] >= 2  # start and end (the end at shutdown)
    # The clip holds raw files the buffer has deleted, readable, from before the start.
    clip = clips[0]
    info = json.loads((clip / "event.json").read_text())
    kept = sorted(clip.glob("ogiflow-*.mcap"))
    assert kept and {p.name for p in kept} - {p.name for p in raw}, "nothing outlived the buffer"
    assert info["files"] == [p.name for p in kept]
    frames = _topics(kept)["/camera/left/image"]
    assert frames > 30
    assert info["window_s"][0] <= info["start_s"] - 2.0
