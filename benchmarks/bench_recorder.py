"""Recorder throughput and queue headroom at the appliance's stereo rate.

Run from the repository root: PYTHONPATH=. python benchmarks/bench_recorder.py [--pairs N]

Frames are encoded as the daemon's camera threads encode them (``schemas.frame_records``:
RawImage + frame info per frame, by ``drivers.camera.mcap_format``), in the producer loop.

1. Unpaced: N pairs of noisy 320x240 uint16 frames as fast as the producer can serialize
   them; reports the writer's pairs/s (after warm-up) and its ratio to the 30 pairs/s needed.
2. Paced at 2 x 30 Hz for the same N pairs: reports drops and the queue's peak depth against
   its capacity (the "never full in normal operation" claim).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from appliance.config import RecordingConfig
from appliance.recording import schemas as S
from appliance.recording.recorder import Recorder, closed_files
from drivers.camera.base import Frame

#: Messages per camera frame: RawImage + frame info.
MESSAGES_PER_FRAME = 2


def _frames(n: int) -> list[Frame]:
    rng = np.random.default_rng(0)
    base = rng.integers(7000, 9000, (240, 320), dtype=np.uint16)
    return [Frame(image=base + rng.integers(0, 64, (240, 320), dtype=np.uint16),
                  pixel_format="Mono16", host_ns=i, seq=i) for i in range(n)]


def _record(rec: Recorder, side: str, frame: Frame, t: int) -> None:
    for r in S.frame_records(side, frame, t):
        rec.record(r.topic, r.schema, r.payload, r.log_time_ns, r.publish_time_ns)


def run(pairs: int, paced: bool, frames: list[Frame]) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as d:
        rc = dataclasses.replace(RecordingConfig(), dir=Path(d), quota_gb=None)
        rec = Recorder(rc).start()
        # warm-up: first file, schema registration, zstd context
        for i in range(10):
            _record(rec, "left", frames[i % len(frames)], i)
        while rec.stats().queue_depth:
            time.sleep(0.01)
        w0 = rec.stats().messages_written
        t0 = time.perf_counter()
        for i in range(pairs):
            _record(rec, "left", frames[i % len(frames)], i)
            _record(rec, "right", frames[(i + 1) % len(frames)], i)
            if paced:
                time.sleep(max(0.0, t0 + (i + 1) / 30 - time.perf_counter()))
        while rec.stats().queue_depth:
            time.sleep(0.001)
        elapsed = time.perf_counter() - t0
        st = rec.stats()
        rec.close()
        size = sum(p.stat().st_size for p in closed_files(Path(d)))
        raw = st.messages_written / MESSAGES_PER_FRAME * 240 * 320 * 2
        per_pair = 2 * MESSAGES_PER_FRAME
        return {"pairs_per_s": (st.messages_written - w0) / per_pair / elapsed,
                "drops": st.messages_dropped, "queue_peak": st.queue_peak,
                "queue_capacity": rc.queue_size, "ratio_vs_raw": size / raw}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pairs", type=int, default=300)
    args = ap.parse_args()
    frames = _frames(16)
    fast = run(args.pairs, False, frames)
    print(f"unpaced: writer {fast['pairs_per_s']:.0f} pairs/s = "
          f"{fast['pairs_per_s'] / 30:.1f}x the 30 pairs/s needed; file/raw size "
          f"{fast['ratio_vs_raw']:.2f}; drops {fast['drops']:.0f}")
    paced = run(args.pairs, True, frames)
    print(f"paced 2x30 Hz for {args.pairs / 30:.0f} s: drops {paced['drops']:.0f}, queue peak "
          f"{paced['queue_peak']:.0f} of {paced['queue_capacity']:.0f}")


if __name__ == "__main__":
    main()
