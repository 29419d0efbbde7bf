"""Retention for months: raw frames in a rolling buffer, results for months, event clips.

The split layout (``recording.split``, default) under ``recording.dir``:

- ``raw/``: camera frames (with their frame info), the full result fields and a copy of the
  raw wind samples (so a raw file replays on its own), in ``raw_rotate_s``-long files under
  ``raw_quota_gb``: a rolling buffer of hours (150 MB a minute);
- ``data/``: summaries, pairs, wind, health and leak events under ``quota_gb``: about
  0.5 MB a minute, so months;
- ``events/``: the raw files of every leak event (:mod:`appliance.recording.clips`).

:class:`SplitRecorder` has the :class:`~appliance.recording.recorder.Recorder` interface the
daemon uses (``record``, ``stats``, ``close``) and routes each topic to its recorder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from appliance.config import RecordingConfig
from appliance.recording.recorder import Recorder, RecorderStats
from appliance.recording.schemas import MessageSchema

#: Topics of the raw buffer (prefixes); ``/wind/raw`` goes to both.
RAW_PREFIXES = ("/camera/", "/cam/", "/sceneflow/flow", "/sceneflow/disparity",
                "/sceneflow/velocity", "/sceneflow/mask")
BOTH = ("/wind/raw",)


def raw_config(rc: RecordingConfig) -> RecordingConfig:
    """The raw buffer's recorder settings."""
    return dataclasses.replace(rc, dir=Path(rc.dir) / "raw", quota_gb=rc.raw_quota_gb,
                               rotate_s=rc.raw_rotate_s)


def data_config(rc: RecordingConfig) -> RecordingConfig:
    """The long-term data recorder's settings."""
    return dataclasses.replace(rc, dir=Path(rc.dir) / "data")


class SplitRecorder:
    """Two recorders behind one ``record``: raw buffer and long-term data (module docstring).

    Parameters
    ----------
    rc : RecordingConfig
    metadata : mapping
        Metadata records of every file (both recorders).
    on_raw_file_closed : callable, optional
        Polled after every raw write batch (event clips link closed files).
    """

    def __init__(self, rc: RecordingConfig, metadata: Mapping[str, Mapping[str, str]],
                 **kwargs: Any) -> None:
        self.raw = Recorder(raw_config(rc), metadata, **kwargs)
        self.data = Recorder(data_config(rc), metadata, **kwargs)

    def start(self) -> SplitRecorder:
        self.raw.start()
        self.data.start()
        return self

    def record(self, topic: str, schema: MessageSchema, payload: bytes, log_time_ns: int,
               publish_time_ns: int | None = None) -> bool:
        """Queue one message on the recorder its topic belongs to; never blocks."""
        if topic in BOTH:
            ok = self.raw.record(topic, schema, payload, log_time_ns, publish_time_ns)
            return self.data.record(topic, schema, payload, log_time_ns, publish_time_ns) and ok
        target = self.raw if topic.startswith(RAW_PREFIXES) else self.data
        return target.record(topic, schema, payload, log_time_ns, publish_time_ns)

    def stats(self) -> RecorderStats:
        """Both recorders' counters added up (paused when either is)."""
        a, b = self.raw.stats(), self.data.stats()
        out = RecorderStats()
        for f in dataclasses.fields(RecorderStats):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if isinstance(x, bool):
                setattr(out, f.name, x or y)
            elif isinstance(x, (int, float)):
                setattr(out, f.name, x + y)
            elif isinstance(x, dict):
                merged = dict(x)
                for k, v in y.items():
                    merged[k] = merged.get(k, 0) + v
                setattr(out, f.name, merged)
            else:
                setattr(out, f.name, f"{x}; {y}" if x and y else (x or y))
        return out

    def close(self, timeout: float = 5.0) -> bool:
        """Finish both recorders' files; False when either did not in time."""
        ok_raw = self.raw.close(timeout=timeout)
        ok_data = self.data.close(timeout=timeout)
        return ok_raw and ok_data
