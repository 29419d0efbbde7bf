"""Simulated camera: timing model, frame sources, sharing, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drivers.camera import CameraError, EndOfStream, create_camera
from drivers.camera.simulated import SimulatedCamera, TimingModel, TimingParams
from drivers.camera.sources import SyntheticDirSource, TexturePatternSource, load_source


def _synthetic_dir(root: Path, n: int = 3, shape=(24, 32)) -> Path:
    d = root / "synth"
    d.mkdir()
    meta = {"format": "ogiflow-synthetic/1", "n_frames": n, "frame_interval_s": 1 / 30,
            "camera": {"width": shape[1], "height": shape[0]}}  # fmt: skip
    (d / "meta.json").write_text(json.dumps(meta))
    for i in range(n):
        left = np.full(shape, 1000 + i, np.uint16)
        np.savez(d / f"frame_{i:05d}.npz", left=left, right=left + 500)
    return d


def test_frames_come_from_the_synthetic_directory_and_loop(tmp_path: Path) -> None:
    d = _synthetic_dir(tmp_path)
    cams = {
        s: create_camera("simulated", side=s, source=d, realtime=False) for s in ("left", "right")
    }
    with cams["left"], cams["right"]:
        left = [cams["left"].grab() for _ in range(5)]
        right = [cams["right"].grab() for _ in range(5)]
    assert cams["left"].source is cams["right"].source  # one copy of the frames
    assert [int(f.image[0, 0]) for f in left] == [1000, 1001, 1002, 1000, 1001]
    assert [int(f.image[0, 0]) for f in right] == [1500, 1501, 1502, 1500, 1501]
    assert all(f.pixel_format == "Mono16" and f.image.shape == (24, 32) for f in left)


@pytest.mark.parametrize(
    "damage,match",
    [
        (lambda d: (d / "frame_00001.npz").unlink(), "frame_00001.npz: missing"),
        (
            lambda d: np.savez(
                d / "frame_00002.npz",
                left=np.zeros((5, 5), np.uint16),
                right=np.zeros((5, 5), np.uint16),
            ),
            r"left is \(5, 5\)",
        ),
        (lambda d: (d / "meta.json").write_text("{"), "not valid JSON"),
        (lambda d: (d / "meta.json").write_text('{"format": "other/2"}'), "format"),
        (lambda d: (d / "frame_00000.npz").write_bytes(b"junk"), "unreadable"),
    ],
)
def test_bad_synthetic_directories_name_the_problem(tmp_path: Path, damage, match: str) -> None:
    d = _synthetic_dir(tmp_path)
    damage(d)
    with pytest.raises(CameraError, match=match):
        SyntheticDirSource(d)


def test_timing_model_matches_its_definition() -> None:
    p = TimingParams(fps=30.0, latency_s=0.01, jitter_s=0.002, clock_offset_s=100.0,
                     drift_ppm=50.0, phase_s=0.005, seed=4)  # fmt: skip
    tm = TimingModel(p)
    ev = tm.block(0)
    period = 1e9 / 30
    assert np.allclose(np.diff(ev.device_ns), period, atol=1)  # frame timer on device clock
    true_period = period / (1 + 50e-6)
    assert np.allclose(np.diff(ev.capture_ns), true_period, atol=1)
    assert ev.capture_ns[0] == pytest.approx(5e6, abs=1)
    delay = ev.arrival_ns - ev.capture_ns
    assert delay.min() >= 10_000_000 and np.median(delay) < 10_000_000 + 3_000_000
    assert np.all(np.diff(ev.arrival_ns) >= 0)  # in-order delivery
    assert np.array_equal(TimingModel(p).block(0).arrival_ns, ev.arrival_ns)  # reproducible


def test_drops_are_reported_as_lost_with_a_frame_id_gap() -> None:
    cam = create_camera("simulated", drop_rate=0.3, realtime=False, seed=5, max_frames=200)
    with cam:
        frames = []
        with pytest.raises(EndOfStream):
            while True:
                frames.append(cam.grab())
    ids = [f.device_frame_id for f in frames]
    gaps = np.diff([-1, *ids]) - 1
    assert [f.lost for f in frames] == gaps.tolist()
    assert 30 < sum(gaps) < 130
    assert cam.stats.lost == sum(gaps)


def test_image_jitter_shifts_by_subpixels_and_clockless_mode() -> None:
    src = TexturePatternSource(n_frames=2)
    cam = create_camera("simulated", source=src, image_jitter_px=0.3, device_clock=False,
                        realtime=False)  # fmt: skip
    with cam:
        f = cam.grab()
    ref = src.stereo(0)[0].astype(float)
    diff = np.abs(f.image.astype(float) - ref)
    assert 0 < diff.mean() < 100  # shifted a little, not replaced
    assert f.device_ts_ns is None and f.device_frame_id == 0


def test_a_flat_field_shutter_steps_the_whole_picture_up_and_back() -> None:
    """Every 0.1 s (3 frames at 30 Hz) the picture's offset steps by 300 counts, up and
    back down in turn, saturating at the format's top; a bad setting is refused."""
    src = TexturePatternSource(n_frames=4)
    cam = create_camera("simulated", source=src, shutter_every_s=0.1, shutter_counts=300,
                        drop_rate=0.0, realtime=False)
    with cam:
        frames = [cam.grab() for _ in range(12)]
    for f in frames:
        k = f.device_frame_id
        ref = src.stereo(k)[0].astype(np.int64)
        step = 300 if (k // 3) % 2 else 0
        expected = np.minimum(ref + step, np.iinfo(f.image.dtype).max)
        np.testing.assert_array_equal(f.image.astype(np.int64), expected, err_msg=str(k))
    assert {(f.device_frame_id // 3) % 2 for f in frames} == {0, 1}
    for bad in ({"shutter_every_s": 0.0}, {"shutter_every_s": 1.0, "shutter_counts": 0}):
        with pytest.raises(ValueError, match="shutter"):
            create_camera("simulated", source=src, realtime=False, **bad)


def test_a_shutter_can_leave_a_new_fixed_pattern_each_time() -> None:
    """With ``shutter_pattern_counts`` every shutter interval adds its own white fixed
    pattern (the residual non-uniformity of that correction): the same within an interval,
    another in the next, about that standard deviation; the offset still alternates."""
    src = TexturePatternSource(n_frames=4)
    cam = create_camera("simulated", source=src, shutter_every_s=0.1, shutter_counts=300,
                        shutter_pattern_counts=20.0, drop_rate=0.0, realtime=False)
    with cam:
        frames = [cam.grab() for _ in range(9)]
    added = [f.image.astype(np.float64) - src.stereo(f.device_frame_id)[0] for f in frames]
    by_interval = {}
    for f, a in zip(frames, added, strict=True):
        by_interval.setdefault(f.device_frame_id // 3, []).append(a)
    for interval, patterns in by_interval.items():
        for a in patterns[1:]:
            np.testing.assert_array_equal(a, patterns[0])  # fixed within the interval
        step = 300 if interval % 2 else 0
        assert abs(np.median(patterns[0]) - step) < 2, interval
        assert 18 < np.std(patterns[0]) < 22, interval
    first, second = by_interval[0][0], by_interval[2][0]
    assert abs(np.corrcoef(first.ravel(), second.ravel())[0, 1]) < 0.05  # a new pattern


def test_realtime_mode_delivers_live_frames() -> None:
    cam = create_camera("simulated", fps=100.0, latency_s=0.001, jitter_s=0.0005)
    with cam:
        frames = [cam.grab(1.0) for _ in range(3)]
    assert [f.seq for f in frames] == [0, 1, 2]
    assert frames[0].device_frame_id + 2 == frames[2].device_frame_id


def test_pattern_source_is_shared_and_read_only() -> None:
    a, b = load_source("pattern"), load_source("pattern")
    assert a is b
    left, right = a.stereo(0)
    assert left.dtype == np.uint16 and left.shape == (240, 320)
    assert not left.flags.writeable
    np.testing.assert_array_equal(left[:, :-8], right[:, 8:])  # constant disparity


def test_outage_disconnects_refuses_to_open_and_skips_its_frames() -> None:
    """``outage_after_s``/``outage_s``: the fault injection the daemon tests use."""
    import time

    from drivers.camera.base import CameraDisconnected

    label = f"outage-{time.monotonic_ns()}"
    cam = SimulatedCamera("left", "pattern", outage_after_s=0.3, outage_s=0.4, label=label)
    cam.open()
    cam.start()
    ids = []
    with pytest.raises(CameraDisconnected):
        for _ in range(100):
            ids.append(cam.grab(1.0).device_frame_id)
    cam.close()
    again = SimulatedCamera("left", "pattern", outage_after_s=0.3, outage_s=0.4, label=label)
    with pytest.raises(CameraDisconnected):
        again.open()  # still away
    time.sleep(0.45)
    again.open()
    again.start()
    first = again.grab(1.0).device_frame_id
    again.close()
    assert 5 <= len(ids) <= 12  # ~0.3 s of frames at 30 Hz
    assert first - ids[-1] >= 10  # the ~0.4 s outage's frames were never delivered
