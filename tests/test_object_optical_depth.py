"""benchmarks/object_optical_depth.py: the differential optical depth of a warm object's
moving edge and of moving gas, on radiance images whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import object_optical_depth as ood

L_BG, L_GAS, L_OBJ = 0.030, 0.014, 0.048  # radiance of the wall, the gas and the object


def _frames(shift_px: int, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Radiance (with the object, without it): gas of transmittance ``tau`` in rows
    10-19 in front of the wall, a warm 8 x 8 object in rows 30-37 from column
    10 + ``shift_px``."""
    clean = np.full((48, 64), L_BG, np.float32)
    clean[10:20, 10:40] = L_BG * tau + L_GAS * (1 - tau)
    with_object = clean.copy()
    with_object[30:38, 10 + shift_px:18 + shift_px] = L_OBJ
    return with_object, clean


def test_an_edge_reads_the_object_contrast_and_gas_its_change_of_optical_depth() -> None:
    (o0, c0), (o1, c1) = _frames(0, 0.80), _frames(3, 0.78)
    gas = np.zeros(c0.shape, bool)
    gas[10:20, 10:40] = True
    edges, moving = ood.pair_depths((o0, o1), (c0, c1), gas, L_GAS, 1e-4)
    # the object covered 3 new columns and left 3: 2 x 3 x 8 pixels changed
    assert edges.size == 48
    assert edges == pytest.approx((L_OBJ - L_BG) / ((L_OBJ + L_BG) / 2 - L_GAS), rel=1e-4)
    assert moving.size == gas.sum()
    assert moving == pytest.approx(0.02 / 0.79, rel=1e-3)
    # the separation the benchmark reports: the edges far above the gas
    assert edges.min() > 10 * moving.max()


def test_still_frames_give_no_edge_and_no_moving_gas() -> None:
    o, c = _frames(0, 0.8)
    edges, moving = ood.pair_depths((o, o), (c, c), np.ones(c.shape, bool), L_GAS, 1e-4)
    assert edges.size == 0 and moving.size == 0
