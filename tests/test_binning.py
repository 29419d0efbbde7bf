"""Pixel binning: the chain on k x k blocks of a wide camera, the fields at camera size."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from appliance.evaluation.bench_input import blob_frames, geometry
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.chain.binning import (
    bin_image,
    binned_geometry,
    binned_parameters,
    grow,
    upsampled_result,
)
from processing.stereo_geometry import StereoGeometry


def test_a_binned_image_is_the_mean_of_each_block() -> None:
    img = np.arange(24, dtype=np.float32).reshape(4, 6)
    out = bin_image(img, 2)
    assert out.shape == (2, 3) and out.dtype == np.float32
    assert out[0, 0] == np.mean([0, 1, 6, 7])
    assert out[1, 2] == np.mean([16, 17, 22, 23])
    assert bin_image(img, 1) is img
    noisy = np.random.default_rng(4).normal(0.5, 0.1, (48, 64)).astype(np.float32)
    for k in (2, 4):
        means = noisy.reshape(48 // k, k, 64 // k, k).mean(axis=(1, 3), dtype=np.float64)
        assert np.allclose(bin_image(noisy, k), means, rtol=0, atol=1e-7)
    with pytest.raises(ValueError, match="does not divide"):
        bin_image(np.zeros((5, 6), np.float32), 2)


@pytest.mark.parametrize("field", [
    np.random.default_rng(0).standard_normal((6, 8)).astype(np.float32),
    np.random.default_rng(1).standard_normal((6, 8, 2)).astype(np.float32),
    np.random.default_rng(2).standard_normal((6, 8, 3)).astype(np.float32),
    np.random.default_rng(3).random((6, 8)) > 0.5,
])
@pytest.mark.parametrize("k", [2, 3, 4])
def test_a_grown_field_puts_each_value_on_its_whole_block(field: np.ndarray, k: int) -> None:
    out = grow(field, k)
    expected = np.repeat(np.repeat(field, k, axis=0), k, axis=1)
    assert out.dtype == field.dtype and out.shape == expected.shape
    assert np.array_equal(out, expected)


def test_the_binned_geometry_sees_a_point_at_its_block() -> None:
    geo = StereoGeometry(camera_constant=1560.0, principal_point=(319.5, 239.5), baseline=0.3,
                         image_size=(640, 480))
    b = binned_geometry(geo, 2)
    assert b.image_size == (320, 240) and b.camera_constant == 780.0
    for point in ((0.4, -0.2, 5.0), (-1.0, 0.7, 8.0)):
        x, y, z = point
        u = geo.principal_point[0] + geo.camera_constant * x / z  # camera pixel coordinate
        ub = b.principal_point[0] + b.camera_constant * x / z  # block coordinate
        # block i holds camera pixels 2i and 2i + 1, its centre at 2i + 0.5
        assert ub * 2 + 0.5 == pytest.approx(u)
        vb = b.principal_point[1] + b.camera_constant * y / z
        assert vb * 2 + 0.5 == pytest.approx(geo.principal_point[1] + geo.camera_constant * y / z)
    # the disparity of a point in blocks is half its disparity in camera pixels
    assert b.camera_constant * b.baseline / 5.0 == geo.camera_constant * geo.baseline / 10.0
    assert binned_geometry(geo, 1) is geo


def test_settings_in_camera_pixels_become_settings_in_blocks() -> None:
    p = ChainParameters(binning=2, d0=64.0, sgm_num_disparities=128, gate_tolerance_px=3.0,
                        max_motion_px=15, region_margin_px=48, max_jitter_px=3.0)
    b = binned_parameters(p)
    assert (b.binning, b.d0, b.sgm_num_disparities, b.gate_tolerance_px) == (1, 32.0, 64, 1.5)
    assert (b.max_motion_px, b.region_margin_px, b.max_jitter_px) == (8, 24, 1.5)
    assert b.denoise_lambda == p.denoise_lambda and b.alpha == p.alpha
    # the SGM range stays a multiple of 16 and never covers less of the band
    assert binned_parameters(ChainParameters(binning=2, sgm_num_disparities=16)) \
        .sgm_num_disparities == 16
    assert binned_parameters(ChainParameters(binning=4, sgm_num_disparities=80)) \
        .sgm_num_disparities == 32


@pytest.mark.parametrize("bad", [0, 5, 2.0, True, "2"])
def test_a_binning_that_is_not_a_small_integer_is_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="binning"):
        ChainParameters.from_mapping({"binning": bad})


def test_frames_whose_size_binning_does_not_divide_are_refused() -> None:
    geo = StereoGeometry(camera_constant=780.0, principal_point=(160.5, 120.0), baseline=0.3,
                         image_size=(322, 240))
    frames = [np.zeros((240, 322), np.uint16)] * 3
    with pytest.raises(ValueError, match="binning 4 does not divide the 322x240"):
        compute_scene_flow(frames, frames, (0.0, 1 / 30, 2 / 30), geo,
                           ChainParameters(binning=4))


def _twice_the_pixels(geo: StereoGeometry) -> StereoGeometry:
    """The camera of ``geo`` (320x240) with each pixel split into 2x2 (640x480)."""
    s, (x0, y0) = geo.camera_constant, geo.principal_point
    return dataclasses.replace(geo, camera_constant=2 * s,
                               principal_point=(2 * x0 + 0.5, 2 * y0 + 0.5),
                               image_size=(640, 480))


def _grow_stack(stack: np.ndarray) -> np.ndarray:
    """(N, H, W) frames with each pixel repeated on a 2x2 block."""
    return np.repeat(np.repeat(stack, 2, axis=1), 2, axis=2)


def _parameters() -> tuple[ChainParameters, ChainParameters]:
    """The 320x240 chain's parameters and those of its 640x480 camera binned by 2 (settings
    in camera px doubled). The first normalisation scale is taken from the raw frames'
    sampled differences, a different sample at the two sizes: fixed here, so that
    everything else is compared."""
    small = ChainParameters(d0=5.0, diff_scale=300.0)
    return small, dataclasses.replace(small, binning=2, d0=10.0, sgm_num_disparities=128,
                                      gate_tolerance_px=3.0, max_motion_px=16,
                                      region_margin_px=48, max_jitter_px=3.0)


def test_the_binned_chain_is_the_chain_on_the_binned_camera_at_camera_size() -> None:
    """A 640x480 pair whose 2x2 blocks are the pixels of a 320x240 pair, binned by 2, gives
    exactly the 320x240 chain's fields grown to 640x480 (warm triples included)."""
    small = blob_frames(n_frames=6)
    geo_small = geometry()
    geo_big = _twice_the_pixels(geo_small)
    big_left, big_right = _grow_stack(small.left), _grow_stack(small.right)
    p_small, p_big = _parameters()
    st_small, st_big = ChainState(), ChainState()
    for k in range(4):
        t = tuple(float(x) for x in small.times_s[k:k + 3])
        r_small = compute_scene_flow(list(small.left[k:k + 3]), list(small.right[k:k + 3]), t,
                                     geo_small, p_small, st_small)
        r_big = compute_scene_flow(list(big_left[k:k + 3]), list(big_right[k:k + 3]), t,
                                   geo_big, p_big, st_big)
        want = upsampled_result(r_small, 2)
        assert r_big.warm == r_small.warm == (k > 0)
        assert r_big.gas_mask.shape == (480, 640) and r_big.gas_mask.any()
        for name in ("flow", "disparity", "disparity_change", "velocity", "position", "valid",
                     "u_sf_valid", "gas_mask", "phi"):
            assert np.array_equal(getattr(r_big, name), getattr(want, name)), name
        assert np.array_equal(r_big.u_sf, want.u_sf, equal_nan=True)
        assert np.array_equal(r_big.diff_left[1], want.diff_left[1])
        assert r_big.summary == want.summary
        assert r_big.summary.mean_velocity == r_small.summary.mean_velocity
        assert r_big.summary.gas_pixel_count == 4 * r_small.summary.gas_pixel_count
        assert np.array_equal(r_big.flow, 2 * grow(r_small.flow, 2))


