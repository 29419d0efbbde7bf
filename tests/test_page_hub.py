"""The operator page's pictures when the cameras feed the hub: the camera's newest frame with
the newest processed result's gas drawn on it, and what the page is told of both ages."""

from __future__ import annotations

import time

import numpy as np
import pytest

from appliance.live.items import LiveFrame
from appliance.page.hub import OVERLAY_MAX_AGE_S, PageHub

SHAPE = (48, 64)


def _wait(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


def _result(t_ns: int, camera: str = "left") -> LiveFrame:
    mask = np.zeros(SHAPE, bool)
    mask[10:20, 30:50] = True
    return LiveFrame(frame=7, t_capture_ns=t_ns + 33_000_000, raw_left=np.zeros(SHAPE, np.uint16),
                     gas_mask=mask, pixels=np.array([[35.0, 15.0]]),
                     velocity3d=np.array([[1.0, -0.5, 0.2]]), raw_capture_ns=t_ns, camera=camera)


def _camera_image(level: int = 2000) -> np.ndarray:
    return np.full(SHAPE, level, np.uint16)


@pytest.fixture
def hub():
    h = PageHub(max_image_hz=1000.0, jpeg_quality=90).start()
    yield h
    h.close()


def _picture(hub: PageHub, seq_before: int) -> dict:
    _wait(lambda: hub.newest_frame() is not None and hub.newest_frame().seq > seq_before)
    return hub.newest_frame().notice()


def test_the_picture_is_the_cameras_newest_frame_with_the_results_gas(hub: PageHub) -> None:
    t0 = time.time_ns()
    hub.push(_result(t0 - 400_000_000))  # before any camera frame: a picture of its own
    first = _picture(hub, 0)
    assert first["frame"] == 7 and first["overlay_capture_ns"] == t0 - 400_000_000
    time.sleep(0.002)
    assert hub.push_camera("left", _camera_image(), 1234, t0)
    f = _picture(hub, first["seq"])
    assert f["frame"] == 1234 and f["camera"] == "left"
    assert f["t_capture_ns"] == t0  # the camera frame's own capture time, not the result's
    assert f["overlay_capture_ns"] == t0 - 400_000_000
    assert f["t_result_ns"] >= t0 - 1_000_000_000
    # the result from now on only feeds the overlay: no picture of its own
    seq = f["seq"]
    assert hub.push(_result(t0 - 100_000_000))
    time.sleep(0.1)
    assert hub.newest_frame().seq == seq
    time.sleep(0.002)
    hub.push_camera("left", _camera_image(), 1235, t0 + 33_000_000)
    assert _picture(hub, seq)["overlay_capture_ns"] == t0 - 100_000_000


def test_the_gas_is_drawn_on_the_picture(hub: PageHub) -> None:
    import cv2

    t0 = time.time_ns()
    hub.push_camera("left", _camera_image(), 1, t0)
    bare = _picture(hub, 0)
    hub.push(_result(t0 - 200_000_000))
    time.sleep(0.002)
    hub.push_camera("left", _camera_image(), 2, t0 + 33_000_000)
    drawn = _picture(hub, bare["seq"])
    assert bare["overlay_capture_ns"] is None and drawn["overlay_capture_ns"] is not None

    def img(n: dict) -> np.ndarray:
        enc = hub.frame(n["seq"])
        return cv2.imdecode(np.frombuffer(enc.jpeg, np.uint8), cv2.IMREAD_COLOR)

    a, b = img(bare).astype(int), img(drawn).astype(int)
    gas = np.abs(b[12:18, 32:48] - a[12:18, 32:48]).mean()
    elsewhere = np.abs(b[30:45, 2:20] - a[30:45, 2:20]).mean()
    assert gas > 20 and elsewhere < 3, (gas, elsewhere)


@pytest.mark.parametrize("why", ["too old", "other camera", "other size"])
def test_an_overlay_that_does_not_belong_to_the_picture_is_left_off(hub: PageHub,
                                                                     why: str) -> None:
    t0 = time.time_ns()
    hub.push_camera("left", _camera_image(), 1, t0)
    seq = _picture(hub, 0)["seq"]
    res = {"too old": _result(t0 - int((OVERLAY_MAX_AGE_S + 0.5) * 1e9)),
           "other camera": _result(t0 - 100_000_000, camera="right"),
           "other size": LiveFrame(frame=1, t_capture_ns=t0, raw_left=np.zeros((8, 8)),
                                   gas_mask=np.ones((8, 8), bool), raw_capture_ns=t0)}[why]
    hub.push(res)
    time.sleep(0.002)
    hub.push_camera("left", _camera_image(), 2, t0 + 33_000_000)
    assert _picture(hub, seq)["overlay_capture_ns"] is None
    assert hub.stats().without_overlay == 2


def test_pictures_are_taken_at_the_page_rate_and_the_image_is_copied() -> None:
    hub = PageHub(max_image_hz=2.0).start()
    try:
        image = _camera_image(1000)
        t0 = time.time_ns()
        assert hub.push_camera("left", image, 1, t0)
        assert not hub.push_camera("left", image, 2, t0 + 1)  # 0.5 s not yet over
        image[:] = 3000  # the camera reuses its buffer
        _wait(lambda: hub.newest_frame() is not None)
        assert hub.stats().camera_frames == 1
        # with a camera feed no full fields are wanted: a result without them (no raw
        # frame) still brings its gas mask for the overlay
        assert not hub.wants_pictures()
        bare = _result(t0)
        bare.raw_left = None
        assert hub.push(bare)
    finally:
        hub.close()
    import cv2

    enc = hub.newest_frame()
    grey = cv2.imdecode(np.frombuffer(enc.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert grey.std() < 2  # one level: the copy, not the overwritten buffer's change
