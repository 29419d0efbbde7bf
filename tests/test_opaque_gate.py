"""The opaque-edge gate: a warm object's moving edge is removed by its differential optical
depth, dense gas (whose optical depth changes as fast) is not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.preprocess.opaque_gate import GROW_PX, opaque_edges

L_BG, L_GAS, L_OBJ = 0.030, 0.014, 0.048  # wall, gas temperature, warm object (radiance)


def _frame(k: int) -> np.ndarray:
    """Radiance at frame k: dense gas (transmittance 0.35 -> 0.25 -> 0.15) in rows 5-14, a
    faint plume (0.90 -> 0.88 -> 0.86) in rows 20-29, a warm 10 x 10 object in rows 40-49
    from column 10 + 3 k."""
    img = np.full((64, 80), L_BG, np.float32)
    for rows, tau in ((slice(5, 15), 0.35 - 0.1 * k), (slice(20, 30), 0.90 - 0.02 * k)):
        img[rows, 10:60] = L_BG * tau + L_GAS * (1 - tau)
    img[40:50, 10 + 3 * k:20 + 3 * k] = L_OBJ
    return img


def test_the_moving_edge_of_a_warm_object_goes_and_gas_stays() -> None:
    frames = [_frame(k) for k in range(3)]
    raw0, raw1 = frames[0] - frames[1], frames[1] - frames[2]
    mask = opaque_edges(frames, raw0, raw1, L_GAS, 1e-4)
    # every pixel the object's edge crossed, with the rim the mask grows by
    crossed = (raw0 != 0) | (raw1 != 0)
    crossed[:35] = False
    assert mask[crossed].all()
    assert not mask[:40 - GROW_PX - 1].any()  # the dense and the faint gas are left
    assert not mask[50 + GROW_PX + 1:].any()
    # the dense gas's |D| (0.1 / 0.3 and more) exceeds the threshold, its radiance lies
    # closer to the gas's than the wall's: that, not |D|, keeps it
    d = np.abs(raw0[5:15, 10:60]) / (0.5 * (frames[0] + frames[1])[5:15, 10:60] - L_GAS)
    assert d.min() > 0.2


def test_still_frames_have_no_edge() -> None:
    f = _frame(0)
    zero = np.zeros_like(f)
    assert not opaque_edges([f, f, f], zero, zero, L_GAS, 1e-4).any()


def test_the_gate_needs_radiometric_curves_and_a_temperature() -> None:
    from appliance.evaluation.bench_input import blob_frames
    from appliance.evaluation.bench_input import geometry as bench_geometry

    frames = blob_frames(n_frames=3)
    geo = dataclasses.replace(bench_geometry(), curve_left=None, curve_right=None)
    params = ChainParameters(d0=20.0, opaque_gate_gas_k=285.0)
    with pytest.raises(ValueError, match="radiometric curves"):
        compute_scene_flow(list(frames.left), list(frames.right), frames.times_s, geo,
                           params, ChainState())
    for bad in (20.0, 500.0):
        with pytest.raises(ValueError, match="opaque_gate_gas_k"):
            ChainParameters(opaque_gate_gas_k=bad)


def test_the_chain_blanks_an_object_inside_the_band_with_the_gate_on() -> None:
    """A warm object at the gas's disparity passes the depth gate; with
    ``opaque_gate_gas_k`` its edge becomes "no change" in the differential images."""
    from appliance.evaluation.bench_input import geometry as bench_geometry
    from processing.calibration.radiometric import CharacteristicCurve, band_radiance

    curve = CharacteristicCurve(offset=2000.0, gain=4e5)
    geo = dataclasses.replace(bench_geometry(), curve_left=curve, curve_right=curve)
    l_gas = float(band_radiance(285.0, curve.band_m))
    rng = np.random.default_rng(3)
    wall = l_gas + 0.016 + 0.0005 * rng.standard_normal((240, 360)).astype(np.float32)

    def counts(k: int, shift: int) -> np.ndarray:
        img = wall.copy()
        tau = 0.9 - 0.02 * k
        img[60:120, 100:220] = img[60:120, 100:220] * tau + l_gas * (1 - tau)
        img[150:190, 120 + 3 * k:160 + 3 * k] = l_gas + 0.034
        return np.rint(2000.0 + 4e5 * img[:, shift:shift + 320]).astype(np.uint16)

    left = [counts(k, 20) for k in range(3)]
    right = [counts(k, 0) for k in range(3)]  # everything 20 px of disparity: in the band
    times = (0.0, 1 / 30, 2 / 30)
    base = ChainParameters(d0=10.0)
    off = compute_scene_flow(left, right, times, geo, base, ChainState())
    on = compute_scene_flow(left, right, times, geo,
                            dataclasses.replace(base, opaque_gate_gas_k=285.0), ChainState())
    edge = (slice(152, 188), slice(100, 103))  # the object's trailing edge, left view
    assert "object_motion_rejected" not in off.summary.flags
    assert "object_motion_rejected" in on.summary.flags
    assert np.abs(off.diff_left[0][edge] - 0.5).max() > 0.1
    assert np.all(on.diff_left[0][edge] == 0.5)
    # flow_drop_blanked changes nothing where nothing was blanked
    same = compute_scene_flow(left, right, times, geo,
                              dataclasses.replace(base, flow_drop_blanked=True), ChainState())
    np.testing.assert_array_equal(same.flow, off.flow)


def test_the_flow_drops_its_data_term_on_the_opaque_gates_pixels_and_on_the_rest_if_asked(
        ) -> None:
    """Which left pixels the flow has no data term on (region.flow_blanked): the
    opaque-edge gate's own always, the depth gate's with ``flow_drop_blanked``, cut to the
    solvers' box."""
    from processing.chain.region import Box
    from processing.chain.region import flow_blanked as _flow_blanked

    depth = np.zeros((8, 10), bool)
    depth[1:3, 1:3] = True
    both = depth.copy()
    both[5:7, 6:9] = True  # what the opaque-edge gate added
    right = np.zeros_like(depth)
    plain, drop = ChainParameters(), ChainParameters(flow_drop_blanked=True)
    assert _flow_blanked(None, None, plain, None) is None  # nothing blanked
    depth_only = (depth, right)
    assert _flow_blanked(depth_only, depth_only, plain, None) is None  # the depth gate's
    np.testing.assert_array_equal(_flow_blanked(depth_only, depth_only, drop, None), depth)
    np.testing.assert_array_equal(_flow_blanked((both, right), depth_only, plain, None),
                                  both & ~depth)
    np.testing.assert_array_equal(_flow_blanked((both, right), None, plain, None), both)
    np.testing.assert_array_equal(_flow_blanked((both, right), depth_only, drop, None), both)
    box = Box(y0=0, y1=8, x0=4, x1=10, shift=0)
    np.testing.assert_array_equal(_flow_blanked((both, right), depth_only, plain, box),
                                  (both & ~depth)[:, 4:10])


