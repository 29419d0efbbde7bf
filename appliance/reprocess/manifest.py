"""The manifest of a reprocessing run: what is finished, so a re-run does only the rest.

``OUT/manifest.jsonl`` holds one JSON object per line, appended (and fsynced) by the
driver only, when something is finished:

- ``{"kind": "plan", "job": key, ...}``: the input's segments (pair ranges), so a re-run
  need not read the input again to cut it;
- ``{"kind": "segment", "job": key, "segment": i, ...}``: segment i's results are in
  ``OUT/.segments/<key>/seg-<i>.mcap`` (and ``.parquet``), written atomically by its task;
- ``{"kind": "merged", "job": key, "output": path}``: the job's output file is complete.

A line torn by a crash is ignored (that piece is simply done again). A segment counts as
finished only when its line *and* its files exist.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


class Manifest:
    """Read the finished work of earlier runs and append new entries."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.path = out_dir / "manifest.jsonl"
        self.plans: dict[str, dict[str, Any]] = {}
        self.segments: dict[tuple[str, int], dict[str, Any]] = {}
        self.merged: dict[str, dict[str, Any]] = {}
        if self.path.is_file():
            for line in self.path.read_text().splitlines():
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError:
                    continue  # torn by a crash while appending
                self._index(entry)

    def _index(self, entry: dict[str, Any]) -> None:
        kind = entry.get("kind")
        if kind == "plan":
            self.plans[entry["job"]] = entry
        elif kind == "segment":
            self.segments[(entry["job"], int(entry["segment"]))] = entry
        elif kind == "merged":
            self.merged[entry["job"]] = entry

    def segment_dir(self, job: str) -> Path:
        return self.out_dir / ".segments" / job

    def segment_done(self, job: str, index: int) -> bool:
        d = self.segment_dir(job)
        return ((job, index) in self.segments and (d / f"seg-{index:05d}.mcap").is_file()
                and (d / f"seg-{index:05d}.parquet").is_file())

    def merged_done(self, job: str) -> bool:
        entry = self.merged.get(job)
        return entry is not None and Path(entry["output"]).is_file()

    def append(self, entry: dict[str, Any]) -> None:
        """Add one entry durably (fsync) and index it."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            f.write(json.dumps(entry, default=str) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self._index(entry)