def test_a_binning_that_does_not_divide_the_cameras_is_a_config_error() -> None:
    from appliance import config as C

    with pytest.raises(C.ConfigError) as info:
        C.validate_config(C.apply_overrides({}, [("processing.parameters", {"binning": 3})]))
    assert info.value.errors == [
        "processing.parameters.binning: binning 3 does not divide the 320x240 camera image "
        "(each side must be a multiple of 3)"]
    ok = C.validate_config(C.apply_overrides({}, [
        ("simulation.width_px", 640), ("simulation.height_px", 480),
        ("processing.parameters", {"binning": 4})]))
    assert ok.processing.parameters == {"binning": 4}


def test_the_emission_rate_of_a_binned_pair_is_that_of_the_binned_camera() -> None:
    """The pair of the test above, binned by 2: its emission rate per triple is the 320x240
    pair's, to the bit (the estimator works on the blocks the chain measured)."""
    from appliance.runtime.emission_setup import EmissionSetup, emission_rate
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.emission.estimator import EmissionSettings

    small = blob_frames(n_frames=8)
    geo_small = geometry()
    geo_big = _twice_the_pixels(geo_small)
    setup = EmissionSetup(EmissionSettings(background_frames=4), gas_temperature_k=285.0,
                          curve_left=CharacteristicCurve(offset=2000.0, gain=4e5))
    p_small, p_big = _parameters()
    est_small, est_big = setup.estimator(geo_small), setup.estimator(geo_big, 2)
    assert est_small is not None and est_big is not None
    assert est_big.settings.pixel_scale == est_small.settings.pixel_scale == 1.0
    st_small, st_big = ChainState(), ChainState()
    rates = []
    for k in range(6):
        t = tuple(float(x) for x in small.times_s[k:k + 3])
        left, right = small.left[k:k + 3], small.right[k:k + 3]
        big_l, big_r = _grow_stack(left), _grow_stack(right)
        r_small = compute_scene_flow(list(left), list(right), t, geo_small, p_small, st_small)
        r_big = compute_scene_flow(list(big_l), list(big_r), t, geo_big, p_big, st_big,
                                   at_camera_size=False)
        a = emission_rate(est_small, left[1], r_small, 285.0)
        b = emission_rate(est_big, big_l[1], r_big, 285.0)
        assert a == b
        rates.append(a.rate_g_s)
    assert any(r is not None and r > 0 for r in rates), rates
    with pytest.raises(ValueError, match=r"binned by 2 takes its \(240, 320\) block fields"):
        emission_rate(est_big, big_l[1], upsampled_result(r_big, 2), 285.0)


