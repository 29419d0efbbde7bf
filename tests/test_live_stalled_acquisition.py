"""A stalled live viewer never stalls acquisition or recording: the components together.

An acquisition thread feeds raw frames and pairs to the recorder, pairs to the ring, frames to
the live view and ticks to health, as `ogiflow run` will; the live view's Rerun call hangs
for the whole run. Every frame must still be recorded, and the worker's windows plus its
reported skips must account for every pair.
"""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from appliance.config import Config, LiveConfig, RecordingConfig
from appliance.live.view import LiveFrame, LiveView
from appliance.recording import schemas as S
from appliance.recording.metadata import file_metadata
from appliance.recording.recorder import Recorder, closed_files
from appliance.runtime.health import HealthMonitor, HealthReporter, live_sink, log_sink, mcap_sink
from appliance.runtime.ring import PairRing
from drivers.camera.base import Frame

PAIRS = 300


def test_stalled_viewer_does_not_stall_acquisition_or_recording(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rc = dataclasses.replace(RecordingConfig(), dir=tmp_path / "rec", quota_gb=None)
    recorder = Recorder(rc, file_metadata(Config())).start()
    view = LiveView(dataclasses.replace(LiveConfig(), mode="save", file=tmp_path / "l.rrd",
                                        queue_size=4))
    hang = threading.Event()
    monkeypatch.setattr(view, "_log", lambda *a, **k: hang.wait(60))  # a viewer that hangs
    view.start()
    monitor = HealthMonitor(stall_s=30)
    monitor.add_counters(lambda: {"recorder_drops": recorder.stats().messages_dropped,
                                  "live_drops": view.stats().dropped})
    reporter = HealthReporter(monitor, 0.05, [mcap_sink(recorder), live_sink(view),
                                              log_sink()]).start()
    ring = PairRing.create(8, (240, 320))
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 65535, (240, 320), dtype=np.uint16) for _ in range(4)]
    left_c, right_c = monitor.stream("cam/left"), monitor.stream("cam/right")
    done = threading.Event()

    def acquisition() -> None:
        for i in range(PAIRS):
            t = 1_700_000_000_000_000_000 + i * 33_333_333
            for side, image in (("left", frames[i % 4]), ("right", frames[(i + 1) % 4])):
                frame = Frame(image=image, pixel_format="Mono16", host_ns=t, seq=i)
                for r in S.frame_records(side, frame, t):  # as the camera threads record
                    recorder.record(r.topic, r.schema, r.payload, r.log_time_ns,
                                    r.publish_time_ns)
            left_c.tick()
            right_c.tick()
            pair = {"pair_index": i, "left_seq": i, "right_seq": i, "t_left_mono_ns": t,
                    "t_right_mono_ns": t, "t_mono_ns": t, "t_wall_ns": t, "dt_ns": 0}
            recorder.record("/pairs", S.STEREO_PAIR, S.encode_json(S.STEREO_PAIR, pair), t)
            ring.write(frames[i % 4], frames[(i + 1) % 4], pair_index=i, t_wall_ns=t)
            view.push(LiveFrame(frame=i, t_capture_ns=t, diff_left=frames[i % 4],
                                gas_speed_m_s=1.0))
        done.set()

    taken: list[int] = []
    skipped: list[int] = []

    def worker() -> None:
        while not done.is_set() or ring.stats().occupancy:
            lease = ring.take_newest(3)
            if lease is None:
                done.wait(0.001)
                continue
            taken.append(lease.seqs[-1])
            skipped.append(lease.skipped)
            lease.release()

    threads = [threading.Thread(target=acquisition), threading.Thread(target=worker)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)  # bounded: a hang here is the failure this test exists for
    assert done.is_set() and not any(t.is_alive() for t in threads)
    reporter.stop()
    drops_before = view.stats().dropped
    final = reporter.report()  # a final snapshot, as the daemon writes at shutdown
    assert not view.close(timeout=0.2)  # the hung viewer is abandoned, not waited for
    assert recorder.close()
    hang.set()

    live = view.stats()
    assert live.dropped > 0 and live.pushed + live.dropped >= PAIRS
    rec_stats = recorder.stats()
    assert rec_stats.messages_dropped == 0
    counts: dict[str, int] = {}
    for path in closed_files(tmp_path / "rec"):
        with open(path, "rb") as f:
            for _, channel, _ in make_reader(f).iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts["/camera/left/image"] == counts["/camera/right/image"] == PAIRS  # none lost
    assert counts["/camera/left/frame_info"] == counts["/camera/right/frame_info"] == PAIRS
    assert counts["/pairs"] == PAIRS
    assert counts["/health"] >= 1
    # every window end 2..PAIRS-1 was either processed or reported as skipped
    assert taken[-1] == PAIRS - 1
    assert len(taken) + sum(skipped) == PAIRS - 2
    assert final.counters["live_drops"] == drops_before  # health saw the live view's drops
    ring.close()
    ring.unlink()
