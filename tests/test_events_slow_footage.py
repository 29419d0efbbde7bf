"""Leak events on footage slower than the flow can follow (one frame per second): the
occupancy map (appliance.runtime.occupancy), on synthetic gas masks with random flow."""

from __future__ import annotations

import numpy as np
import pytest

from appliance.runtime.events import EventConfig, EvidenceStream, LeakDetector
from appliance.runtime.occupancy import OccupancyModel, near_mean, persistent_plume

H, W = 240, 320
YY, XX = np.mgrid[:H, :W]
SOURCE = (120.0, 140.0)


def _plume(rng: np.random.Generator) -> np.ndarray:
    """A cone from SOURCE out of the right edge, its edge meandering from frame to frame."""
    dx = XX - SOURCE[0]
    half = 6 + 0.35 * dx + rng.normal(0, 4)
    return (dx >= 0) & (np.abs(YY - SOURCE[1] - rng.normal(0, 3)) < half)


def _cloud(k: int) -> np.ndarray:
    """Cloud texture drifting across the sky at 6 px per frame."""
    return (XX - (20 + 6 * k) % W) ** 2 / 40 ** 2 + (YY - 60) ** 2 / 25 ** 2 < 1


def _run(masks: list[np.ndarray], rng: np.random.Generator) -> LeakDetector:
    stream = EvidenceStream(frame_interval_s=1.0)
    det = LeakDetector(EventConfig())
    for k, mask in enumerate(masks):
        flow = rng.normal(0, 40, (H, W, 2))  # what the flow gives 1 s apart: noise
        det.update(stream(float(k), k, mask, flow))
    det.close(float(len(masks)), len(masks), "end of data")
    return det


def test_an_anchored_plume_is_one_event_even_when_frames_lose_it() -> None:
    """300 s of plume in which a third of the frames segment nothing (as when the plume
    fills the view): one event, its source at the apex, held to the end."""
    rng = np.random.default_rng(0)
    masks = [(_plume(rng) if rng.random() > 0.33 else np.zeros((H, W), bool))
             for _ in range(300)]
    det = _run(masks, rng)
    assert len(det.finished) == 1, [(e.start_t_s, e.end_t_s) for e in det.finished]
    ev = det.finished[0]
    assert ev.start_t_s < 60 and ev.end_reason == "end of data"
    assert np.hypot(ev.source_xy[0] - SOURCE[0], ev.source_xy[1] - SOURCE[1]) <= 10


def test_drifting_clouds_and_noise_raise_no_event() -> None:
    rng = np.random.default_rng(1)
    masks = [_cloud(k) | (rng.random((H, W)) < 0.02) for k in range(300)]
    det = _run(masks, rng)
    assert det.finished == []


def test_occupancy_decays_over_a_gap_and_the_apex_is_the_plume_start() -> None:
    rng = np.random.default_rng(2)
    model = OccupancyModel(1.0)
    for k in range(60):
        occ = model.update(float(k), _plume(rng))
    region, apex = persistent_plume(occ)
    assert region.any() and apex is not None
    assert np.hypot(apex[0] - SOURCE[0], apex[1] - SOURCE[1]) <= 10
    before = near_mean(occ, SOURCE)
    occ = model.update(100.0, np.zeros((H, W), bool))  # 40 s without frames
    assert near_mean(occ, SOURCE) == pytest.approx(before * np.exp(-40 / 20), rel=0.05)
    with pytest.raises(ValueError, match="frame interval"):
        OccupancyModel(0.0)
