"""Stereo stamping (runtime.stamping.StereoStamper): clock model per camera + pairer, fed
frames the way the daemon's camera threads deliver them (interleaved, with arrival jitter)."""

from __future__ import annotations

import numpy as np

from appliance.runtime.stamping import StereoStamper
from drivers.camera.base import Frame

PERIOD_NS = 33_333_333  # 30 Hz


def _frames(side: str, n: int, *, capture_offset_ns: int, device_offset_ns: int | None,
            seed: int) -> list[Frame]:
    """Frames captured every period from ``capture_offset_ns``; the device clock (or none)
    runs at its own offset; arrival = capture + 4 ms transfer + 0..6 ms jitter."""
    rng = np.random.default_rng(seed)
    image = np.zeros((2, 2), np.uint16)
    out = []
    for i in range(n):
        t = 1_000_000_000 + capture_offset_ns + i * PERIOD_NS
        out.append(Frame(image=image, pixel_format="Mono16",
                         host_ns=t + 4_000_000 + int(rng.integers(0, 6_000_000)), seq=i,
                         device_ts_ns=None if device_offset_ns is None else t + device_offset_ns,
                         device_frame_id=None if device_offset_ns is None else i))
    return out


def _feed(stamper: StereoStamper, left: list[Frame], right: list[Frame]) -> list:
    """Push both cameras' frames in arrival order with the arrival as ``now``, then flush."""
    arrivals = sorted([("left", f) for f in left] + [("right", f) for f in right],
                      key=lambda sf: sf[1].host_ns)
    pairs = []
    for side, f in arrivals:
        pairs += stamper.push(side, f, f.host_ns)
    return pairs + stamper.flush()


def test_untriggered_cameras_with_device_clocks_pair_frame_by_frame() -> None:
    # Right camera captures 3 ms after the left; the device clocks have unrelated epochs.
    left = _frames("left", 90, capture_offset_ns=0, device_offset_ns=7 * 10**12, seed=1)
    right = _frames("right", 90, capture_offset_ns=3_000_000, device_offset_ns=-5 * 10**9,
                    seed=2)
    stamper = StereoStamper(30.0)
    pairs = _feed(stamper, left, right)
    # Each camera's first frame is stamped from its arrival alone and left unpaired.
    assert [(p.left.seq, p.right.seq) for p in pairs] == [(i, i) for i in range(1, 90)]
    # Capture times come from the clock models, not the jittered arrivals: once each model
    # has settled the residual is the true 3 ms offset, not up to 6 ms of jitter on top.
    residuals = np.array([p.right_ns - p.left_ns for p in pairs[30:]])
    assert np.all(np.abs(residuals - 3_000_000) < 1_500_000), residuals
    assert stamper.unpaired() == {"left": 1, "right": 1}


def test_a_lost_frame_is_counted_unpaired_and_the_rest_still_pair() -> None:
    left = _frames("left", 40, capture_offset_ns=0, device_offset_ns=0, seed=3)
    right = _frames("right", 40, capture_offset_ns=1_000_000, device_offset_ns=0, seed=4)
    del right[17]
    stamper = StereoStamper(30.0)
    pairs = _feed(stamper, left, right)
    assert [p.left.seq for p in pairs] == [i for i in range(1, 40) if i != 17]
    assert all(p.left.seq == p.right.seq for p in pairs)
    assert stamper.unpaired() == {"left": 2, "right": 1}  # frame 17 and the first frames


def test_cameras_without_clocks_use_the_nominal_period() -> None:
    left = _frames("left", 30, capture_offset_ns=0, device_offset_ns=None, seed=5)
    right = _frames("right", 30, capture_offset_ns=2_000_000, device_offset_ns=None, seed=6)
    pairs = _feed(StereoStamper(30.0), left, right)
    assert [(p.left.seq, p.right.seq) for p in pairs] == [(i, i) for i in range(1, 30)]


def test_tolerance_rejects_frames_too_far_apart() -> None:
    # 12 ms apart: paired with the default tolerance (half a period), not with 5 ms.
    left = _frames("left", 20, capture_offset_ns=0, device_offset_ns=0, seed=7)
    right = _frames("right", 20, capture_offset_ns=12_000_000, device_offset_ns=0, seed=8)
    assert len(_feed(StereoStamper(30.0), left, right)) == 19  # all but the first frames
    strict = StereoStamper(30.0, tolerance_s=0.005)
    assert _feed(strict, left, right) == []
    assert strict.unpaired() == {"left": 20, "right": 20}


def test_a_first_frame_delivered_late_is_not_paired_with_the_wrong_moment() -> None:
    """A camera whose start stalled delivers its first frames in a burst 20 periods late
    (the simulated camera under load did this): stamped by their arrival, those frames would
    pair with the other camera's frame of 0.67 s later, and the chain turned such
    a pair into a disparity of 112 px for 43 (measured). It stays unpaired instead."""
    left = _frames("left", 60, capture_offset_ns=0, device_offset_ns=0, seed=9)
    right = _frames("right", 60, capture_offset_ns=1_000_000, device_offset_ns=0, seed=10)
    stale = right[0]
    late = Frame(image=stale.image, pixel_format="Mono16", host_ns=right[20].host_ns - 2_000_000,
                 seq=0, device_ts_ns=stale.device_ts_ns, device_frame_id=0)
    # the frames captured during the stall come in one burst just before the present
    burst = [Frame(image=f.image, pixel_format="Mono16", host_ns=late.host_ns + 100_000 * k,
                   seq=f.seq, device_ts_ns=f.device_ts_ns, device_frame_id=f.seq)
             for k, f in enumerate(right[1:20], start=1)]
    right = [late, *burst, *right[21:]]
    stamper = StereoStamper(30.0)
    pairs = _feed(stamper, left, right)
    assert pairs and all(p.left.seq == p.right.seq for p in pairs), [
        (p.left.seq, p.right.seq) for p in pairs[:3]]
    assert pairs[0].left.seq >= 21