@pytest.mark.parametrize("fields", [False, True])
def test_a_worker_sends_a_binned_result_as_the_grown_result(fields: bool) -> None:
    """What a worker packs from the chain's block result is what it packed from the result
    grown to camera size: the gas mask, the flow at its pixels, the arrows, the summary in
    camera pixels (and the fields, when the daemon asks for them)."""
    from appliance.runtime.worker_result import WorkerResult, pack_result

    small = blob_frames(n_frames=4)
    geo_big = _twice_the_pixels(geometry())
    _, p_big = _parameters()
    state = ChainState()
    big_l, big_r = _grow_stack(small.left), _grow_stack(small.right)
    for k in range(2):
        t = tuple(float(x) for x in small.times_s[k:k + 3])
        blocks = compute_scene_flow(list(big_l[k:k + 3]), list(big_r[k:k + 3]), t, geo_big,
                                    p_big, state, at_camera_size=False)
        assert blocks.gas_mask.shape == (240, 320) and blocks.gas_mask.any()

        def base() -> WorkerResult:
            return WorkerResult(worker=0, pair_indices=(0, 1, 2), t_mono_ns=(0, 1, 2),
                                t_wall_ns=0, skipped=0, done_mono_ns=0)

        got = pack_result(blocks, base(), big_l[k], fields=fields, binning=2)
        want = pack_result(upsampled_result(blocks, 2), base(), big_l[k], fields=fields)
        assert got.gas_mask.shape == (480, 640)
        assert got.summary == want.summary
        assert got.summary["gas_pixel_count"] == 4 * int(blocks.gas_mask.sum())
        for name in ("gas_mask", "gas_flow", "points3d", "velocity3d", "pixels", "flow",
                     "disparity", "disparity_change", "velocity", "valid", "diff_left",
                     "diff_right", "raw_left"):
            a, b = getattr(got, name), getattr(want, name)
            assert (a is None) == (b is None) == (name in ("flow", "disparity",
                    "disparity_change", "velocity", "valid", "diff_left", "diff_right",
                    "raw_left") and not fields), name
            assert a is None or (a.dtype == b.dtype and np.array_equal(a, b)), name


def test_a_binned_worker_sends_camera_size_results_with_block_rates() -> None:
    """A worker of a binned site sends its stereo result at the cameras' size with the rate
    of the blocks; while one camera is lost it runs the single-camera chain on every pixel,
    whose emission rate must not go through the estimator of the binned stereo chain."""
    from types import SimpleNamespace

    from appliance.runtime.emission_setup import EmissionSetup
    from appliance.runtime.worker_result import WorkerResult
    from appliance.runtime.workers import _Worker
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.emission.estimator import EmissionSettings

    small = blob_frames(n_frames=4)
    geo = _twice_the_pixels(geometry())
    setup = EmissionSetup(EmissionSettings(typed_distance_m=5.0, background_frames=4),
                          gas_temperature_k=285.0,
                          curve_left=CharacteristicCurve(offset=2000.0, gain=4e5))
    worker = _Worker(0, SimpleNamespace(capacity=16), 1, geo, ChainParameters(binning=2),
                     setup, None, None, None)
    assert worker.estimator is not None and worker.estimator.binning == 2
    assert worker.single_estimator is not None and worker.single_estimator.binning == 1
    frames = _grow_stack(small.left[:3])
    times = tuple(int(t * 1e9) for t in small.times_s[:3])

    def base() -> WorkerResult:
        return WorkerResult(worker=0, pair_indices=(0, 1, 2), t_mono_ns=times, t_wall_ns=0,
                            skipped=0, done_mono_ns=0)

    stereo = base()
    worker._stereo(frames, _grow_stack(small.right[:3]), stereo, False, True)
    assert stereo.error is None and stereo.gas_mask is not None
    assert stereo.gas_mask.shape == (480, 640) and stereo.gas_mask.any()
    assert stereo.rate is not None and "failed" not in stereo.rate.reason, stereo.rate
    single = base()
    worker._single("left", frames, single, False, True)
    assert single.rate is not None and "failed" not in single.rate.reason, single.rate
