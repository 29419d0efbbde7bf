"""Quality measure U_SF (paper Eq. 7) and c_USF (Eq. 8)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.velocity.quality import c_usf, scene_flow_energy

D, DP, U, V = 6, 1, 2, 1  # integer shifts: bicubic warps are exact, the match perfect
H, W = 60, 80


def _scene() -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(1)
    tex = cv2.GaussianBlur(rng.random((H + 20, W + 40)).astype(np.float32), (0, 0), 2.0)
    tex = (tex - tex.min()) / (tex.max() - tex.min())

    def view(dx: int, dy: int) -> np.ndarray:  # image(x, y) = tex(y + 10 - dy, x + 20 + dx)
        return np.ascontiguousarray(tex[10 - dy:10 - dy + H, 20 + dx:20 + dx + W])

    il0 = view(0, 0)
    ir0 = view(D, 0)  # ir0(x - D) = il0(x)
    il1 = view(-U, V)  # il1(x + U, y + V) = il0(x, y)
    ir1 = view(D + DP - U, V)  # ir1(x + U - D - DP, y + V) = il0(x, y)
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = U
    flow[..., 1] = V
    return il0, ir0, il1, ir1, flow


def test_perfect_match_gives_the_floor() -> None:
    il0, ir0, il1, ir1, flow = _scene()
    d = np.full((H, W), D, np.float32)
    dp = np.full((H, W), DP, np.float32)
    u_sf, valid = scene_flow_energy(il0, ir0, il1, ir1, flow, d, dp)
    assert u_sf.dtype == np.float32 and valid.dtype == np.bool_
    floor = (0.05 + 0.5 + 3.0) * 0.001  # psi(0) = eps for each of the five terms
    # Samples inside every image: x - D >= 0, x + U <= W - 1, y + V <= H - 1.
    expected = np.zeros((H, W), bool)
    expected[:H - V, D:W - U] = True
    np.testing.assert_array_equal(valid, expected)
    np.testing.assert_allclose(u_sf[valid], floor, atol=1e-4)
    c = c_usf(u_sf, np.ones((H, W), bool), valid)
    assert c == pytest.approx(np.exp(-floor), abs=1e-4)


def test_wrong_disparity_scores_worse() -> None:
    il0, ir0, il1, ir1, flow = _scene()
    dp = np.full((H, W), DP, np.float32)
    good, vg = scene_flow_energy(il0, ir0, il1, ir1, flow, np.full((H, W), D, np.float32), dp)
    bad, vb = scene_flow_energy(il0, ir0, il1, ir1, flow,
                                np.full((H, W), D + 1.5, np.float32), dp)
    both = vg & vb
    assert bad[both].mean() > 10 * good[both].mean()
    region = np.ones((H, W), bool)
    assert c_usf(bad, region, vb) < c_usf(good, region, vg) - 0.01
    # A non-smooth d' costs gamma2 psi(|grad d'|^2) even where the data fit.
    rough = dp + np.where(np.arange(W) % 2 == 0, 0.5, -0.5).astype(np.float32)[None, :]
    rough_u, _ = scene_flow_energy(il0, ir0, il1, ir1, flow, np.full((H, W), D, np.float32),
                                   rough)
    assert rough_u[vg].mean() > good[vg].mean()


def test_c_usf_empty_region_is_none() -> None:
    u = np.zeros((4, 4), np.float32)
    assert c_usf(u, np.zeros((4, 4), bool)) is None
    # Region non-empty but all of it invalid: also None, not NaN.
    assert c_usf(u, np.ones((4, 4), bool), np.zeros((4, 4), bool)) is None
    assert c_usf(u, np.ones((4, 4), bool)) == 1.0


def test_bad_input_raises() -> None:
    il0, ir0, il1, ir1, flow = _scene()
    d = np.full((H, W), D, np.float32)
    with pytest.raises(ValueError, match="differ in shape"):
        scene_flow_energy(il0, ir0, il1, ir1, flow, d[:, :10], d)
    with pytest.raises(ValueError, match="NaN"):
        scene_flow_energy(il0, ir0, il1, ir1, flow, d, np.full_like(d, np.nan))
    with pytest.raises(ValueError, match="flow must have shape"):
        scene_flow_energy(il0, ir0, il1, ir1, flow[:, :, 0], d, d)
    with pytest.raises(ValueError, match="boolean"):
        c_usf(d, np.ones((H, W), np.uint8))
    with pytest.raises(ValueError, match="differ in shape"):
        c_usf(d, np.ones((H, W + 1), bool))
    with pytest.raises(ValueError, match="NaN"):
        c_usf(np.full((2, 2), np.nan, np.float32), np.ones((2, 2), bool))
