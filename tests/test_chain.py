"""The single entry point of the scene-flow chain."""

from __future__ import annotations

import numpy as np
import pytest

from appliance.evaluation.bench_input import blob_frames
from appliance.evaluation.bench_input import geometry as bench_geometry
from processing.chain import (
    ChainParameters,
    ChainState,
    StereoGeometry,
    compute_scene_flow,
    frame_interval,
)
from processing.chain.summary import GasSummary
from tests.scene_flow_plane import B_M, PP, S_PX, SIZE, render, texture

GEOMETRY = StereoGeometry(
    camera_constant=S_PX, principal_point=PP, baseline=B_M, image_size=(SIZE[1], SIZE[0])
)
# The plane fills the view, so there is no static background to register on.
PARAMS = ChainParameters(register=False, disparity_init="d0", d0=60.0)


def _raw_triple(velocity: np.ndarray, dt: float, z0: float = 2.0, seed: int = 0):
    """Three consecutive stereo pairs (as 16-bit counts) of a textured moving plane."""
    tex = texture(seed)
    left, right = [], []
    for k in range(3):
        z = z0 + velocity[2] * dt * k
        shift = (velocity[0] * dt * k, velocity[1] * dt * k)
        for frames, cam_x in ((left, 0.0), (right, B_M)):
            frames.append(
                np.rint(1000.0 + 20000.0 * render(tex, z, shift, cam_x)).astype(np.uint16)
            )
    return left, right


def _region_mean(result, region: np.ndarray) -> np.ndarray:
    assert result.valid[region].mean() > 0.99
    return result.velocity[region & result.valid].astype(np.float64).mean(axis=0)


def test_moving_plane_through_the_whole_chain() -> None:
    """Raw frames -> differential images -> w, d, d' -> V of a plane at 2 m (30 Hz)."""
    v_true = np.array([0.3, -0.2, -0.5])
    dt = 1 / 30
    left, right = _raw_triple(v_true, dt)
    times = (10.0, 10.0 + dt, 10.0 + 2 * dt)
    result = compute_scene_flow(left, right, times, GEOMETRY, PARAMS)
    region = np.zeros(SIZE, bool)
    region[20:-20, 110:-20] = True  # seen by both cameras, away from pyramid borders
    mean = _region_mean(result, region)
    rel = abs(np.linalg.norm(mean) - np.linalg.norm(v_true)) / np.linalg.norm(v_true)
    ang = np.degrees(np.arccos(mean @ v_true / np.linalg.norm(mean) / np.linalg.norm(v_true)))
    assert rel < 0.05, rel
    assert ang < 3.0, ang
    assert result.dt_s == pytest.approx(dt)
    # I_diff(t0) = I(t0) - I(t1) shows the plane half-way through [t0, t1].
    z_mid = 2.0 + v_true[2] * dt / 2
    assert np.median(result.disparity[region]) == pytest.approx(S_PX * B_M / z_mid, abs=0.05)
    for name in (
        "preprocess",
        "flow",
        "disparity",
        "velocity_quality",
        "segmentation",
        "summary",
        "total",
    ):
        assert result.timings_ms[name] >= 0.0
    _assert_summary_is_finite(result.summary)


def _assert_summary_is_finite(summary: GasSummary) -> None:
    for value in summary.to_dict().values():
        for v in np.ravel(np.asarray(value, dtype=object)):
            if isinstance(v, float):
                assert np.isfinite(v)


def test_frame_interval_comes_from_the_timestamps() -> None:
    """The same frames stamped twice as far apart give half the velocity (Eq. 4, f = 1/dt)."""
    v_true = np.array([0.3, -0.2, 0.0])
    left, right = _raw_triple(v_true, 1 / 30)
    region = np.zeros(SIZE, bool)
    region[20:-20, 110:-20] = True
    fast = compute_scene_flow(left, right, (0.0, 1 / 30, 2 / 30), GEOMETRY, PARAMS)
    slow = compute_scene_flow(left, right, (0.0, 2 / 30, 4 / 30), GEOMETRY, PARAMS)
    np.testing.assert_allclose(
        _region_mean(slow, region), _region_mean(fast, region) / 2, atol=1e-3
    )
    assert slow.dt_s == pytest.approx(2 / 30)


