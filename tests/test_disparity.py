"""Joint disparity and disparity change (paper Eq. 6): analytic planes and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from processing.flow.brox import brox_optical_flow
from processing.stereo.joint import joint_disparity
from tests.scene_flow_plane import S_PX, moving_plane, render, texture

# Pixels whose correspondences lie inside all four images at d ~ 78 px (the left 78 columns
# have no counterpart in the right image) with a margin for the pyramid's border effects.
REGION = (slice(15, -15), slice(100, -15))


@pytest.fixture(scope="module")
def plane():
    scene = moving_plane()
    return scene, brox_optical_flow(scene.il0, scene.il1)


def _static_pair(disparity: float) -> tuple[np.ndarray, np.ndarray]:
    """Left/right views of a fronto-parallel plane at 2 m and disparity ``disparity`` px.

    The baseline is chosen to give the disparity (b = d Z / s) so that the texture keeps
    its scale (a far plane would alias the 2 mm texels).
    """
    z = 2.0
    tex = texture(seed=3)
    return render(tex, z, (0.0, 0.0), 0.0), render(tex, z, (0.0, 0.0), disparity * z / S_PX)


def test_static_plane_from_zero_initialisation() -> None:
    # d = 12.3 px reached by coarse-to-fine warping from d0 = 0; static pair, zero flow.
    left, right = _static_pair(12.3)
    zero = np.zeros((*left.shape, 2), np.float32)
    d, dp = joint_disparity(left, right, left, right, zero, d0=0.0)
    assert d.dtype == np.float32 and dp.dtype == np.float32
    assert d.shape == left.shape
    err = np.abs(d[15:-15, 30:-15] - 12.3)
    # Measured 0.006 px mean, 0.015 px 99th percentile (with OpenCV's a = -0.75 bicubic
    # warp instead of Catmull-Rom it was 0.037 px: the bound would catch that regression).
    assert err.mean() < 0.02, err.mean()
    assert np.percentile(err, 99) < 0.05
    assert np.abs(dp).max() < 0.02  # identical t0/t1: no disparity change


def test_moving_plane_recovers_d_and_change(plane) -> None:
    # d = s b / Z0 = 78 px, d' = s b / Z1 - d = 1.188 px; initial minimum disparity 60 px.
    scene, flow = plane
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=60.0)
    # Measured: mean errors 0.0003 px (d) and 0.0004 px (d').
    assert abs(float(np.mean(d[REGION])) - scene.d) < 0.02
    assert np.percentile(np.abs(d[REGION] - scene.d), 99) < 0.05
    assert abs(float(np.mean(dp[REGION])) - scene.d_change) < 0.02
    assert np.percentile(np.abs(dp[REGION] - scene.d_change), 99) < 0.05


def test_initial_disparity_field_is_used(plane) -> None:
    scene, flow = plane
    init = np.full(scene.il0.shape, 77.0)  # e.g. an SGM estimate; float64 is accepted
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow,
                            initial_disparity=init)
    assert abs(float(np.mean(d[REGION])) - scene.d) < 0.05
    assert abs(float(np.mean(dp[REGION])) - scene.d_change) < 0.05


def test_interpolated_finest_level_keeps_a_warm_moving_plane(plane) -> None:
    # The chain's warm start: 6 levels from the previous fields (here 0.3 px off in d), the
    # finest interpolated from the next one (finest_level 1) instead of solved.
    scene, flow = plane
    start = np.full(scene.il0.shape, scene.d + 0.3, np.float32)
    change = np.full(scene.il0.shape, scene.d_change, np.float32)
    warm = {"n_levels": 6, "n_warps": 1, "n_inner": 2, "n_sor": 8}
    solved = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow,
                             initial_disparity=start, initial_change=change, **warm)
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow,
                            initial_disparity=start, initial_change=change, finest_level=1,
                            **warm)
    assert d.shape == dp.shape == scene.il0.shape
    assert not np.array_equal(d, solved[0])  # the finest level really was left out
    # Measured: mean errors 0.0006 px (d) and 0.0014 px (d'), 99th percentiles 0.023 and
    # 0.008 px (solved: 0.007 and 0.005); the bounds are those of the solved plane above.
    assert abs(float(np.mean(d[REGION])) - scene.d) < 0.02
    assert np.percentile(np.abs(d[REGION] - scene.d), 99) < 0.05
    assert abs(float(np.mean(dp[REGION])) - scene.d_change) < 0.02
    assert np.percentile(np.abs(dp[REGION] - scene.d_change), 99) < 0.05


@pytest.fixture(scope="module")
def patch_plane():
    # Texture only on a 0.3 m disk of the plane (7800 of 76800 px), like a gas cloud.
    scene = moving_plane(patch_radius_m=0.15)
    textured = np.abs(scene.il0 - 0.5) > 0.02
    return scene, brox_optical_flow(scene.il0, scene.il1), textured


@pytest.mark.parametrize("start", [0.0, -1.0, 2.0])
def test_change_of_a_partly_textured_plane_does_not_depend_on_the_start(patch_plane,
                                                                          start: float) -> None:
    # d' is smooth with a stiff weight and constrained by data only on the texture; SOR
    # barely moved its constant part, which kept its start (measured without the
    # constant-mode step: d' 0.77 / -0.13 / 1.83 px from 0 / -1 / 2; with it 1.184 px).
    scene, flow, textured = patch_plane
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=60.0,
                            initial_change=np.full(textured.shape, start, np.float32))
    assert abs(float(np.median(d[textured])) - scene.d) < 0.02
    assert abs(float(np.median(dp[textured])) - scene.d_change) < 0.02


def test_blanked_pixels_do_not_pull_the_solution(patch_plane) -> None:
    # A band through the textured patch is blanked to "no change" in all four images
    # (what the depth gate does to an object); in the right view at x - d. Measured: the
    # rest of the patch keeps d and d' within 0.003 px (without the constant-mode step
    # d fell to 60.7 px and d' to 0.07 px).
    scene, flow, textured = patch_plane
    left = np.zeros(textured.shape, bool)
    left[:, 150:200] = True
    right = np.roll(left, -78, axis=1)  # x_R = x_L - d, d = 78 px
    images = [np.where(mask, np.float32(0.5), im).astype(np.float32) for im, mask in (
        (scene.il0, left), (scene.ir0, right), (scene.il1, left), (scene.ir1, right))]
    d, dp = joint_disparity(*images, flow, d0=60.0, blanked=(left, right))
    keep = textured & ~left
    assert abs(float(np.median(d[keep])) - scene.d) < 0.02
    assert abs(float(np.median(dp[keep])) - scene.d_change) < 0.02
    with pytest.raises(ValueError, match="blanked right"):
        joint_disparity(*images, flow, d0=60.0, blanked=(left, right[:, :10]))


def test_flow_error_reaches_the_change_only_through_e3(plane) -> None:
    # The flow handed to Eq. 6 is 0.3 px off horizontally (as Brox's is in a gas's faint
    # parts). E3 (right image t0 -> t1) has its minimum where d' takes up the error; E1
    # and E4 measure d and d + d' at t0 and t1 directly. Measured d' error: +0.171 px with
    # the paper's weight (the default), +0.0001 px with E3 off.
    scene, flow = plane
    wrong = flow + np.asarray((0.3, 0.0), np.float32)
    _, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, wrong, d0=60.0)
    assert float(np.mean(dp[REGION])) - scene.d_change > 0.1
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, wrong, d0=60.0,
                            right_temporal_weight=0.0)
    assert abs(float(np.mean(d[REGION])) - scene.d) < 0.02
    assert abs(float(np.mean(dp[REGION])) - scene.d_change) < 0.02


def test_shared_pyramids_give_the_same_fields(plane) -> None:
    # The chain hands one pyramid cache to the flow and the joint solver: the second takes
    # the left images' levels from it and must solve exactly as without it.
    from processing.solvers.variational import PyramidCache

    scene, _ = plane
    cache = PyramidCache()
    flow = brox_optical_flow(scene.il0, scene.il1, pyramid_cache=cache)
    alone = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=60.0)
    shared = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=60.0,
                             pyramid_cache=cache)
    np.testing.assert_array_equal(alone[0], shared[0])
    np.testing.assert_array_equal(alone[1], shared[1])
    # the flow's two pyramids and the right images' two, not six
    assert len(cache) == 4


def test_far_initialisation_fails_visibly(plane) -> None:
    # d0 = 0 for a 78 px disparity (a quarter of the width) is outside the method's reach:
    # the paper's reason for giving d0. The test documents that the setting matters.
    scene, flow = plane
    d, _ = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=0.0)
    assert np.mean(np.abs(d[REGION] - scene.d)) > 5.0


def test_float64_and_float32_agree() -> None:
    left, right = _static_pair(8.0)
    zero = np.zeros((*left.shape, 2), np.float32)
    d32, _ = joint_disparity(left, right, left, right, zero)
    d64, _ = joint_disparity(left.astype(np.float64), right.astype(np.float64),
                             left.astype(np.float64), right.astype(np.float64),
                             zero.astype(np.float64))
    np.testing.assert_allclose(d32, d64, atol=1e-4)


def _good():
    rng = np.random.default_rng(0)
    img = rng.random((32, 40)).astype(np.float32)
    return img, np.zeros((32, 40, 2), np.float32)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: {"il0": a["il0"][:, :30]}, "differ in shape"),
        (lambda a: {"ir1": a["ir1"].astype(np.uint8)}, "floating-point"),
        (lambda a: {"il1": np.where(a["il1"] > 0.5, np.nan, a["il1"])}, "NaN"),
        (lambda a: {"ir0": a["ir0"][None]}, "2-D"),
        (lambda a: {"il0": a["il0"][:4, :4], "ir0": a["ir0"][:4, :4],
                    "il1": a["il1"][:4, :4], "ir1": a["ir1"][:4, :4]}, "too small"),
        (lambda a: {"flow": a["flow"][..., :1]}, "flow must have shape"),
        (lambda a: {"flow": np.full_like(a["flow"], np.inf)}, "flow contains"),
        (lambda a: {"gamma1": 0.0}, "gamma1"),
        (lambda a: {"gamma2": -1.0}, "gamma2"),
        (lambda a: {"right_temporal_weight": -0.5}, "right_temporal_weight"),
        (lambda a: {"omega": 2.0}, "omega"),
        (lambda a: {"n_sor": 0}, "n_sor"),
        (lambda a: {"n_inner_finest": 0}, "n_inner_finest"),
        (lambda a: {"finest_level": -1}, "finest_level"),
        (lambda a: {"finest_level": 1.0}, "finest_level"),
        (lambda a: {"finest_level": 2, "n_levels": 2}, "finest_level"),
        (lambda a: {"n_warps": 1.5}, "n_warps"),
        (lambda a: {"pyramid_factor": 1.0}, "pyramid_factor"),
        (lambda a: {"d0": float("nan")}, "d0"),
        (lambda a: {"initial_disparity": np.zeros((3, 3), np.float32)}, "initial_disparity"),
    ],
)
def test_bad_input_raises(change, message: str) -> None:
    img, flow = _good()
    args = {"il0": img, "ir0": img, "il1": img, "ir1": img, "flow": flow}
    args.update(change(args))
    with pytest.raises(ValueError, match=message):
        joint_disparity(args.pop("il0"), args.pop("ir0"), args.pop("il1"), args.pop("ir1"),
                        args.pop("flow"), **args)


def test_catmull_rom_warp_is_exact_for_quadratics_and_integer_shifts() -> None:
    from processing.solvers import derivatives

    yy, xx = np.mgrid[0:30, 0:40].astype(np.float32)
    quad = 0.01 * (xx - 12.0) ** 2 + 0.02 * (yy - 7.0) ** 2 + 0.003 * xx * yy
    mx, my = xx + 0.3, yy - 0.45
    a, ax = derivatives.warp_dx_catmull_rom(quad, mx, my)
    exact = 0.01 * (mx - 12.0) ** 2 + 0.02 * (my - 7.0) ** 2 + 0.003 * mx * my
    exact_dx = 0.02 * (mx - 12.0) + 0.003 * my
    inner = (slice(2, -2), slice(2, -2))
    np.testing.assert_allclose(a[inner], exact[inner], atol=1e-4)
    np.testing.assert_allclose(ax[inner], exact_dx[inner], atol=1e-4)
    rng = np.random.default_rng(0)
    img = rng.random((30, 40)).astype(np.float32)
    shifted, _ = derivatives.warp_dx_catmull_rom(img, xx + 3, yy - 2)
    np.testing.assert_allclose(shifted[2:, :-3], img[:-2, 3:], atol=1e-6)
    # Outside the image the border is replicated (as derivatives.warp does), flat in x.
    out, out_dx = derivatives.warp_dx_catmull_rom(img, np.full_like(xx, -5.0), yy)
    np.testing.assert_allclose(out, np.repeat(img[:, :1], 40, axis=1), atol=1e-6)
    assert np.all(out_dx == 0.0)


def test_row_sampler_equals_the_general_sampler_on_pixel_rows() -> None:
    import numba

    from processing.solvers import derivatives

    @numba.njit
    def on_rows(padded: np.ndarray, mx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        value = np.empty(mx.shape, np.float32)
        slope = np.empty(mx.shape, np.float32)
        for y in range(mx.shape[0]):
            for x in range(mx.shape[1]):
                value[y, x], slope[y, x] = derivatives.catmull_rom_dx_on_row(padded, mx[y, x], y)
        return value, slope

    rng = np.random.default_rng(3)
    img = rng.random((20, 30)).astype(np.float32)
    yy, xx = np.mgrid[0:20, 0:30].astype(np.float32)
    mx = xx + rng.normal(0.0, 6.0, xx.shape).astype(np.float32)  # some outside the image
    general = derivatives.warp_dx_catmull_rom(img, mx, yy)
    rows = on_rows(derivatives.pad_for_sampling(img), mx)
    np.testing.assert_allclose(rows[0], general[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(rows[1], general[1], rtol=0, atol=1e-6)
