"""Replay back ends: image folders and video files through the camera interface."""

from __future__ import annotations

import contextlib
import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from appliance.runtime.clock import ClockModel
from appliance.runtime.pairing import StereoPairer
from drivers.camera import (
    CameraBackendMissing,
    CameraError,
    EndOfStream,
    Frame,
    create_camera,
)


def _texture(k: int, shape=(240, 320), dtype=np.uint16) -> np.ndarray:
    rng = np.random.default_rng(k)
    hi = 60000 if dtype == np.uint16 else 250
    return rng.integers(0, hi, shape).astype(dtype)


def _grab_all(cam, timeout: float = 2.0) -> list[Frame]:
    """Every frame of an opened camera, up to its end of stream."""
    frames = []
    while True:
        try:
            frames.append(cam.grab(timeout))
        except EndOfStream:
            return frames


def _drain(cam, timeout: float = 2.0) -> list[Frame]:
    with cam:
        return _grab_all(cam, timeout)


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    d = tmp_path / "left"
    d.mkdir()
    for k in range(8):
        assert cv2.imwrite(str(d / f"img_{k:03d}.png"), _texture(k))
    (d / "img_003b.png").write_bytes(b"not a png")  # corrupt: skipped and counted
    assert cv2.imwrite(str(d / "img_005b.tif"), _texture(99, (10, 10)))  # wrong size: skipped
    (d / "notes.txt").write_text("ignored: not an image suffix")
    return d


def test_folder_replay_delivers_every_good_image_in_order(folder: Path) -> None:
    cam = create_camera("replay_folder", path=folder, fps=30.0, pace=False)
    frames = _drain(cam)
    assert len(frames) == 8
    for k, f in enumerate(frames):
        assert f.pixel_format == "Mono16" and f.image.dtype == np.uint16
        np.testing.assert_array_equal(f.image, _texture(k))
        assert f.seq == k and f.device_frame_id == k
    assert np.all(np.diff([f.host_ns for f in frames]) == round(1e9 / 30))
    assert cam.stats.skipped == 2


def test_folder_replay_takes_the_folders_frame_interval_unless_told(folder: Path) -> None:
    """A folder's labels.json frame_interval_s (GasVid: 1 s) sets the frames' times; the
    fps option wins over it; without either, 30 frames/s."""
    assert np.all(np.diff([f.host_ns for f in _drain(create_camera(
        "replay_folder", path=folder, pace=False))]) == round(1e9 / 30))
    (folder / "labels.json").write_text('{"frame_interval_s": 1.0}')
    own = _drain(create_camera("replay_folder", path=folder, pace=False))
    assert len(own) == 8 and np.all(np.diff([f.host_ns for f in own]) == 10**9)
    told = _drain(create_camera("replay_folder", path=folder, fps=5.0, pace=False))
    assert np.all(np.diff([f.host_ns for f in told]) == 2 * 10**8)
    (folder / "labels.json").write_text('{"frame_interval_s": "soon"}')  # unusable: 30/s
    assert np.all(np.diff([f.host_ns for f in _drain(create_camera(
        "replay_folder", path=folder, pace=False))]) == round(1e9 / 30))


def test_folder_replay_paced_and_looping(folder: Path) -> None:
    cam = create_camera(
        "replay_folder", path=folder, fps=200.0, pattern="img_00?.png", pace=True, loop=True
    )
    with cam:
        frames = [cam.grab(1.0) for _ in range(20)]  # 8 images, looped
    np.testing.assert_array_equal(frames[9].image, frames[1].image)
    assert [f.seq for f in frames] == list(range(20))


def test_folder_replay_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="not a folder"):
        create_camera("replay_folder", path=tmp_path / "missing").open()
    with pytest.raises(CameraError, match=r"no .*png"):
        create_camera("replay_folder", path=tmp_path).open()