def test_state_warm_starts_only_consecutive_triples() -> None:
    v_true = np.array([0.3, 0.0, 0.0])
    left, right = _raw_triple(v_true, 1 / 30)
    state = ChainState()
    compute_scene_flow(left, right, (0.0, 1.0, 2.0), GEOMETRY, PARAMS, state)
    assert state.previous_times == (0.0, 1.0, 2.0)
    assert state.scale is not None
    first_flow = state.previous_flow
    # Not consecutive (t0 != previous t1): no warm start, the state is simply replaced.
    compute_scene_flow(left, right, (5.0, 6.0, 7.0), GEOMETRY, PARAMS, state)
    assert state.previous_times == (5.0, 6.0, 7.0)
    assert state.previous_flow is not first_flow


def test_an_implausible_speed_is_flagged_and_the_next_triple_starts_cold() -> None:
    """A mean speed above ``max_gas_speed_m_s`` is no measurement: the summary is invalid
    and flagged, and its fields do not seed the next triple (the bound is set below the
    drifting blob's speed here to make it implausible)."""
    frames = blob_frames(n_frames=4)
    geo = bench_geometry()

    def two(params: ChainParameters) -> list:
        state = ChainState()
        return [compute_scene_flow(list(frames.left[k:k + 3]), list(frames.right[k:k + 3]),
                                   frames.times_s[k:k + 3], geo, params, state)
                for k in (0, 1)]

    ok = two(ChainParameters(d0=20.0))
    assert ok[0].summary.valid and "implausible_speed" not in ok[0].summary.flags
    assert ok[1].warm
    speed = ok[0].summary.speed
    bad = two(ChainParameters(d0=20.0, max_gas_speed_m_s=0.5 * speed))
    assert not bad[0].summary.valid and "implausible_speed" in bad[0].summary.flags
    assert bad[0].summary.speed == pytest.approx(speed)  # kept for diagnosis, flagged
    assert not bad[1].warm
    with pytest.raises(ValueError, match="max_gas_speed_m_s"):
        ChainParameters(max_gas_speed_m_s=0.0)


@pytest.mark.parametrize("stride", [1, 2])
def test_a_warm_flow_from_two_frames_back_runs_the_whole_pyramid(stride: int,
                                                                  monkeypatch) -> None:
    """Two workers warm-start from their own triple two frames back: the flow then takes
    ``far_warm_flow_options`` (the whole pyramid); one frame back ``warm_flow_options``."""
    from processing.chain import driver

    frames = blob_frames(n_frames=2 + 2 * stride)
    seen: list[dict] = []
    brox = driver.brox_optical_flow

    def spy(*args, **kwargs):
        seen.append(kwargs)
        return brox(*args, **kwargs)

    monkeypatch.setattr(driver, "brox_optical_flow", spy)
    state, params = ChainState(stride=stride), ChainParameters(d0=20.0)
    for k in (0, stride):
        res = compute_scene_flow(list(frames.left[k:k + 3]), list(frames.right[k:k + 3]),
                                 frames.times_s[k:k + 3], bench_geometry(), params, state)
    assert res.warm
    cold, warm = seen
    assert cold["initial_flow"] is None and "n_levels" not in cold
    expected = params.warm_flow_options if stride == 1 else params.far_warm_flow_options
    assert {k: warm[k] for k in expected} == dict(expected)
    assert ("n_levels" in warm) == (stride == 1)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda a, b, t: (a[:2], b, t), "need 3 left and 3 right"),
        (lambda a, b, t: (a, [f[:, :-1] for f in b], t), "calibration expects"),
        (lambda a, b, t: (a, b, (0.0, 0.0, 1.0)), "increasing"),
        (lambda a, b, t: (a, b, (0.0, float("nan"), 1.0)), "increasing"),
    ],
)
def test_bad_input_raises(mutate, message: str) -> None:
    left, right = _raw_triple(np.zeros(3), 1 / 30)
    l2, r2, t2 = mutate(left, right, (0.0, 0.1, 0.2))
    with pytest.raises(ValueError, match=message):
        compute_scene_flow(l2, r2, t2, GEOMETRY, PARAMS)


def test_parameters_from_mapping_reject_unknown_keys() -> None:
    assert ChainParameters.from_mapping({"alpha": 0.1}).alpha == 0.1
    with pytest.raises(ValueError, match=r"unknown processing parameter.*alhpa"):
        ChainParameters.from_mapping({"alhpa": 0.1})
    with pytest.raises(ValueError, match="disparity_init"):
        ChainParameters(disparity_init="magic")


def test_frame_interval_is_half_the_triple_span() -> None:
    assert frame_interval((1.0, 1.5, 2.2)) == pytest.approx(0.6)
