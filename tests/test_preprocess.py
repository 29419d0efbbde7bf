"""Radiometric correction, rectification, shared normalisation and the per-camera chain."""

from __future__ import annotations

import numpy as np
import pytest

from processing.calibration.radiometric import CharacteristicCurve
from processing.preprocess.differential import (
    apply_rectification,
    differential_image,
    levelled_difference,
    preprocess_camera,
    radiometric_correction,
)
from processing.preprocess.normalisation import DiffScaleTracker, normalise_difference
from processing.preprocess.offset import offset_step
from processing.preprocess.stereo_triple import preprocess_stereo
from processing.preprocess.translation import warp_translation


def _scene(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    """Smooth textured background radiance."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((h, w))
    for _ in range(60):
        cx, cy, s, a = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(2, 6), rng.uniform(-1, 1)
        out += a * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return (10.0 + out).astype(np.float32)


def _curve(gain: float, offset: float, quadratic: float = 0.0) -> CharacteristicCurve:
    return CharacteristicCurve(offset=offset, gain=gain, curvature=quadratic)


def _counts(curve: CharacteristicCurve, radiance: np.ndarray) -> np.ndarray:
    return curve.curvature * radiance**2 + curve.gain * radiance + curve.offset


def test_linear_curve_inverts_counts() -> None:
    radiance = np.linspace(0.0, 5.0, 48, dtype=np.float32).reshape(6, 8)
    curve = _curve(800.0, 1200.0)
    counts = np.round(_counts(curve, radiance)).astype(np.uint16)
    out = radiometric_correction(counts, curve)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, radiance, atol=0.5 / 800.0 + 1e-6)


def test_quadratic_curve_inverts_counts_and_identity_when_none() -> None:
    radiance = np.linspace(0.0, 5.0, 48).reshape(6, 8)
    curve = _curve(800.0, 1200.0, 12.0)
    counts = _counts(curve, radiance)
    np.testing.assert_allclose(radiometric_correction(counts, curve), radiance, atol=1e-4)
    raw = np.arange(48, dtype=np.uint16).reshape(6, 8)
    np.testing.assert_array_equal(radiometric_correction(raw, None), raw.astype(np.float32))


def test_normalisation_is_identical_for_both_cameras_and_all_frames() -> None:
    """Same radiance change in two cameras with different curves -> same normalised image.

    And the value of a pixel does not depend on the rest of the frame (unlike a per-frame
    min-max stretch): a hot pixel elsewhere in one camera changes nothing else.
    """
    rng = np.random.default_rng(1)
    background = _scene()
    gas = np.zeros_like(background)
    gas[30:60, 40:90] = 0.3 * rng.standard_normal((30, 50)).astype(np.float32)
    left_curve = _curve(700.0, 1000.0)
    right_curve = _curve(950.0, 400.0)
    scale = 1.0

    def normalised(curve: dict[str, float], frame0: np.ndarray, frame1: np.ndarray) -> np.ndarray:
        c0 = _counts(curve, frame0)
        c1 = _counts(curve, frame1)
        d = radiometric_correction(c0, curve) - radiometric_correction(c1, curve)
        return normalise_difference(d, scale)

    left = normalised(left_curve, background + gas, background)
    right = normalised(right_curve, background + gas, background)
    np.testing.assert_allclose(left, right, atol=1e-4)
    hot = background.copy()
    hot[5, 5] += 50.0
    right_hot = normalised(right_curve, hot + gas, background)
    outside = np.ones(left.shape, bool)
    outside[5, 5] = False
    np.testing.assert_allclose(right_hot[outside], left[outside], atol=1e-4)
    # A later frame with the same radiance change maps to the same values.
    later = normalised(left_curve, background + 2.0 + gas, background + 2.0)
    np.testing.assert_allclose(later, left, atol=1e-4)
    assert float(left[0, 0]) == pytest.approx(0.5, abs=1e-4)


@pytest.mark.parametrize("gas_radiance", [None, 5.0])
def test_an_offset_step_of_the_camera_leaves_the_differential_image(
        gas_radiance: float | None) -> None:
    """A uniform step between two frames (a flat-field shutter) is the median of their
    difference while gas changes under half of the picture: the differential image, plain
    or as optical depth, is the one without the step; without a step (or one lost in the
    noise) the difference is left as it is."""
    background = _scene()
    rng = np.random.default_rng(1)
    earlier = background + rng.normal(0, 0.01, background.shape).astype(np.float32)
    later = background + rng.normal(0, 0.01, background.shape).astype(np.float32)
    later[20:60, 30:90] -= 0.4  # gas on a fifth of the picture
    kwargs = {"gas_radiance": gas_radiance, "min_contrast": 0.5}
    plain, none = levelled_difference(earlier, later, **kwargs)
    stepped, step = levelled_difference(earlier, later + np.float32(3.0), **kwargs)
    # The step is reported (a shutter counted for the box's health), in the frames' unit.
    assert none == 0.0 and step == pytest.approx(-3.0, abs=0.01)
    np.testing.assert_array_equal(differential_image(earlier, later, **kwargs), plain)
    level = float(np.abs(earlier).mean())
    assert offset_step(earlier - (later + np.float32(3.0)), level) == pytest.approx(-3.0,
                                                                                   abs=0.01)
    np.testing.assert_allclose(stepped, plain, atol=0.02)
    if gas_radiance is None:  # no step: the difference as it is, noise and gas alone
        np.testing.assert_array_equal(plain, earlier - later)
    # A step within half the noise's median absolute deviation is taken for none.
    assert offset_step(earlier - (later + np.float32(0.002)), level) == 0.0
    # Without noise, a step under STEP_FLOOR of the picture's level (10 here) is rounding.
    assert offset_step(np.full((8, 8), 5e-3, np.float32), level) == 0.0
    assert offset_step(np.full((8, 8), 2e-2, np.float32), level) == pytest.approx(2e-2)


def test_normalise_maps_scale_to_unit_interval() -> None:
    d = np.array([[-2.0, -1.0, 0.0, 0.5, 1.0, 3.0]], np.float32)
    np.testing.assert_allclose(
        normalise_difference(d, 1.0), [[0.0, 0.0, 0.5, 0.75, 1.0, 1.0]], atol=1e-7
    )


def test_scale_tracker_is_shared_and_forgets_slowly() -> None:
    rng = np.random.default_rng(2)
    tracker = DiffScaleTracker(1.0, forgetting=0.05, quantile=0.99)
    left = rng.standard_normal((50, 60)).astype(np.float32)
    right = 3.0 * rng.standard_normal((50, 60)).astype(np.float32)
    before = tracker.scale
    after = tracker.update(left, right)
    assert after == tracker.scale
    assert abs(after - before) <= 0.05 * max(before, 10.0)
    for _ in range(200):
        tracker.update(left, right)
    pooled = np.abs(np.concatenate([left[::2, ::2].ravel(), right[::2, ::2].ravel()]))
    assert tracker.scale == pytest.approx(float(np.quantile(pooled, 0.99)), rel=1e-3)


def test_rectification_applies_maps() -> None:
    img = _scene()
    h, w = img.shape
    map_x, map_y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    np.testing.assert_allclose(apply_rectification(img, map_x, map_y), img, atol=1e-5)
    shifted = apply_rectification(img, map_x + 2.0, map_y)
    np.testing.assert_allclose(shifted[:, :-2], img[:, 2:], atol=1e-5)


def test_preprocess_camera_removes_jitter_before_differencing() -> None:
    """A static scene with jitter only: the differential images must be ~0.5 everywhere."""
    background = _scene(seed=3)
    frames = [
        background,
        warp_translation(background, (-0.4, 0.3)),
        warp_translation(background, (0.35, -0.25)),
    ]
    jittery = preprocess_camera(frames, scale=0.5, register=False, denoise_lambda=0.0)
    fixed = preprocess_camera(frames, scale=0.5, register=True, denoise_lambda=0.0)
    inner = (slice(6, -6), slice(6, -6))
    err_jittery = np.abs(jittery.diff0 - 0.5)[inner].max()
    err_fixed = np.abs(fixed.diff0 - 0.5)[inner].max()
    assert err_fixed < 0.1 * err_jittery
    assert np.abs(fixed.diff1 - 0.5)[inner].max() < 0.1 * np.abs(jittery.diff1 - 0.5)[inner].max()
    (s01, s12) = fixed.shifts
    assert s01 == pytest.approx((0.4, -0.3), abs=0.05)
    assert s12 == pytest.approx((-0.75, 0.55), abs=0.05)
    assert fixed.diff0.dtype == np.float32
    assert 0.0 <= float(fixed.diff0.min()) and float(fixed.diff0.max()) <= 1.0


def test_curve_of_the_wrong_type_raises() -> None:
    with pytest.raises(ValueError, match="CharacteristicCurve"):
        radiometric_correction(np.zeros((3, 4)), {"gain": 1.0, "offset": 0.0})  # type: ignore[arg-type]


def test_bad_frames_raise() -> None:
    f = _scene()
    with pytest.raises(ValueError, match="exactly 3"):
        preprocess_camera([f, f], scale=1.0)
    with pytest.raises(ValueError, match="differ in shape"):
        preprocess_camera([f, f, f[:-1]], scale=1.0)
    with pytest.raises(ValueError, match="scale"):
        preprocess_camera([f, f, f], scale=0.0)
    with pytest.raises(ValueError, match="2-D"):
        radiometric_correction(np.zeros((3, 4, 2)), None)
    with pytest.raises(ValueError, match="NaN"):
        radiometric_correction(np.full((3, 4), np.nan), None)
    with pytest.raises(ValueError, match="scale"):
        normalise_difference(np.zeros((4, 4), np.float32), -1.0)


def test_preprocess_stereo_shares_the_scale_across_cameras() -> None:
    """Two cameras with different characteristic curves seeing the same radiance."""
    rng = np.random.default_rng(6)
    background = _scene(seed=4)
    gas = [np.zeros_like(background) for _ in range(3)]
    for t in range(3):
        gas[t][30:60, 40 + 3 * t : 90 + 3 * t] = 0.4 * rng.random((30, 50), dtype=np.float32)
    radiance = [background + g for g in gas]
    left_curve = _curve(700.0, 1000.0)
    right_curve = _curve(950.0, 400.0, 3.0)

    def counts(curve: CharacteristicCurve) -> list[np.ndarray]:
        return [_counts(curve, r) for r in radiance]

    left, right = preprocess_stereo(
        counts(left_curve),
        counts(right_curve),
        scale=0.5,
        curves=(left_curve, right_curve),
        register=False,
        denoise_lambda=1.0,
    )
    np.testing.assert_allclose(left.diff0, right.diff0, atol=2e-4)
    np.testing.assert_allclose(left.diff1, right.diff1, atol=2e-4)
    with pytest.raises(ValueError, match="differ in shape"):
        preprocess_stereo(radiance, [r[:, :-1] for r in radiance], scale=0.5, register=False)


def test_registration_does_not_cancel_gas_motion_over_a_featureless_background() -> None:
    """Uniform background, one textured gas patch moving 1.5 px per frame.

    Registration can only lock onto the gas there; the estimate exceeds any plausible
    jitter, so it must be rejected (counted) and the gas motion left in the images.
    """
    h, w = 96, 128
    rng = np.random.default_rng(7)
    patch = warp_translation(_scene(h, w, seed=8) - 10.0, (0.0, 0.0))
    mask = np.zeros((h, w), np.float32)
    mask[30:70, 40:90] = 1.0
    gas = patch * mask
    frames = [
        (100.0 + warp_translation(gas, (-1.5 * t, 0.0))).astype(np.float32) for t in range(3)
    ]
    frames = [f + 0.001 * rng.standard_normal((h, w)).astype(np.float32) for f in frames]
    out = preprocess_camera(frames, scale=0.5, register=True, denoise_lambda=0.0)
    assert out.rejected_shifts == 2
    assert out.shifts == ((0.0, 0.0), (0.0, 0.0))
    plain = preprocess_camera(frames, scale=0.5, register=False, denoise_lambda=0.0)
    np.testing.assert_array_equal(out.diff0, plain.diff0)
