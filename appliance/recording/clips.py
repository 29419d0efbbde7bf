"""Event clips: the raw frames of every leak event, kept out of the rolling raw buffer.

Raw frames (about 150 MB a minute) live in a rolling buffer (``<dir>/raw``, its own quota,
hours); results, wind, health and events in ``<dir>/data`` (their own quota, months). When a
leak event starts, every raw file that overlaps ``[start - pre_s, end + post_s]`` is
hard-linked into ``<dir>/events/<UTC start>-event<id>/`` as it is closed, with an
``event.json``. A hard link costs no copy and no time: when the raw buffer's quota later
deletes its name, the clip's name keeps the data. The clips have their own quota (oldest
clips deleted first). Clip boundaries are those of the raw files (``recording.raw_rotate_s``,
30 s by default), so a clip holds at least the requested window.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from appliance.recording.files import FILE_PATTERN, closed_files

log = logging.getLogger("ogiflow.clips")


def file_start_s(path: Path) -> float:
    """UNIX start time of a recording from its name (``ogiflow-<UTC>-<n>.mcap``)."""
    m = FILE_PATTERN.match(path.name)
    if m is None:
        raise ValueError(f"not an ogiflow recording name: {path.name}")
    stamp = datetime.strptime(m.group(1)[:-4], "%Y%m%dT%H%M%S").replace(tzinfo=timezone.utc)
    return stamp.timestamp() + int(m.group(1)[-4:-1]) / 1000.0


@dataclass
class _Clip:
    event_id: int
    folder: Path
    start_s: float
    until_s: float | None = None  # end + post; None while the event lasts
    linked: set[str] = field(default_factory=set)
    info: dict[str, Any] = field(default_factory=dict)


class ClipKeeper:
    """Links the raw files of leak events into event clips (module docstring).

    Parameters
    ----------
    raw_dir : Path
        The raw buffer's folder.
    events_dir : Path
        Where clips go (same file system as ``raw_dir``; otherwise files are copied).
    pre_s, post_s : float
        Pre- and post-trigger, s.
    quota_gb : float or None
        Most space the clips may take; the oldest finished clips go first.
    """

    def __init__(self, raw_dir: Path, events_dir: Path, *, pre_s: float = 30.0,
                 post_s: float = 30.0, quota_gb: float | None = None) -> None:
        self.raw_dir, self.events_dir = Path(raw_dir), Path(events_dir)
        self.pre_s, self.post_s, self.quota_gb = pre_s, post_s, quota_gb
        self._clips: dict[int, _Clip] = {}
        self._lock = threading.Lock()
        self.copied = 0  # files copied because a hard link was impossible
        self.deleted = 0  # clips deleted by the quota

    # ------------------------------------------------------------------ events

    def event_started(self, event_id: int, start_s: float, info: dict[str, Any]) -> Path:
        """Open a clip for an event that started at ``start_s`` (UNIX s); returns its folder."""
        stamp = datetime.fromtimestamp(start_s, tz=timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        folder = self.events_dir / f"{stamp}-event{event_id}"
        folder.mkdir(parents=True, exist_ok=True)
        clip = _Clip(event_id, folder, start_s, info=dict(info))
        with self._lock:
            self._clips[event_id] = clip
        self._write_info(clip, finished=False)
        self.poll()
        return folder

    def event_ended(self, event_id: int, end_s: float, info: dict[str, Any]) -> None:
        """The event ended at ``end_s``: keep linking until ``end_s + post_s`` is on disk."""
        with self._lock:
            clip = self._clips.get(event_id)
            if clip is None:
                return
            clip.until_s = end_s + self.post_s
            clip.info.update(info)
        self._write_info(clip, finished=False)

    # ------------------------------------------------------------------ files

    def poll(self) -> list[Path]:
        """Link newly closed raw files into the open clips; finish clips whose window is
        complete. Call it after each raw file is closed (or periodically). Returns the
        clips finished by this call."""
        files = closed_files(self.raw_dir)
        starts = [file_start_s(f) for f in files]
        finished = []
        with self._lock:
            clips = list(self._clips.values())
        for clip in clips:
            lo = clip.start_s - self.pre_s
            hi = clip.until_s if clip.until_s is not None else float("inf")
            for i, f in enumerate(files):
                end = starts[i + 1] if i + 1 < len(files) else float("inf")
                if starts[i] <= hi and end >= lo and f.name not in clip.linked:
                    self._link(f, clip.folder / f.name)
                    clip.linked.add(f.name)
            if clip.until_s is not None and starts and starts[-1] > clip.until_s:
                self._write_info(clip, finished=True)
                with self._lock:
                    self._clips.pop(clip.event_id, None)
                finished.append(clip.folder)
        if finished:
            self._enforce_quota()
        return finished

    def _link(self, src: Path, dst: Path) -> None:
        try:
            os.link(src, dst)
        except FileExistsError:
            pass
        except OSError:  # another file system, or links not supported: copy
            shutil.copy2(src, dst)
            self.copied += 1

    def _write_info(self, clip: _Clip, *, finished: bool) -> None:
        info = {"event_id": clip.event_id, "start_s": clip.start_s,
                "window_s": [clip.start_s - self.pre_s, clip.until_s],
                "finished": finished, "files": sorted(clip.linked), **clip.info}
        tmp = clip.folder / "event.json.tmp"
        tmp.write_text(json.dumps(info, indent=1, default=str))
        tmp.replace(clip.folder / "event.json")

    def _enforce_quota(self) -> None:
        if self.quota_gb is None:
            return
        with self._lock:
            open_folders = {c.folder for c in self._clips.values()}
        clips = sorted(p for p in self.events_dir.iterdir() if p.is_dir())
        sizes = {c: sum(f.stat().st_size for f in c.iterdir() if f.is_file()) for c in clips}
        total = sum(sizes.values())
        for c in clips:
            if total <= self.quota_gb * 1e9:
                break
            if c in open_folders:
                continue
            shutil.rmtree(c, ignore_errors=True)
            total -= sizes[c]
            self.deleted += 1
            log.warning("event clip quota: deleted %s", c.name)

    def close(self) -> None:
        """At shutdown: link what is on disk; unfinished clips keep what they have."""
        self.poll()
        with self._lock:
            clips = list(self._clips.values())
        for clip in clips:
            clip.info.setdefault("end_reason", "appliance stopped before the post-trigger")
            self._write_info(clip, finished=False)
