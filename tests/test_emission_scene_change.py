"""A triple the chain flags ``scene_change`` gets no emission rate and leaves the background
model alone: its gas mask and velocities are the picture's jump, not gas."""

from __future__ import annotations

import numpy as np

from appliance.evaluation.bench_input import blob_frames, geometry
from appliance.runtime.emission_setup import EmissionSetup, emission_rate
from processing.calibration.radiometric import CharacteristicCurve
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.emission.estimator import EmissionSettings


def test_a_scene_change_has_no_rate_and_does_not_feed_the_background() -> None:
    frames = blob_frames(n_frames=8)
    geo = geometry()
    setup = EmissionSetup(EmissionSettings(background_frames=4), gas_temperature_k=285.0,
                          curve_left=CharacteristicCurve(offset=2000.0, gain=4e5))
    estimator = setup.estimator(geo)
    assert estimator is not None
    state, params = ChainState(), ChainParameters()
    rates = []
    for k in range(4):
        t = tuple(float(x) for x in frames.times_s[k:k + 3])
        left, right = list(frames.left[k:k + 3]), list(frames.right[k:k + 3])
        res = compute_scene_flow(left, right, t, geo, params, state)
        assert "scene_change" not in res.summary.flags
        rates.append(emission_rate(estimator, left[1], res, 285.0))
    assert any(r.rate_g_s is not None for r in rates)
    # A jump of the picture: from t1 on both cameras deliver garbled frames, random counts
    # all over (the gas changes a pixel by at most ~600). A flat-field shutter's uniform
    # step is no scene change: the differential images are levelled.
    k = 4
    t = tuple(float(x) for x in frames.times_s[k:k + 3])
    rng = np.random.default_rng(2)

    def garbled(f: np.ndarray) -> np.ndarray:
        return rng.integers(2000, 30000, f.shape).astype(np.uint16)

    left = [frames.left[k], *(garbled(f) for f in frames.left[k + 1:k + 3])]
    right = [frames.right[k], *(garbled(f) for f in frames.right[k + 1:k + 3])]
    jump = compute_scene_flow(left, right, t, geo, params, state)
    assert "scene_change" in jump.summary.flags
    seen = estimator.background.frames
    rate = emission_rate(estimator, left[1], jump, 285.0)
    assert rate.rate_g_s is None and "scene change" in rate.reason
    assert estimator.background.frames == seen