def test_two_folders_replayed_fast_pair_frame_by_frame(tmp_path: Path) -> None:
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for k in range(12):
            cv2.imwrite(str(tmp_path / side / f"{k:04d}.png"), _texture(k + (side == "right")))
    cams = {
        s: create_camera("replay_folder", path=tmp_path / s, pace=False) for s in ("left", "right")
    }
    period = round(1e9 / 30)
    pairer: StereoPairer = StereoPairer(period)
    # Both cameras start before either is read: draining one first moved the other's start
    # (and so its nominal timeline) by the reading time, half a period on a loaded machine.
    with contextlib.ExitStack() as stack:
        for c in cams.values():
            stack.enter_context(c)
        frames = {s: _grab_all(c) for s, c in cams.items()}
    clocks = {s: ClockModel() for s in cams}
    pairs = []
    # replayed fast, each camera stamps its nominal timeline from its own start(); the two
    # starts are microseconds apart, far inside the tolerance
    for s in ("left", "right"):
        for f in frames[s]:
            pairs += pairer.push(s, clocks[s].update(f.host_ns, f.device_ts_ns), f.seq)
    pairs += pairer.flush()
    assert [(p.left, p.right) for p in pairs] == [(k, k) for k in range(12)]


@pytest.mark.parametrize(
    "fourcc,suffix,lossless", [("MJPG", ".avi", False), ("FFV1", ".mkv", True)]
)
def test_video_file_through_opencv(
    tmp_path: Path, fourcc: str, suffix: str, lossless: bool
) -> None:
    path = tmp_path / f"clip{suffix}"
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter.fourcc(*fourcc), 30.0, (320, 240), isColor=False
    )
    assert writer.isOpened(), f"OpenCV cannot write {fourcc}"
    written = []
    for k in range(15):
        img = cv2.GaussianBlur(_texture(k, dtype=np.uint8), (0, 0), 2.0)  # compressible
        written.append(img)
        writer.write(img)
    writer.release()
    cam = create_camera("opencv", source=str(path), pace=False)
    frames = _drain(cam)
    assert len(frames) == 15
    assert [f.device_frame_id for f in frames] == list(range(15))
    assert all(f.device_ts_ns is None for f in frames)  # no capture time in a file
    assert all(b.host_ns > a.host_ns for a, b in itertools.pairwise(frames))
    for f, img in zip(frames, written, strict=True):
        assert f.pixel_format == "Mono8" and f.image.shape == (240, 320)
        diff = np.abs(f.image.astype(int) - img.astype(int)).mean()
        assert diff == 0 if lossless else diff < 4.0


def test_video_file_paced_loops(tmp_path: Path) -> None:
    path = tmp_path / "short.avi"
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter.fourcc(*"MJPG"), 100.0, (64, 48), isColor=False
    )
    for k in range(3):
        writer.write(np.full((48, 64), 40 * k, np.uint8))
    writer.release()
    cam = create_camera("opencv", source=str(path), pace=True, loop=True)
    with cam:
        frames = [cam.grab(1.0) for _ in range(7)]
    assert [f.device_frame_id for f in frames] == list(range(7))
    assert abs(float(frames[3].image.mean()) - float(frames[0].image.mean())) < 2


def test_opencv_missing_file_and_bad_options(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="no such video file"):
        create_camera("opencv", source=str(tmp_path / "none.avi")).open()
    with pytest.raises(ValueError, match="api"):
        create_camera("opencv", source=0, api="dshow")


def test_registry_names_unknown_backends_and_options() -> None:
    with pytest.raises(ValueError, match=r"unknown camera back end 'gige'.*aravis"):
        create_camera("gige")
    with pytest.raises(ValueError, match=r"no option.*fsp"):
        create_camera("replay_folder", path=".", fsp=30)
    assert issubclass(CameraBackendMissing, ImportError)


def test_frame_rejects_mismatched_image() -> None:
    with pytest.raises(ValueError, match="Mono16 frame needs a 2-D uint16"):
        Frame(image=np.zeros((4, 4), np.uint8), pixel_format="Mono16", host_ns=0, seq=0)
    with pytest.raises(ValueError, match="unknown pixel format"):
        Frame(image=np.zeros((4, 4), np.uint8), pixel_format="RGB8", host_ns=0, seq=0)
