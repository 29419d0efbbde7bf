"""Event clips: raw files of a leak event hard-linked out of the rolling raw buffer."""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path

from appliance.recording.clips import ClipKeeper, file_start_s

T0 = datetime(2026, 11, 29, 12, 0, 0, tzinfo=timezone.utc).timestamp()


def _raw(raw: Path, k: int, period_s: float = 30.0, size: int = 1000) -> Path:
    t = datetime.fromtimestamp(T0 + k * period_s, tz=timezone.utc)
    p = raw / f"ogiflow-{t.strftime('%Y%m%dT%H%M%S')}000Z-{k + 1:04d}.mcap"
    p.write_bytes(os.urandom(size))
    return p


def test_clip_links_the_window_and_survives_raw_deletion(tmp_path: Path) -> None:
    raw, events = tmp_path / "raw", tmp_path / "events"
    raw.mkdir()
    files = [_raw(raw, k) for k in range(6)]  # 12:00:00 ... 12:02:30, 30 s each
    assert file_start_s(files[2]) == T0 + 60
    keeper = ClipKeeper(raw, events, pre_s=30, post_s=30)
    # Event from 12:02:10 to 12:03:20: window 12:01:40 .. 12:03:50.
    folder = keeper.event_started(1, T0 + 130, {"source_xy": [60, 120]})
    linked = sorted(p.name for p in folder.glob("*.mcap"))
    assert linked == [f.name for f in files[3:6]]  # 12:01:30 onwards
    keeper.event_ended(1, T0 + 200, {"end_reason": "gas gone"})
    for k in range(6, 9):  # 12:03:00 ... 12:04:00 closed later
        _raw(raw, k)
        keeper.poll()
    info = json.loads((folder / "event.json").read_text())
    assert info["finished"] and info["end_reason"] == "gas gone"
    assert info["files"] == sorted([f.name for f in files[3:6]] + [
        p.name for p in sorted(raw.glob("*.mcap"))[6:8]])  # 12:03:00, 12:03:30; not 12:04:00
    for f in files:  # the raw buffer's quota deletes its names ...
        f.unlink()
    kept = folder / files[4].name
    assert kept.stat().st_size == 1000  # ... the clip keeps the data (hard link)


def test_clip_quota_deletes_oldest_finished_clips(tmp_path: Path) -> None:
    raw, events = tmp_path / "raw", tmp_path / "events"
    raw.mkdir()
    keeper = ClipKeeper(raw, events, pre_s=0, post_s=0, quota_gb=2500 / 1e9)
    for event in range(3):
        _raw(raw, 2 * event, size=1000)
        keeper.event_started(event + 1, T0 + 60 * event + 1, {})
        keeper.event_ended(event + 1, T0 + 60 * event + 2, {})
        _raw(raw, 2 * event + 1, size=1000)
        keeper.poll()
    clips = sorted(p.name for p in events.iterdir())
    assert len(clips) == 2 and clips[0].endswith("event2") and keeper.deleted == 1