def test_the_daemon_refuses_the_gate_without_radiometric_curves() -> None:
    """A configuration error (exit 2 before any device opens), not a failure per triple."""
    from appliance.config import ConfigError
    from appliance.evaluation.bench_input import geometry as bench_geometry
    from appliance.runtime.site_geometry import check_radiometry
    from processing.calibration.radiometric import CharacteristicCurve

    gate = ChainParameters(opaque_gate_gas_k=288.0)
    with pytest.raises(ConfigError, match="opaque_gate_gas_k"):
        check_radiometry(gate, bench_geometry())  # no curves
    with pytest.raises(ConfigError, match="opaque_gate_gas_k"):
        check_radiometry(gate, None)  # a single-camera site
    curve = CharacteristicCurve(offset=2000.0, gain=4e5)
    check_radiometry(gate, dataclasses.replace(bench_geometry(), curve_left=curve,
                                               curve_right=curve))
    check_radiometry(ChainParameters(), None)


def test_the_objects_rim_beyond_the_removed_edge_does_not_set_the_scale(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A warm object's faint halo changes the wall by less than the gate's |D| but by far
    more than faint gas: left in the raw differences it would set the normalisation scale
    (the gas then squeezed into a few grey levels); within ``RIM_PX`` of the removed edge
    it does not, and the scale is the gas's own."""
    from appliance.evaluation.bench_input import geometry as bench_geometry
    from processing.calibration.radiometric import CharacteristicCurve, band_radiance
    from processing.preprocess import opaque_gate

    curve = CharacteristicCurve(offset=2000.0, gain=4e5)
    geo = dataclasses.replace(bench_geometry(), curve_left=curve, curve_right=curve)
    l_gas = float(band_radiance(285.0, curve.band_m))
    rng = np.random.default_rng(5)
    wall = l_gas + 0.016 + 0.0005 * rng.standard_normal((240, 360)).astype(np.float32)

    def counts(k: int, shift: int, with_object: bool) -> np.ndarray:
        img = wall.copy()
        tau = 0.9 - 0.02 * k
        img[60:120, 100:220] = img[60:120, 100:220] * tau + l_gas * (1 - tau)
        if with_object:
            x = 120 + 3 * k
            img[150:190, x - 8:x + 48] += 0.002  # the halo: |D| about 0.1
            img[150:190, x:x + 40] = l_gas + 0.034
        return np.rint(2000.0 + 4e5 * img[:, shift:shift + 320]).astype(np.uint16)

    times = (0.0, 1 / 30, 2 / 30)
    params = ChainParameters(d0=10.0, opaque_gate_gas_k=285.0)

    def scale(with_object: bool) -> float:
        left = [counts(k, 20, with_object) for k in range(3)]
        right = [counts(k, 0, with_object) for k in range(3)]
        return compute_scene_flow(left, right, times, geo, params, ChainState()).diff_scale

    gas_only = scale(False)
    assert scale(True) == pytest.approx(gas_only, rel=0.1)
    monkeypatch.setattr(opaque_gate, "RIM_PX", 0)
    assert scale(True) > 3 * gas_only
