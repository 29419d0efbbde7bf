"""Black-body radiance and the characteristic-curve fit (paper Sec. 4.1, ref. [16])."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from processing.calibration.radiometric import (
    CharacteristicCurve,
    apply_characteristic_curve,
    band_radiance,
    celsius_to_kelvin,
    fit_characteristic_curve,
    planck_spectral_radiance,
    roi_means,
)


@pytest.mark.parametrize("t_k", [250.0, 300.0, 373.15, 600.0])
def test_band_radiance_matches_adaptive_quadrature(t_k: float) -> None:
    ref, _ = quad(lambda lam: float(planck_spectral_radiance(lam, t_k)), 3.2e-6, 3.4e-6,
                  epsabs=0, epsrel=1e-12)
    assert band_radiance(t_k) == pytest.approx(ref, rel=1e-10)


def test_planck_total_radiance_is_stefan_boltzmann() -> None:
    # Units check: the whole spectrum gives sigma T^4 / pi (W m^-2 sr^-1).
    t = 500.0
    total = sum(quad(lambda lam: float(planck_spectral_radiance(lam, t)), a, b,
                     epsrel=1e-10, limit=200)[0]
                for a, b in ((1e-7, 2e-6), (2e-6, 2e-5), (2e-5, 1e-3)))
    assert total == pytest.approx(5.670374419e-8 * t**4 / np.pi, rel=1e-5)


def test_band_radiance_known_magnitude_and_monotonic() -> None:
    L = band_radiance(celsius_to_kelvin([20.0, 50.0, 100.0]))
    assert np.all(np.diff(L) > 0)
    assert 0.01 < L[0] < 0.1  # ~0.03 W m^-2 sr^-1 at room temperature in 3.2-3.4 um


@pytest.mark.parametrize("bad", [0.0, -5.0, np.nan])
def test_band_radiance_rejects_bad_temperature(bad: float) -> None:
    with pytest.raises(ValueError):
        band_radiance(bad)


def _frames(rng, gain, offset, t_c, n=5, curvature=0.0, shape=(240, 320), noise=20.0):
    L = band_radiance(celsius_to_kelvin(t_c))
    level = offset + gain * L + curvature * L * L
    frames = []
    for _ in range(n):
        f = level + rng.normal(0.0, noise, shape)
        f[:20] = 100  # the black body does not fill the frame; the ROI must exclude this
        frames.append(np.clip(np.rint(f), 0, 65535).astype(np.uint16))
    return frames


def test_fit_recovers_gain_and_offset_within_one_percent() -> None:
    rng = np.random.default_rng(0)
    gain, offset = 45000.0, 12000.0  # counts per W m^-2 sr^-1, counts
    temps_c = [20.0, 35.0, 50.0, 65.0, 80.0]
    means = [roi_means(_frames(rng, gain, offset, t)) for t in temps_c]
    curve = fit_characteristic_curve(celsius_to_kelvin(temps_c), means)
    assert curve.gain == pytest.approx(gain, rel=0.01)
    assert curve.offset == pytest.approx(offset, rel=0.01)
    assert curve.model == "linear"
    assert curve.residual_rms_counts < 1.0
    assert len(curve.residuals_counts) == 5 and curve.frames_per_temperature == (5,) * 5


def test_quadratic_fit_and_inverse() -> None:
    rng = np.random.default_rng(1)
    gain, offset, curv = 40000.0, 10000.0, -30000.0
    temps_c = [10.0, 30.0, 50.0, 70.0, 90.0]
    means = [roi_means(_frames(rng, gain, offset, t, curvature=curv, noise=2.0))
             for t in temps_c]
    curve = fit_characteristic_curve(celsius_to_kelvin(temps_c), means, quadratic=True)
    assert curve.gain == pytest.approx(gain, rel=0.01)
    assert curve.offset == pytest.approx(offset, rel=0.01)
    assert curve.curvature == pytest.approx(curv, rel=0.05)
    L = np.linspace(0.02, 0.2, 50)
    back = apply_characteristic_curve(curve.counts(L), curve)
    np.testing.assert_allclose(back, L, rtol=1e-5)
    # Beyond the extremum, counts map to the extremum's radiance, never NaN.
    assert np.isfinite(apply_characteristic_curve(np.array([1e9]), curve)).all()


def test_apply_inverts_linear_curve_and_returns_float32() -> None:
    curve = CharacteristicCurve(offset=1000.0, gain=5.0e4)
    counts = np.array([[1000, 6000], [11000, 51000]], np.uint16)
    out = apply_characteristic_curve(counts, curve)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [[0.0, 0.1], [0.2, 1.0]], rtol=1e-6)


def test_apply_without_curve_is_identity() -> None:
    counts = np.arange(12, dtype=np.uint16).reshape(3, 4)
    out = apply_characteristic_curve(counts, None)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, counts)


def test_fit_errors() -> None:
    t = celsius_to_kelvin([20.0, 40.0])
    with pytest.raises(ValueError, match="at least 3 distinct"):
        fit_characteristic_curve(t, [[1.0], [2.0]], quadratic=True)
    with pytest.raises(ValueError, match="not positive"):
        fit_characteristic_curve(t, [[2000.0, 2001.0], [1000.0]])
    with pytest.raises(ValueError, match="2 temperatures but 1"):
        fit_characteristic_curve(t, [[1.0]])
    with pytest.raises(ValueError, match="no frames"):
        fit_characteristic_curve(t, [[1.0], []])


def test_saturated_roi_is_refused() -> None:
    f = np.full((100, 100), 65535, np.uint16)
    with pytest.raises(ValueError, match="saturated"):
        roi_means([f])
