"""d' coherence along the flow (processing.stereo.coherence): values land where gas moved."""

from __future__ import annotations

import numpy as np
import pytest

from processing.stereo.coherence import carry_along_flow, smooth_disparity_change


def test_carry_along_a_uniform_flow_shifts_the_field() -> None:
    prev = np.zeros((20, 30), np.float32)
    prev[10, 5] = 1.0
    flow = np.zeros((20, 30, 2), np.float32)
    flow[..., 0] = 3.0  # the gas moved 3 px right since the previous triple
    aligned, inside = carry_along_flow(prev, flow)
    assert aligned[10, 8] == pytest.approx(1.0) and aligned[10, 5] == pytest.approx(0.0)
    assert not inside[:, :3].any() and inside[:, 3:].all()


def test_smoothing_blends_history_and_keeps_new_gas() -> None:
    dd = np.full((8, 8), 0.2, np.float32)
    prev = np.full((8, 8), -0.2, np.float32)
    flow = np.zeros((8, 8, 2), np.float32)
    flow[..., 0] = 2.0
    out = smooth_disparity_change(dd, prev, flow, 0.7)
    assert out[:, 2:] == pytest.approx(0.3 * 0.2 + 0.7 * -0.2)
    assert out[:, :2] == pytest.approx(0.2)  # came from outside the image: kept as it is
    assert np.array_equal(smooth_disparity_change(dd, None, flow, 0.7), dd)
    with pytest.raises(ValueError):
        smooth_disparity_change(dd, prev, flow, 1.0)
