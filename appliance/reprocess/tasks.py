"""Bodies of the reprocessing tasks; plain functions (Ray runs them, tests may call them).

Each returns a small dict (picklable, JSON-able) and writes its files atomically, so a
task killed at any point leaves nothing that looks finished and can simply run again.
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path
from typing import Any

from appliance.recording.tables import SUMMARY_COLUMNS, summary_row, write_parquet
from appliance.reprocess.jobs import Job
from appliance.reprocess.segments import Segment, cut_segments, process_into, replay_parameters
from appliance.reprocess.sink import McapSink
from appliance.reprocess.source import (
    PairStream,
    Recording,
    load_geometry,
    read_wind,
)
from appliance.runtime.workers import single_threaded
from drivers.camera.base import CameraError


def plan_task(job: Job) -> dict[str, Any]:
    """Cut ``job.input`` into segments: pairs it by the appliance's rules, once.

    Returns ``{"segments": [[first, stop], ...], "pairs", "truncated", "appliance_id",
    "output_meta"}`` or ``{"error": text}`` for an unreadable input.
    """

    try:
        rec = Recording.open(job.input)
        pairs = PairStream(rec)
        times = [p.time_ns for _i, p in pairs]
    except (ValueError, OSError, CameraError) as exc:
        return {"error": f"{job.input}: {exc}"}
    segments = cut_segments(times, job.segment_s)
    return {"segments": [[s.first, s.stop] for s in segments], "pairs": len(times),
            "truncated": pairs.truncated, "appliance_id": rec.appliance_id}


def segment_paths(seg_dir: Path, index: int) -> tuple[Path, Path, Path]:
    """The segment's result MCAP, its summary rows (Parquet) and its attempts log."""
    stem = seg_dir / f"seg-{index:05d}"
    return stem.with_suffix(".mcap"), stem.with_suffix(".parquet"), stem.with_suffix(".attempts")


def segment_task(job: Job, index: int, first: int, stop: int, n_pairs: int, seg_dir: Path,
                 run_id: str) -> dict[str, Any]:
    """Process one segment of one job; write its results and summary rows.

    Every attempt appends ``run_id pid host`` to the segment's attempts log first (how
    retries are counted, and how a test finds the worker to kill).
    """

    single_threaded()
    seg_dir.mkdir(parents=True, exist_ok=True)
    mcap_path, rows_path, attempts = segment_paths(seg_dir, index)
    with open(attempts, "a") as f:
        f.write(f"{run_id} {os.getpid()} {socket.gethostname()}\n")
    t0 = time.monotonic()
    rec = Recording.open(job.input)
    geometry = load_geometry(rec.meta, job.calibration)
    wind = read_wind(job.input)
    params = replay_parameters(rec, dict(job.overrides), wind)
    sink = McapSink(mcap_path, {})
    segment = Segment(index, first, stop)
    try:
        report, publisher = process_into(sink, rec, geometry, params, [segment],
                                         fields_every=job.fields_every, keep_summaries=True,
                                         wind=wind)
        rows = [summary_row(s) for s in publisher.summaries]
    except BaseException:
        sink.abort()
        raise
    write_parquet(rows_path, rows, SUMMARY_COLUMNS)
    sink.close()  # last: the .mcap is what marks the segment as written
    expected = len(segment.triples(n_pairs))
    return {"segment": index, "triples": report.triples, "failed": report.failed,
            "expected": expected, "errors": report.errors[:5],
            "seconds": time.monotonic() - t0, "host": socket.gethostname()}


def merge_task(job: Job, n_segments: int, seg_dir: Path, output: Path) -> dict[str, Any]:
    """Write the job's output: metadata, raw wind, then every segment's messages in order."""

    rec = Recording.open(job.input)
    wind = read_wind(job.input)
    params = replay_parameters(rec, dict(job.overrides), wind)
    sink = McapSink(output, rec.output_metadata(params, job.segment_s))
    try:
        sink.record_wind(wind, rec.wall_offset_ns)
        for i in range(n_segments):
            sink.copy_from(segment_paths(seg_dir, i)[0])
    except BaseException:
        sink.abort()
        raise
    sink.close()
    return {"output": str(output), "messages": sink.messages}
