"""The fused per-pixel pass equals the reference velocity, position and U_SF functions."""

from __future__ import annotations

import numpy as np
import pytest

from processing.velocity.pixelwise import velocity_and_quality
from processing.velocity.quality import scene_flow_energy
from processing.velocity.triangulate import scene_flow_velocity, surface_position

GEO = dict(principal_point=(15.5, 11.0), camera_constant=300.0, baseline=0.2)


def _inputs(seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    h, w = 24, 32
    imgs = [rng.random((h, w)).astype(np.float32) for _ in range(4)]
    flow = rng.normal(0.0, 2.0, (h, w, 2)).astype(np.float32)
    d = rng.uniform(-1.0, 12.0, (h, w)).astype(np.float32)  # some invalid (d <= 0)
    dp = rng.normal(0.0, 0.5, (h, w)).astype(np.float32)
    dp[0, 0] = -d[0, 0] - 1.0 if d[0, 0] > 0 else dp[0, 0]  # d + d' <= 0
    return flow, d, dp, *imgs


def test_fused_pass_matches_the_references() -> None:
    flow, d, dp, il0, ir0, il1, ir1 = _inputs()
    vel, pos, valid, u_sf, u_ok = velocity_and_quality(flow, d, dp, (il0, ir0, il1, ir1),
                                                       dt=1 / 30, **GEO)
    ref_v, ref_valid = scene_flow_velocity(flow, d, dp, dt=1 / 30, **GEO)
    ref_p, p_valid = surface_position(d, **GEO)
    ref_valid &= p_valid
    np.testing.assert_array_equal(valid, ref_valid)
    assert 0 < valid.sum() < valid.size
    np.testing.assert_allclose(vel, np.where(ref_valid[..., None], ref_v, 0), rtol=1e-5,
                               atol=1e-5)
    np.testing.assert_allclose(pos, np.where(ref_valid[..., None], ref_p, 0), rtol=1e-5,
                               atol=1e-6)
    ref_u, ref_ok = scene_flow_energy(il0, ir0, il1, ir1, flow, d, dp)
    np.testing.assert_array_equal(u_ok, ref_ok)
    np.testing.assert_allclose(u_sf, ref_u, rtol=1e-5, atol=1e-6)


def test_quality_only_where_asked_and_everything_else_unchanged() -> None:
    flow, d, dp, *imgs = _inputs(2)
    full = velocity_and_quality(flow, d, dp, tuple(imgs), dt=1 / 30, **GEO)
    gas = np.zeros(d.shape, bool)
    gas[5:15, 8:20] = True
    part = velocity_and_quality(flow, d, dp, tuple(imgs), dt=1 / 30, **GEO, quality_mask=gas)
    for a, b in zip(full[:3], part[:3], strict=True):  # velocity, position, valid
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(part[3][gas], full[3][gas])
    np.testing.assert_array_equal(part[4][gas], full[4][gas])
    assert np.isnan(part[3][~gas]).all() and not part[4][~gas].any()
    with pytest.raises(ValueError, match="quality_mask"):
        velocity_and_quality(flow, d, dp, tuple(imgs), dt=1 / 30, **GEO,
                             quality_mask=gas[:-1])


def test_non_finite_input_raises() -> None:
    flow, d, dp, *imgs = _inputs(1)
    d[3, 4] = np.nan
    with pytest.raises(ValueError, match="d contains NaN"):
        velocity_and_quality(flow, d, dp, tuple(imgs), dt=0.01, **GEO)


def test_huge_velocity_is_masked_never_inf() -> None:
    flow, d, dp, *imgs = _inputs(2)
    d[3, 4], dp[3, 4] = 1e-40, 0.0  # subnormal: b / d overflows float32
    vel, pos, valid, _, _ = velocity_and_quality(flow, d, dp, tuple(imgs), dt=0.01, **GEO)
    assert not valid[3, 4]
    assert np.isfinite(vel).all() and np.isfinite(pos).all()


def test_bad_shapes_raise() -> None:
    flow, d, dp, *imgs = _inputs()
    with pytest.raises(ValueError, match="d_change"):
        velocity_and_quality(flow, d, dp[:-1], tuple(imgs), dt=0.01, **GEO)
    with pytest.raises(ValueError, match="dt"):
        velocity_and_quality(flow, d, dp, tuple(imgs), dt=0.0, **GEO)
