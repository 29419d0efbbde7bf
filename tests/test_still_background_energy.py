"""The still-background energy (benchmarks/still_background_energy.py) on known noise."""

from __future__ import annotations

import cv2
import numpy as np

from benchmarks import still_background_energy as sbe


def _noise(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    # Smoothed like the solvers' pre-smoothing: a noise image with a finite correlation length.
    return cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), 0.8)


def test_differential_images_sharing_a_frame_peak_at_zero_shift() -> None:
    rng = np.random.default_rng(3)
    frames = [_noise(rng, (120, 160)) for _ in range(3)]
    d0, d1 = frames[0] - frames[1], frames[1] - frames[2]
    mask = np.ones(d0.shape, bool)
    energy = sbe.shifted_energy(d0, d1, mask)
    zero = sbe.SHIFTS_PX.index(0.0)
    assert int(np.argmax(energy)) == zero
    assert energy[zero] > 1.08 * energy[0] and energy[zero] > 1.08 * energy[-1]


def test_independent_noise_has_no_peak() -> None:
    rng = np.random.default_rng(4)
    d0 = _noise(rng, (120, 160)) - _noise(rng, (120, 160))
    d1 = _noise(rng, (120, 160)) - _noise(rng, (120, 160))
    energy = sbe.shifted_energy(d0, d1, np.ones(d0.shape, bool))
    # Without a shared frame the shift changes the mean squared difference by the cubic's
    # smoothing of d1 only (a few %), not by the shared frame's 2 sigma^2 R(s).
    assert np.ptp(energy) < 0.05 * energy.mean()


def test_still_pixels_keep_clear_of_gas_blanked_pixels_and_borders() -> None:
    gas = np.zeros((80, 100), bool)
    gas[40, 50] = True
    blanked = np.zeros_like(gas)
    blanked[60, 20] = True
    keep = sbe.still_pixels(gas, blanked, margin_px=5)
    assert not keep[35:46, 45:56].any() and keep[34, 50] is np.True_
    assert not keep[60, 20] and keep[60, 21]
    assert not keep[:sbe.BORDER_PX].any() and not keep[:, -sbe.BORDER_PX:].any()


def test_the_right_view_sees_the_gas_left_by_its_disparity() -> None:
    gas = np.zeros((10, 40), bool)
    gas[5, 30] = True
    disparity = np.full(gas.shape, 12.0, np.float32)
    moved = sbe.seen_right(gas, disparity)
    assert moved[5, 18] and moved.sum() == 1
