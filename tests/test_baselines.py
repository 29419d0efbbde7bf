"""Decoupled baselines of Sec. 5.1: SGBM at t0 and t1, d' along the flow."""

from __future__ import annotations

import numpy as np
import pytest

from processing.metrics.baselines import change_along_flow, sgm_brox, sgm_farneback
from processing.stereo.sgm import sgbm_disparity, sgbm_initial_disparity
from tests.scene_flow_plane import moving_plane

# SGBM with a 128 px search range has no result left of x = 127.
REGION = (slice(15, -15), slice(130, -15))


@pytest.fixture(scope="module")
def scene():
    return moving_plane()


def test_sgbm_recovers_plane_disparity(scene) -> None:
    d, valid = sgbm_disparity(scene.il0, scene.ir0, num_disparities=128)
    assert d.dtype == np.float32 and valid.dtype == np.bool_
    assert valid[REGION].mean() > 0.95
    assert np.median(np.abs(d[REGION][valid[REGION]] - scene.d)) < 0.25
    # Left of x = 127 px the whole search range does not fit: SGBM returns no disparity.
    assert not valid[:, :126].any()
    assert np.all(d[~valid] == 0.0)


def test_initial_disparity_fills_holes(scene) -> None:
    init = sgbm_initial_disparity(scene.il0, scene.ir0, num_disparities=128)
    assert np.all(np.isfinite(init))
    assert np.median(init) == pytest.approx(scene.d, abs=0.25)


def test_change_along_flow_bilinear_and_validity() -> None:
    h, w = 20, 30
    xx = np.tile(np.arange(w, dtype=np.float32), (h, 1))
    d0 = np.full((h, w), 10.0, np.float32)
    d1 = 10.0 + 0.1 * xx  # a ramp: bilinear sampling is exact on it
    v0 = np.ones((h, w), bool)
    v1 = np.ones((h, w), bool)
    v1[5, 12] = False  # a hole at t1
    flow = np.zeros((h, w, 2), np.float32)
    flow[..., 0] = 1.5
    change, valid = change_along_flow(d0, v0, d1.astype(np.float32), v1, flow)
    # x + 1.5 is inside for x <= 27; the hole spoils x + 1.5 in (11, 13): x = 10, 11.
    assert valid[0, :28].all() and not valid[0, 28:].any()
    assert not valid[5, 10] and not valid[5, 11] and valid[5, 9] and valid[5, 12]
    np.testing.assert_allclose(change[valid], (0.1 * (xx + 1.5))[valid], atol=1e-5)
    assert np.all(change[~valid] == 0.0)


@pytest.mark.parametrize("method", [sgm_brox, sgm_farneback])
def test_baselines_on_moving_plane(scene, method) -> None:
    res = method(scene.il0, scene.ir0, scene.il1, scene.ir1, num_disparities=128)
    assert res.flow.shape == (*scene.il0.shape, 2)
    ok = res.valid[REGION]
    assert ok.mean() > 0.9
    assert abs(np.median(res.d[REGION][ok]) - scene.d) < 0.25
    # SGBM's 1/16-px quantisation and sub-pixel bias: d' within 0.25 px (1.188 px true).
    assert abs(np.median(res.d_change[REGION][ok]) - scene.d_change) < 0.25
    assert np.all(res.d[~res.valid] == 0.0) and np.all(res.d_change[~res.valid] == 0.0)


def test_bad_input_raises(scene) -> None:
    with pytest.raises(ValueError, match="multiple of 16"):
        sgbm_disparity(scene.il0, scene.ir0, num_disparities=100)
    with pytest.raises(ValueError, match="block_size"):
        sgbm_disparity(scene.il0, scene.ir0, block_size=4)
    with pytest.raises(ValueError, match="differ in shape"):
        sgm_farneback(scene.il0, scene.ir0[:, :100], scene.il1, scene.ir1)
    with pytest.raises(ValueError, match="floating-point"):
        sgm_brox(scene.il0, scene.ir0, (scene.il1 * 255).astype(np.uint8), scene.ir1)
