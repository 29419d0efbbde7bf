"""Scene-flow metrics of Sec. 5.1 / Eq. 10 against hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from processing.metrics import sceneflow as sm


def _field(vectors: list[list[float]]) -> np.ndarray:
    """A 1 x N field of 3-vectors."""
    return np.asarray(vectors, dtype=np.float64)[None, :, :]


def test_mean_velocity_over_region_only() -> None:
    f = _field([[1, 2, 3], [3, 2, 1], [100, 100, 100]])
    region = np.array([[True, True, False]])
    np.testing.assert_allclose(sm.mean_velocity(f, region), [2.0, 2.0, 2.0])
    assert sm.mean_velocity(f, np.zeros((1, 3), bool)) is None


def test_mean_velocity_rejects_nan_inside_region_but_not_outside() -> None:
    f = _field([[1, 0, 0], [np.nan, 0, 0]])
    np.testing.assert_allclose(sm.mean_velocity(f, np.array([[True, False]])), [1, 0, 0])
    with pytest.raises(ValueError, match="not finite"):
        sm.mean_velocity(f, np.array([[True, True]]))


def test_rmve_hand_computed() -> None:
    # |V*| = 5 (3-4-0 triangle), |V| = 4.5 -> 10 %; |V| = 6 -> 20 % (absolute value).
    assert sm.rmve([3, 4, 0], [0, 4.5, 0]) == pytest.approx(10.0)
    assert sm.rmve([3, 4, 0], [0, 0, 6]) == pytest.approx(20.0)
    assert sm.rmve([3, 4, 0], [3, 4, 0]) == 0.0


def test_rmve_degenerate_is_none() -> None:
    assert sm.rmve([0, 0, 0], [1, 0, 0]) is None
    assert sm.rmve(None, [1, 0, 0]) is None
    assert sm.rmve([1, 0, 0], None) is None


def test_aemv_hand_computed() -> None:
    assert sm.aemv([1, 0, 0], [0, 2, 0]) == pytest.approx(90.0)
    assert sm.aemv([1, 0, 0], [1, 1, 0]) == pytest.approx(45.0)
    assert sm.aemv([1, 0, 0], [-3, 0, 0]) == pytest.approx(180.0)
    # Parallel vectors whose rounding gives cos slightly above 1: 0, not NaN.
    v = [0.1, 0.7, 0.3]
    assert sm.aemv(v, [3 * x for x in v]) == pytest.approx(0.0, abs=1e-6)
    assert sm.aemv([0, 0, 0], [1, 0, 0]) is None


def test_errors_of_sequence_mean_average_out_scatter_but_keep_a_bias() -> None:
    ref = [[1.0, 0.0, 0.0]] * 3
    # frames 10 % fast and 10 % slow, one frame without a measurement: no error on the mean
    scattered = [[1.1, 0.0, 0.0], [0.9, 0.0, 0.0], None]
    assert sm.rmve(ref[0], scattered[0]) == pytest.approx(10.0)
    assert sm.errors_of_sequence_mean(scattered, ref) == (pytest.approx(0.0), pytest.approx(0.0))
    # a frame turned 30 deg up and one 30 deg down: no angle on the mean, but its length is
    # the cosine's (cos 30 deg = 0.866 of the reference)
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    rmve, aemv = sm.errors_of_sequence_mean([[c, s, 0.0], [c, -s, 0.0]], ref[:2])
    assert rmve == pytest.approx(100.0 * (1.0 - c)) and aemv == pytest.approx(0.0, abs=1e-6)
    # 20 % fast in every frame stays 20 %; a frame whose reference is missing is left out
    biased = sm.errors_of_sequence_mean([[0.0, 1.2, 0.0]] * 2 + [[5.0, 0.0, 0.0]],
                                        [[0.0, 1.0, 0.0]] * 2 + [None])
    assert biased == (pytest.approx(20.0), pytest.approx(0.0, abs=1e-6))
    assert sm.errors_of_sequence_mean([None], ref[:1]) == (None, None)
    with pytest.raises(ValueError, match="one reference mean per computed mean"):
        sm.errors_of_sequence_mean(scattered, ref[:2])


def test_aee_3d_hand_computed() -> None:
    ref = _field([[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    got = _field([[1, 0, 0], [0, 4, 4], [9, 9, 9]])
    region = np.array([[True, True, False]])
    # errors: 0 and |(0, 3, 4)| = 5 -> mean 2.5 m/s
    assert sm.aee_3d(ref, got, region) == pytest.approx(2.5)
    assert sm.aee_3d(ref, got, np.zeros((1, 3), bool)) is None


def test_aae_3d_uses_absolute_dot_product_as_printed() -> None:
    ref = _field([[1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0]])
    # angles 0, 90, 45 and a reversed vector: |cos| = 1 -> 0 (Eq. 10's |V* . V|)
    got = _field([[2, 0, 0], [0, 1, 0], [1, 1, 0], [-1, 0, 0]])
    region = np.ones((1, 4), bool)
    assert sm.aae_3d(ref, got, region) == pytest.approx((0 + 90 + 45 + 0) / 4)


def test_aae_3d_skips_zero_vectors_and_flags_all_zero() -> None:
    ref = _field([[1, 0, 0], [0, 0, 0]])
    got = _field([[1, 1, 0], [1, 0, 0]])
    assert sm.aae_3d(ref, got, np.ones((1, 2), bool)) == pytest.approx(45.0)
    assert sm.aae_3d(_field([[0, 0, 0]]), _field([[1, 0, 0]]), np.ones((1, 1), bool)) is None


def test_histogram_correlation_identical_and_hand_computed() -> None:
    ref = np.array([0.1, 0.2, 0.2, 0.9, 1.0])
    assert sm.histogram_correlation(ref, ref) == pytest.approx(1.0)
    # 2 bins over [0, 1]: reference counts (3, 2), computed (1, 2): mean-free (0.5, -0.5)
    # and (-0.5, 0.5) -> r = -1.
    got = np.array([0.1, 0.8, 0.9])
    assert sm.histogram_correlation(ref, got, bins=2) == pytest.approx(-1.0)
    # 3 bins over [0, 3]: ref counts (2, 1, 1), computed (1, 1, 2)
    # a = (2/3, -1/3, -1/3), b = (-1/3, -1/3, 2/3): a.b = -1/3, |a|^2 = |b|^2 = 2/3 -> -0.5
    ref3 = np.array([0.5, 0.5, 1.5, 3.0])
    got3 = np.array([0.5, 1.5, 2.5, 2.9])
    assert sm.histogram_correlation(ref3, got3, bins=3) == pytest.approx(-0.5)


def test_histogram_correlation_uses_component_magnitudes() -> None:
    # Negative components (V_Y of rising gas) are counted by magnitude: the sign-flipped
    # field has the same histogram.
    ref = np.array([-0.1, -0.5, -0.5, -0.9, -1.2])
    assert sm.histogram_correlation(ref, -ref) == pytest.approx(1.0)
    assert sm.histogram_correlation(ref, ref) == pytest.approx(1.0)


def test_histogram_correlation_drops_values_beyond_the_reference_range() -> None:
    ref = np.array([0.25, 0.75, 0.75])
    # 2 bins over [0, 0.75]: ref (1, 2). computed 0.25, 0.7, 0.7 and 5.0 (outside) -> (1, 2)
    got = np.array([0.25, 0.7, 0.7, 5.0])
    assert sm.histogram_correlation(ref, got, bins=2) == pytest.approx(1.0)


def test_histogram_correlation_degenerate_cases_are_flagged_not_nan() -> None:
    ref = np.array([0.1, 0.5, 0.9])
    assert sm.histogram_correlation(np.zeros(3), ref) is None  # no range
    assert sm.histogram_correlation(np.array([]), ref) is None
    assert sm.histogram_correlation(ref, np.array([])) is None
    # every computed value outside the range: all bins 0, zero variance
    assert sm.histogram_correlation(ref, np.array([7.0, 8.0])) is None
    with pytest.raises(ValueError):
        sm.histogram_correlation(np.array([np.nan]), ref)
    with pytest.raises(ValueError):
        sm.histogram_correlation(ref, ref, bins=1)


def test_histogram_correlations_per_component() -> None:
    rng = np.random.default_rng(3)
    ref = rng.normal(size=(20, 30, 3))
    region = np.ones((20, 30), bool)
    r = sm.histogram_correlations(ref, region, ref.copy(), region)
    assert r == pytest.approx((1.0, 1.0, 1.0))
    r = sm.histogram_correlations(ref, region, ref, np.zeros((20, 30), bool))
    assert r == (None, None, None)


def test_segmentation_ratio_and_overlap() -> None:
    ref = np.zeros((4, 4), bool)
    ref[:2, :] = True  # 8 px
    seg = np.zeros((4, 4), bool)
    seg[1:3, :2] = True  # 4 px, 2 of them inside the reference
    assert sm.segmentation_ratio(seg, ref) == pytest.approx(50.0)
    assert sm.segmentation_overlap(seg, ref) == pytest.approx(25.0)
    assert sm.segmentation_ratio(np.ones((4, 4), bool), ref) == pytest.approx(200.0)
    assert sm.segmentation_ratio(seg, np.zeros((4, 4), bool)) is None
    assert sm.segmentation_overlap(seg, np.zeros((4, 4), bool)) is None


def test_shape_errors_are_named() -> None:
    with pytest.raises(ValueError, match="shape"):
        sm.mean_velocity(np.zeros((2, 2, 2)), np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="region"):
        sm.aee_3d(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), np.ones((3, 2), bool))
    with pytest.raises(ValueError, match="boolean"):
        sm.segmentation_ratio(np.ones((2, 2)), np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="3-vector"):
        sm.rmve([1, 2], [1, 2, 3])


def test_metrics_never_return_nan() -> None:
    outs = [sm.rmve([1e-300, 0, 0], [1, 0, 0]), sm.aemv([1, 0, 0], [1e-300, 0, 0])]
    assert all(o is None or math.isfinite(o) for o in outs)
