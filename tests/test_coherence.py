"""d' coherence along the flow (processing.stereo.coherence): values land where gas moved."""

from __future__ import annotations

import numpy as np
import pytest

from processing.chain.state import ChainState
from processing.stereo.coherence import carry_along_flow, history_weight, smooth_disparity_change


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


def test_the_filter_starts_as_a_running_mean_until_its_memory_is_filled() -> None:
    assert [history_weight(0.7, n) for n in range(5)] == pytest.approx(
        [0.0, 0.5, 2 / 3, 0.7, 0.7])
    assert history_weight(0.0, 4) == 0.0
    # Three triples of a still scene: after the third each weighs a third, where the plain
    # exponential filter left the first (the one without history) 0.49.
    flow = np.zeros((6, 6, 2), np.float32)
    values = [0.6, 0.0, 0.3]
    smoothed, n = None, 0
    for v in values:
        dd = np.full((6, 6), v, np.float32)
        smoothed = smooth_disparity_change(dd, smoothed, flow, history_weight(0.7, n))
        n += 1
    assert smoothed == pytest.approx(np.mean(values))
    for bad in ((1.0, 1), (-0.1, 1), (0.7, -1)):
        with pytest.raises(ValueError):
            history_weight(*bad)


def test_the_state_counts_the_triples_its_d_prime_history_averages() -> None:
    state = ChainState()
    fields = {"flow": np.zeros((4, 4, 2), np.float32), "disparity": np.zeros((4, 4), np.float32),
              "change": np.zeros((4, 4), np.float32)}

    def finish(t0: float, triples: int, cut: bool = False) -> None:
        state.finish(times=(t0, t0 + 1, t0 + 2), scale=1.0, fixed_scale=1.0, forgetting=0.0,
                     measured=[], target=None, scene_change=cut, change_triples=triples,
                     **fields)

    assert state.change_triples(follows=True) == 0  # nothing kept yet
    finish(0.0, state.change_triples(True) + 1)
    finish(1.0, state.change_triples(True) + 1)
    assert state.change_triples(follows=True) == 2
    assert state.change_triples(follows=False) == 0  # a gap: the history is not this gas's
    finish(2.0, 0, cut=True)  # a scene change forgets the fields and the count
    assert state.change_run == 0 and state.change_triples(follows=True) == 0
