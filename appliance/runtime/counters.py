"""The daemon's counters as the health report shows them (one flat name -> int map)."""

from __future__ import annotations

import time
from typing import Any


def health_counters(app: Any) -> dict[str, int]:
    """Every counter of a running :class:`~appliance.runtime.daemon.Appliance` for the
    health report: frames, losses, pairs, results, queue drops, recorder, live view, ring,
    serial line, alarm sinks and each camera's levelled offset steps."""
    c = app.counters
    out = {
        "frames_left": c.frames["left"], "frames_right": c.frames["right"],
        "frames_lost_left": c.frames_lost["left"],
        "frames_lost_right": c.frames_lost["right"],
        "unpaired_left": c.unpaired["left"], "unpaired_right": c.unpaired["right"],
        "worker_restarts": c.worker_restarts,
        "pairs": c.pairs, "results": c.results, "result_errors": c.result_errors,
        "skipped_pairs": c.skipped_pairs, "cold_results": c.cold_results,
        "frame_queue_drops": c.frame_queue_drops,
        "camera_timeouts": c.camera_timeouts, "camera_reconnects": c.camera_reconnects,
        "wind_samples": c.wind_samples, "single_camera_frames": c.single_frames,
        "offset_steps_left": c.offset_steps["left"],
        "offset_steps_right": c.offset_steps["right"],
    }
    if app.acquisition is not None:
        out["degraded_s"] = int(app.acquisition.watch.degraded_s(time.monotonic_ns()))
    if app.recorder is not None:
        rs = app.recorder.stats()
        out["recorder_drops"] = int(rs.messages_dropped)
        out["recorder_write_errors"] = rs.write_errors
        out["recording_paused"] = int(rs.paused)
    if app.live is not None:
        ls = app.live.stats()
        out["live_drops"] = int(ls.dropped)
        out["live_slow_sends"] = int(ls.slow_sends)
    if app.ring is not None:
        out["ring_overwrites"] = int(app.ring.stats().overwrites)
    if getattr(app.acquisition, "anemometer", None) is not None:
        counts = app.acquisition.anemometer.counts
        out["serial_errors"] = int(counts.checksum_failures + counts.malformed)
    for sink in getattr(app.monitor, "sinks", ()):  # alarm sinks: outages, drops
        s = sink.stats()
        out.update({"alarm_connected": int(s.connected), "alarm_disconnects": s.disconnects,
                    "alarm_dropped": s.dropped, "alarm_queued": s.queued,
                    "alarm_outage_s": int(s.outage_s)})
    return out
