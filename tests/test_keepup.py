"""The start-up 'can processing keep up' measurement."""

from __future__ import annotations

import pytest

from appliance.runtime.keepup import KeepUpCheck


def test_says_once_after_the_window_from_the_first_result() -> None:
    check = KeepUpCheck(window_s=10.0, threshold=0.9)
    assert check.observe(100.0, 1, 50) is None  # first result opens the window
    assert check.observe(105.0, 100, 60) is None
    verdict = check.observe(110.0, 200, 150)  # 199 processed, 100 skipped since the start
    assert verdict is not None
    keeps_up, message = verdict
    assert not keeps_up and "cannot keep up" in message and "67 %" in message
    assert check.observe(200.0, 300, 150) is None  # said once


def test_the_advice_names_binning_for_a_wide_camera_and_the_speed_settings() -> None:
    from appliance.runtime.keepup import keep_up_advice

    wide = keep_up_advice((640, 480), 1)
    assert "processing.parameters.binning: 2" in wide and "640x480" in wide
    assert "binning" not in keep_up_advice((640, 480), 2)
    narrow = keep_up_advice((320, 240), 1)
    assert "binning" not in narrow and "docs/performance.md" in narrow
    assert "rendering" not in wide
    rendering = keep_up_advice((320, 240), 1, rendering=True)
    assert rendering.startswith("the simulated scene was rendering in a background process")
    assert "ogiflow run --prepare" in rendering and rendering.endswith(narrow)
    check = KeepUpCheck(window_s=1.0, advice=wide)
    check.observe(0.0, 1, 0)
    verdict = check.observe(2.0, 10, 30)
    assert verdict is not None and not verdict[0] and verdict[1].endswith(wide)


def test_keeping_up_is_reported_too() -> None:
    check = KeepUpCheck(window_s=5.0)
    check.observe(0.0, 1, 0)
    verdict = check.observe(6.0, 180, 3)
    assert verdict is not None and verdict[0] and "keeps up" in verdict[1]


@pytest.mark.parametrize("kwargs", [{"window_s": 0.0}, {"threshold": 0.0}, {"threshold": 1.5}])
def test_bad_settings_raise(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        KeepUpCheck(**kwargs)


def test_stage_times_give_medians_and_the_slowest_stage() -> None:
    from appliance.runtime.keepup import StageTimes

    times = StageTimes(keep=3)
    assert times.describe() is None  # nothing measured yet
    for k in range(5):  # only the last 3 count: 20, 30, 40 ms of flow
        times.add({"preprocess": 10.0, "flow": 10.0 * k, "total": 10.0 + 10.0 * k})
    times.add({"preprocess": 10.0, "total": 50.0})  # a stage may be missing from a result
    med = times.medians()
    assert med == {"preprocess": 10.0, "flow": 30.0, "total": 50.0}  # 40, 50, 50
    text = times.describe()
    assert text is not None and text.startswith("chain 50.0 ms per triple")
    assert "median of the last 3" in text and "flow 30.0" in text and "slowest flow" in text
