"""Sensor axes -> left camera frame, and the wind history."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.anemometer.base import AnemometerConfigError, WindSample
from drivers.anemometer.history import GAP, OK, TOO_EARLY, TOO_LATE, WindHistory
from drivers.anemometer.mounting import NATIVE_AXES, CameraWind, Mounting, reference_to_camera


def sample(u: float, v: float, w: float, ns: int = 0, valid: bool = True) -> WindSample:
    return WindSample(ns, None, u, v, w, 340.0, 20.0, 0, "OK", valid)


def cam(protocol: str, u: float, v: float, w: float, **mount: float) -> np.ndarray:
    return Mounting.from_config(protocol, mount).to_camera(sample(u, v, w)).vector


def test_gill_axes_with_mark_along_optical_axis() -> None:
    # Mark straight ahead of the camera: toward the mark = forward (+Z), V (left) = -X,
    # up = -Y.
    np.testing.assert_allclose(cam("gill", 1, 0, 0), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(cam("gill", 0, 1, 0), [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cam("gill", 0, 0, 1), [0, -1, 0], atol=1e-12)


def test_azimuth_is_clockwise_from_the_optical_axis() -> None:
    np.testing.assert_allclose(cam("gill", 1, 0, 0, azimuth_deg=90), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cam("gill", 1, 0, 0, azimuth_deg=180), [0, 0, -1], atol=1e-12)


def test_camera_tilt_down_and_roll() -> None:
    # Camera looking 30 deg down: rising air moves up in the image and toward the camera.
    s30, c30 = math.sin(math.radians(30)), math.cos(math.radians(30))
    np.testing.assert_allclose(cam("gill", 0, 0, 1, tilt_deg=30), [0, -c30, -s30], atol=1e-12)
    # Horizontal wind along the optical axis now points partly up in the image.
    np.testing.assert_allclose(cam("gill", 1, 0, 0, tilt_deg=30), [0, -s30, c30], atol=1e-12)
    # Camera rolled 90 deg clockwise (seen from behind): "up" in the world is image -X.
    np.testing.assert_allclose(cam("gill", 0, 0, 1, roll_deg=90), [-1, 0, 0], atol=1e-12)


def test_native_axes_handedness() -> None:
    for name, m in NATIVE_AXES.items():
        det = np.linalg.det(m)
        assert det == pytest.approx(-1.0 if name == "metek_usonic3" else 1.0), name
    # CSAT3B: +Ux is wind entering the front of the array (pointing along the mark).
    np.testing.assert_allclose(cam("campbell_csat3b", 1, 0, 0), [0, 0, -1], atol=1e-12)
    # Young: +V toward the mark, +U to its right.
    np.testing.assert_allclose(cam("young_81000", 0, 1, 0), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(cam("young_81000", 1, 0, 0), [1, 0, 0], atol=1e-12)
    # METEK: +y 90 deg clockwise of the mark (to its right).
    np.testing.assert_allclose(cam("metek_usonic3", 0, 1, 0), [1, 0, 0], atol=1e-12)


@settings(max_examples=50, deadline=None, derandomize=True)
@given(
    az=st.floats(-360, 360), tilt=st.floats(-89, 89), roll=st.floats(-180, 180),
    vec=st.tuples(*[st.floats(-40, 40)] * 3),
)
def test_mounting_is_a_rotation_and_matrix_form_agrees(az, tilt, roll, vec) -> None:
    r = reference_to_camera(az, tilt, roll)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    by_angles = cam("gill", *vec, azimuth_deg=az, tilt_deg=tilt, roll_deg=roll)
    by_matrix = Mounting.from_config("gill", {"matrix": r.tolist()}).to_camera(sample(*vec)).vector
    np.testing.assert_allclose(by_angles, by_matrix, atol=1e-9)
    assert np.linalg.norm(by_angles) == pytest.approx(np.linalg.norm(vec), abs=1e-9)


def test_mounting_config_errors_name_the_key() -> None:
    with pytest.raises(AnemometerConfigError, match="unknown mounting key"):
        Mounting.from_config("gill", {"azimut_deg": 3})
    with pytest.raises(AnemometerConfigError, match="either 'matrix' or angles"):
        Mounting.from_config("gill", {"matrix": np.eye(3).tolist(), "tilt_deg": 2})
    with pytest.raises(AnemometerConfigError, match=r"mounting\.matrix is not orthonormal"):
        Mounting.from_config("gill", {"matrix": [[1, 0, 0], [0, 2, 0], [0, 0, 1]]})
    with pytest.raises(AnemometerConfigError, match="determinant"):
        Mounting.from_config("gill", {"matrix": np.diag([1, 1, -1]).tolist()})
    with pytest.raises(AnemometerConfigError, match="3x3"):
        Mounting.from_config("gill", {"matrix": [[1, 0], [0, 1]]})
    with pytest.raises(AnemometerConfigError, match="native axes"):
        Mounting.from_config("unknown_sensor", {})
    flipped = Mounting.from_config("gill", {"native_axes": np.diag([1, -1, 1]).tolist()})
    np.testing.assert_allclose(flipped.to_camera(sample(0, 1, 0)).vector, [1, 0, 0], atol=1e-12)


def test_2d_sensor_vertical_not_measured() -> None:
    cw = Mounting.from_config("gill_polar", {}).to_camera(sample(1, 0, math.nan))
    assert not cw.vertical_measured and np.all(np.isfinite(cw.vector))


def cw(ns: int, x: float, valid: bool = True) -> CameraWind:
    return CameraWind(ns, np.array([x, 0.0, 0.0]), valid, True)


def test_history_interpolates_and_flags_gaps() -> None:
    h = WindHistory(capacity=100, max_gap_s=0.5)
    for ns, x in [(0, 0.0), (100_000_000, 1.0), (200_000_000, 3.0), (1_000_000_000, 5.0)]:
        assert h.add(cw(ns, x))
    mid = h.at(150_000_000)
    assert mid.flag == OK and mid.vector[0] == pytest.approx(2.0)
    assert h.at(100_000_000).vector[0] == 1.0
    gap = h.at(600_000_000)
    assert gap.flag == GAP and np.all(np.isnan(gap.vector)) and gap.span_ns == 800_000_000
    assert h.at(-1).flag == TOO_EARLY and h.at(1_000_000_001).flag == TOO_LATE


def test_history_rejects_invalid_and_out_of_order_and_stays_bounded() -> None:
    h = WindHistory(capacity=10, max_gap_s=1.0)
    assert not h.add(cw(5, 1.0, valid=False))
    h.add(cw(10, 1.0))
    assert not h.add(cw(10, 2.0))
    assert h.rejected_invalid == 1 and h.rejected_out_of_order == 1
    for k in range(1, 100):
        h.add(cw(10 + k, float(k)))
    assert len(h) <= 20
    assert h.at(10 + 99 - 9).ok and h.at(10 + 99 - 10).flag == TOO_EARLY
    with pytest.raises(ValueError, match="max_gap_s"):
        WindHistory(max_gap_s=0)
