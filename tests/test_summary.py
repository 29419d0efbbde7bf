"""Per-frame gas summary: mean 3D velocity, magnitude, directional angles (footnote 1)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from processing.chain.summary import directional_angles, summarize_frame


def _fields(h: int = 6, w: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    velocity = np.zeros((h, w, 3), np.float32)
    valid = np.ones((h, w), bool)
    gas = np.zeros((h, w), bool)
    return velocity, valid, gas


def test_hand_computed_mean_speed_and_angles() -> None:
    velocity, valid, gas = _fields()
    gas[1:3, 1:3] = True  # 4 gas pixels
    velocity[1, 1] = (0.0, 2.0, 2.0)
    velocity[1, 2] = (2.0, 2.0, 2.0)
    velocity[2, 1] = (1.0, 2.0, 2.0)
    velocity[2, 2] = (1.0, 2.0, 2.0)
    velocity[4, 4] = (100.0, 0.0, 0.0)  # not gas: ignored
    s = summarize_frame(velocity, valid, gas, c_usf=0.8)
    assert s.valid
    assert s.pixel_count == 4 and s.gas_pixel_count == 4
    assert s.mean_velocity == pytest.approx((1.0, 2.0, 2.0))
    assert s.speed == pytest.approx(3.0)
    expected = tuple(math.degrees(math.acos(c)) for c in (1 / 3, 2 / 3, 2 / 3))
    assert s.angles_deg == pytest.approx(expected)  # (70.53, 48.19, 48.19)
    assert s.c_usf == pytest.approx(0.8)


def test_invalid_pixels_are_left_out_even_when_nan() -> None:
    velocity, valid, gas = _fields()
    gas[:, :] = True
    velocity[:] = (0.0, 0.0, -1.5)
    velocity[0, 0] = (np.nan, np.inf, 1.0)
    valid[0, 0] = False
    velocity[0, 1] = (np.nan, 0.0, 0.0)  # flagged valid but non-finite: still left out
    s = summarize_frame(velocity, valid, gas)
    assert s.pixel_count == 6 * 8 - 2 and s.gas_pixel_count == 48
    assert s.mean_velocity == pytest.approx((0.0, 0.0, -1.5))
    assert s.angles_deg == pytest.approx((90.0, 90.0, 180.0))
    assert s.c_usf is None


def test_empty_region_gives_flagged_summary_without_non_finite_values() -> None:
    velocity, valid, gas = _fields()
    velocity[:] = np.nan
    s = summarize_frame(velocity, valid, gas, c_usf=float("nan"))
    assert not s.valid
    assert s.pixel_count == 0 and s.gas_pixel_count == 0
    assert s.mean_velocity is None and s.speed is None and s.angles_deg is None
    assert s.c_usf is None
    json.dumps(s.to_dict(), allow_nan=False)  # nothing non-finite
    gas[2, 2] = True
    valid[2, 2] = False
    s2 = summarize_frame(velocity, valid, gas)
    assert not s2.valid and s2.pixel_count == 0 and s2.gas_pixel_count == 1


def test_zero_mean_has_speed_but_no_direction() -> None:
    velocity, valid, gas = _fields()
    gas[0, 0:2] = True
    velocity[0, 0] = (1.0, 0.0, 0.0)
    velocity[0, 1] = (-1.0, 0.0, 0.0)
    s = summarize_frame(velocity, valid, gas)
    assert not s.valid and s.speed == 0.0 and s.angles_deg is None
    assert directional_angles(np.zeros(3)) is None


@pytest.mark.parametrize(
    ("velocity", "valid", "gas", "match"),
    [
        (np.zeros((6, 8, 2)), np.ones((6, 8), bool), np.ones((6, 8), bool), "velocity"),
        (np.zeros((6, 8, 3), int), np.ones((6, 8), bool), np.ones((6, 8), bool), "floating"),
        (np.zeros((6, 8, 3)), np.ones((6, 7), bool), np.ones((6, 8), bool), "valid"),
        (np.zeros((6, 8, 3)), np.ones((6, 8), bool), np.ones((6, 8), np.uint8), "boolean"),
    ],
)
def test_bad_input_raises(
    velocity: np.ndarray, valid: np.ndarray, gas: np.ndarray, match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        summarize_frame(velocity, valid, gas)
