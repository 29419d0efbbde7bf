"""Acquisition and publishing in isolation: wind recording, pairing under a lagging pairing
thread, and memory that must not grow with the number of frames or results."""

from __future__ import annotations

import threading
import time
import tracemalloc
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appliance.config import load_config
from appliance.runtime.acquisition import Acquisition, Counters
from appliance.runtime.health import HealthMonitor
from appliance.runtime.publishing import ResultPublisher
from appliance.runtime.stamping import StereoStamper
from appliance.runtime.worker_result import WorkerResult
from drivers.anemometer.base import WindSample
from drivers.camera.base import Frame


@dataclass
class FakePublisher:
    records: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    pairs: list[int] = field(default_factory=list)

    def record_json(self, topic: str, schema: Any, obj: dict[str, Any], mono_ns: int) -> None:
        self.records.append((topic, obj))

    def record_pair(self, index: int, p: Any) -> None:
        self.pairs.append(index)


class FakeRing:
    def write(self, *args: Any, **kwargs: Any) -> None:
        pass


def _acquisition(publisher: FakePublisher) -> Acquisition:
    cfg = load_config(None, [("live.mode", "off")])
    return Acquisition(cfg, Counters(), HealthMonitor(), threading.Event(), lambda ns: ns,
                       site=None, recorder=None, publisher=publisher,  # type: ignore[arg-type]
                       ring=FakeRing(), watchdog=None)


def test_a_failed_wind_axis_is_recorded_as_null_not_as_calm() -> None:
    """A 2-D sensor or a failed axis gives NaN: the raw record says null, never 0.0 m/s."""
    pub = FakePublisher()
    acq = _acquisition(pub)
    acq.on_wind(WindSample(host_ns=1, counter=None, u=1.5, v=float("nan"), w=float("inf"),
                           speed_of_sound=float("nan"), sonic_temperature=20.0,
                           status_code=0, status_text="", valid=False))
    (topic, obj), = pub.records
    assert topic == "/wind/raw"
    assert obj["u"] == 1.5 and obj["v"] is None and obj["w"] is None
    assert obj["speed_of_sound_m_s"] is None and obj["valid"] is False


def _frame(host_ns: int, seq: int) -> Frame:
    return Frame(image=np.zeros((4, 4), np.uint16), pixel_format="Mono16", host_ns=host_ns,
                 seq=seq, device_ts_ns=seq * 33_333_333, device_frame_id=seq)


def test_a_lagging_pairing_thread_still_pairs_frames_that_arrived_together() -> None:
    """Both frames of each pair arrived on time, but the pairing thread takes them from its
    queue 0.6 s later (a busy machine): none may be given up as unpaired."""
    pub = FakePublisher()
    acq = _acquisition(pub)
    t0 = time.monotonic_ns() - 600_000_000
    for k in range(10):
        for side, offset in (("left", 0), ("right", 1_000_000)):
            acq._frame_q.put((side, _frame(t0 + k * 33_333_333 + offset, k)))
    acq.stop_event.set()  # drain what is queued, then return
    acq.pairing_loop()
    # only each camera's first frame (stamped from its arrival alone) is left unpaired
    assert acq.counters.unpaired == {"left": 1, "right": 1}
    assert pub.pairs == list(range(9))


def test_unpaired_frames_are_not_kept() -> None:
    """While one camera is away the other's frames are released unpaired: counted, and not
    kept with their images (that grew the daemon by a camera's frame rate)."""
    stamper = StereoStamper(30.0, max_delay_s=0.1)
    for k in range(200):
        stamper.push("left", _frame(k * 33_333_333, k), now_ns=k * 33_333_333)
    assert stamper.unpaired()["left"] >= 190
    assert stamper.pairer.take_unpaired() == []


def test_publishing_results_does_not_grow_memory() -> None:
    """The truth comparison keeps running sums, not every result (65 MB/h before)."""
    pub = ResultPublisher(None, None, lambda ns: ns, fields_every=10,
                          truth_for=lambda i: np.array([1.0, 0.0, 0.2]))

    def result(i: int) -> WorkerResult:
        return WorkerResult(worker=0, pair_indices=(i, i + 1, i + 2), t_mono_ns=(i, i + 1, i + 2),
                            t_wall_ns=i, skipped=0, done_mono_ns=i + 3,
                            summary={"valid": True, "mean_velocity": [1.1, 0.0, 0.2],
                                     "speed": 1.1, "angles_deg": [10.0, 90.0, 80.0],
                                     "gas_pixel_count": 100, "c_usf": 0.9, "flags": []})

    for i in range(200):  # warm-up: caches, interned strings
        pub.publish(result(i))
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i in range(200, 5200):
        pub.publish(result(i))
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    comparison = pub.truth_comparison()
    assert comparison is not None and comparison["frames"] == 5200
    assert abs(comparison["measured_m_s"][0] - 1.1) < 1e-9
    assert grown < 50_000, f"{grown} bytes kept for 5000 results"
