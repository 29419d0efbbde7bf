"""The registration's error against the simulated jitter (benchmarks/registration_error.py)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import registration_error as re_


def test_a_perfect_registration_has_no_error() -> None:
    jl = (np.array([0.1, -0.2]), np.array([0.4, 0.3]))
    jr = (np.array([-0.5, 0.0]), np.array([0.2, -0.6]))
    err = re_.registration_errors((0.3, 0.5), (0.7, -0.6), jl, jr)
    np.testing.assert_allclose(err, np.zeros(5), atol=1e-12)


def test_errors_are_removed_less_true_and_the_d_prime_error_is_left_less_right() -> None:
    still = (np.zeros(2), np.zeros(2))
    err = re_.registration_errors((0.02, -0.01), (-0.03, 0.04), still, still)
    np.testing.assert_allclose(err, (0.02, -0.01, -0.03, 0.04, 0.05), atol=1e-12)
    # the same error in both cameras moves both views alike: d' does not see it
    same = re_.registration_errors((0.05, 0.0), (0.05, 0.0), still, still)
    assert same[4] == pytest.approx(0.0)


def test_vz_of_a_disparity_change_follows_eq_4() -> None:
    """s b = 234 px m, d = 36 px: Z = 6.5 m; 0.1 px per frame at 30 Hz is the change of
    depth Z(d + 0.1) - Z(d) per frame, about 0.54 m/s towards the cameras."""
    s, b, f = 780.0, 0.3, 30.0
    d = s * b / 6.5
    vz = re_.vz_of_change(0.1, d, s, b, f)
    exact = (s * b / (d + 0.1) - s * b / d) * f
    assert vz == pytest.approx(exact, rel=1e-5)
    assert vz == pytest.approx(-0.54, abs=0.01)
