"""Tests of the stereo OGI renderer and its ground truth (processing.synthetic.render)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from processing.synthetic.fluid import FluidParams
from processing.synthetic.render import (
    CountsModel,
    MovingObject,
    Radiometry,
    StereoCamera,
    Volume,
    band_radiance,
    column_integrals,
    ground_truth,
    project_points,
    radiance_image,
    ray_directions,
    to_counts,
)
from processing.synthetic.sequences import RenderOptions, SequenceConfig, SyntheticStereoScene

CAM = StereoCamera()  # s = 780 px, b = 0.2 m, 320 x 240


@pytest.mark.parametrize("xyz", [(0.0, 0.0, 2.0), (0.15, -0.1, 1.8), (-0.3, 0.2, 2.5)])
def test_point_projects_with_eq4_geometry(xyz: tuple[float, float, float]) -> None:
    X, Y, Z = xyz
    left, right = project_points(CAM, np.array(xyz))
    assert left[0] == pytest.approx(159.5 + 780.0 * X / Z)
    assert left[1] == pytest.approx(119.5 + 780.0 * Y / Z)
    assert right[1] == pytest.approx(left[1])
    # disparity d = x_L - x_R = s b / Z > 0 (the sign Eq. 4 uses: Z = s b / d)
    d = left[0] - right[0]
    assert d == pytest.approx(780.0 * 0.2 / Z)
    assert 780.0 * 0.2 / d == pytest.approx(Z)


def test_lens_option_reaches_rendering_and_meta() -> None:
    from processing.synthetic.sequences import preset

    cfg = preset("table2_1", options=RenderOptions(lens_k1=-0.1))
    assert cfg.meta()["camera"]["k1"] == -0.1
    assert cfg.effective_camera().k1 == -0.1


def test_ray_directions_invert_projection_with_lens_distortion() -> None:
    cam = replace(CAM, k1=-0.2, k2=0.05)
    dirs = ray_directions(cam)
    for yx in [(0, 0), (239, 319), (120, 40), (7, 300)]:
        p = 2.0 * dirs[yx]  # the point at Z = 2 m on that pixel's ray
        left, _ = project_points(cam, p)
        np.testing.assert_allclose(left, [yx[1], yx[0]], atol=1e-6)


def _blob_volume(centre_xyz: np.ndarray, n: int = 40, h: float = 0.005,
                 sigma_m: float = 0.01) -> tuple[np.ndarray, Volume]:
    origin = centre_xyz - n * h / 2.0
    z, y, x = np.mgrid[:n, :n, :n]
    pts = np.stack(((x + 0.5) * h, (y + 0.5) * h, (z + 0.5) * h), -1) + origin
    c = np.exp(-np.sum((pts - centre_xyz) ** 2, -1) / (2 * sigma_m**2))
    return c, Volume(tuple(origin), h, (n, n, n))


def _centroid(img: np.ndarray) -> np.ndarray:
    ys, xs = np.mgrid[: img.shape[0], : img.shape[1]]
    return np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()


def test_blob_renders_where_the_point_projects_in_both_cameras() -> None:
    centre = np.array([0.05, -0.03, 2.0])
    c, vol = _blob_volume(centre)
    dirs = ray_directions(CAM)
    col_l, zsum, _ = column_integrals(c, vol, dirs, 0.0)
    col_r, _, _ = column_integrals(c, vol, dirs, CAM.b_m)
    left, right = project_points(CAM, centre)
    # a symmetric blob's image centroid is (to first order) the projection of its centre
    np.testing.assert_allclose(_centroid(col_l), left, atol=0.05)
    np.testing.assert_allclose(_centroid(col_r), right, atol=0.05)
    # the column through the centre is the Gaussian's line integral sqrt(2 pi) sigma, less the
    # ~6 % that trilinear interpolation (sigma = 2 voxels) shaves off a peak
    iy, ix = np.unravel_index(np.argmax(col_l), col_l.shape)
    assert col_l[iy, ix] == pytest.approx(np.sqrt(2 * np.pi) * 0.01, rel=0.08)
    # columns times pixel footprints (Z/s)^2 sum to the blob's integral (2 pi)^1.5 sigma^3
    total = col_l.sum() * (2.0 / 780.0) ** 2
    assert total == pytest.approx((2 * np.pi) ** 1.5 * 0.01**3, rel=0.02)
    # concentration-weighted mean depth on the centre's ray is the blob's depth
    gt = ground_truth(col_l, zsum, np.zeros((*col_l.shape, 3)), dirs, necl_ppm_m=1e-3)
    pos = gt.position[iy, ix]
    assert pos[2] == pytest.approx(2.0, abs=0.002)
    np.testing.assert_allclose(pos[:2], centre[:2], atol=0.003)
    assert np.isnan(gt.velocity[0, 0]).all() and not gt.mask[0, 0]


def test_eq1_radiometry_hand_computed() -> None:
    rad = Radiometry(t_bg_k=300.0, t_gas_k=285.0, alpha_per_ppm_m=1e-4)
    col = np.array([[0.0, 10000.0, 1e9]])
    bg = np.full(col.shape, band_radiance(300.0))
    img = radiance_image(col, bg, rad)
    tau = np.exp(-1.0)
    lbg, lg = band_radiance(300.0), band_radiance(285.0)
    np.testing.assert_allclose(img[0], [lbg, lbg * tau + lg * (1 - tau), lg], rtol=1e-12)
    counts = to_counts(img, CountsModel(gain=4e5, offset=2000.0))
    assert counts.dtype == np.uint16
    assert counts[0, 0] == round(2000 + 4e5 * lbg)
    # the gas is colder than the background, so it darkens the image
    assert counts[0, 0] > counts[0, 1] > counts[0, 2]
    # Planck band radiance over 3.2-3.4 um at 300 K (hand integration: ~0.030 W/(m^2 sr))
    assert lbg == pytest.approx(0.0300, rel=0.01)


def _translating_config(wind: tuple[float, float, float], **opts: object) -> SequenceConfig:
    # No buoyancy (gas as dense as air) and no source: the gas only drifts with the wind.
    fluid = FluidParams(shape=(32, 32, 32), voxel_m=0.005, dt_s=0.005, wind_m_s=wind,
                        gas_density_kg_m3=1.0, air_density_kg_m3=1.0,
                        viscosity_m2_s=0.0, diffusivity_m2_s=0.0)
    rad = Radiometry(gas_density_kg_m3=1.0)
    return SequenceConfig(name="translate", fluid=fluid, volume_origin_m=(0.02, -0.08, 1.92),
                          n_frames=3, substeps=2, spinup_steps=0, seed=4, radiometry=rad,
                          options=RenderOptions(**opts), necl_ppm_m=100.0)


def _scene_with_blob(cfg: SequenceConfig) -> SyntheticStereoScene:
    scene = SyntheticStereoScene(cfg)
    z, y, x = np.mgrid[:32, :32, :32]
    scene.sim.state.c = 0.02 * np.exp(-((x - 14) ** 2 + (y - 16) ** 2 + (z - 15) ** 2) / 18.0)
    return scene


def test_uniform_translating_blob_ground_truth_equals_imposed_velocity() -> None:
    wind = (1.0, -2.0, 0.5)
    cfg = _translating_config(wind)
    scene = _scene_with_blob(cfg)
    f0 = scene.next_frame()
    f1 = scene.next_frame()
    for f in (f0, f1):
        assert f.gt_mask.sum() > 100
        np.testing.assert_allclose(f.gt_velocity[f.gt_mask], np.broadcast_to(wind, (
            int(f.gt_mask.sum()), 3)), atol=1e-6)
    # The image motion between the frames is the one Eq. 4's geometry gives for that velocity:
    # the centroid of the column density moves like the projection of the blob's centre.
    dt = cfg.frame_interval_s
    assert dt == pytest.approx(0.01)
    p0 = np.nanmean(f0.gt_position[f0.gt_mask], axis=0)
    flow = _centroid(f1.column_density_ppm_m) - _centroid(f0.column_density_ppm_m)
    a, _ = project_points(CAM, p0)
    b, _ = project_points(CAM, p0 + np.array(wind) * dt)
    np.testing.assert_allclose(flow, b - a, atol=0.15)  # ~8 px of motion
    assert f1.t_s == pytest.approx(dt)


def test_ideal_conditions_by_default_and_options_change_images_not_truth() -> None:
    wind = (1.0, 0.0, 0.0)
    ideal = _scene_with_blob(_translating_config(wind)).next_frame()
    # no gas far from the blob: exact background counts, identical in both cameras
    assert ideal.left[0, 0] == ideal.right[0, 0] == round(2000 + 4e5 * band_radiance(300.0))
    np.testing.assert_array_equal(ideal.jitter_left_px, [0.0, 0.0])
    for opts in (
        {"noise_netd_k": 0.05},
        {"jitter_px": 0.5},
        {"radiometric_mismatch": True},
        {"moving_object": MovingObject(z_m=4.0, radius_m=0.3, center_m=(0.0, 0.0))},
    ):
        cfg = _translating_config(wind, **opts)
        f = _scene_with_blob(cfg).next_frame()
        if "radiometric_mismatch" in opts:  # meta.json reports the effective counts models
            assert cfg.meta()["counts_model"]["right"]["offset"] == 2150.0
        assert not np.array_equal(f.left, ideal.left) or not np.array_equal(f.right, ideal.right)
        np.testing.assert_array_equal(f.gt_mask, ideal.gt_mask)
        np.testing.assert_allclose(f.gt_velocity, ideal.gt_velocity, equal_nan=True)


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="Z > 0"):
        project_points(CAM, np.array([0.0, 0.0, -1.0]))
    with pytest.raises(ValueError, match="last axis"):
        project_points(CAM, np.zeros((4, 2)))
    vol = Volume((0.0, 0.0, 1.0), 0.01, (4, 4, 4))
    with pytest.raises(ValueError, match="does not match"):
        column_integrals(np.zeros((4, 4, 5)), vol, ray_directions(CAM))
    with pytest.raises(ValueError, match="velocity"):
        column_integrals(np.zeros((4, 4, 4)), vol, ray_directions(CAM),
                         velocity=np.zeros((3, 4, 4)))
    with pytest.raises(ValueError, match="s_px"):
        ray_directions(StereoCamera(s_px=0.0))


def _image_flow(frame: object, s_px: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Left-image displacement (px per frame) of each pixel's P* moved by V* dt (Eq. 4 read
    backwards); 0 where the ray meets no gas."""
    p = frame.gt_position.astype(float)
    p1 = p + frame.gt_velocity.astype(float) * dt
    u = s_px * (p1[..., 0] / p1[..., 2] - p[..., 0] / p[..., 2])
    v = s_px * (p1[..., 1] / p1[..., 2] - p[..., 1] / p[..., 2])
    return np.nan_to_num(u), np.nan_to_num(v)


def test_ground_truth_velocity_explains_the_rendered_gas_motion() -> None:
    """Integrating the continuity equation along the rays gives dC/dt + div(C w) = 0 for the
    column density C with w the concentration-weighted velocity V* (projected). So the GT of a
    simulated plume must explain how its column density changes between frames: the best
    scale k of the GT flow is 1 and the residual is small (away from the source, where gas
    appears). Measured: this 40^3 grid k = 0.90 (0.98 while the release was re-drawn every
    step; the time-correlated release leaves less concentration texture, so the numerical
    diffusion of the coarse grid weighs more), residual 0.20 (a GT scaled by 0.8 gives
    k = 1.23 and fails); the full-size Table-2 sequences k = 0.99-1.00, residual 0.11-0.14."""
    from processing.synthetic.sequences import generate_sequence, preset

    cfg = preset("table2_1", n_frames=4)
    cfg = replace(cfg, fluid=replace(cfg.fluid, shape=(40, 40, 40), voxel_m=0.01))
    frames = list(generate_sequence(cfg))
    src = np.asarray(cfg.fluid.sources[0].position_m) + np.asarray(cfg.volume_origin_m)
    src_px, _ = project_points(cfg.camera, src)
    ys, xs = np.mgrid[:240, :320]
    far_from_source = np.hypot(xs - src_px[0], ys - src_px[1]) > 40
    s, dt = cfg.camera.s_px, cfg.frame_interval_s
    ks, residuals = [], []
    for a, b in itertools.pairwise(frames):
        c0 = a.column_density_ppm_m.astype(float)
        c1 = b.column_density_ppm_m.astype(float)
        ua, va = _image_flow(a, s, dt)
        ub, vb = _image_flow(b, s, dt)
        cm = 0.5 * (c0 + c1)
        div = np.gradient(cm * 0.5 * (ua + ub), axis=1) + np.gradient(cm * 0.5 * (va + vb), axis=0)
        keep = (a.gt_mask | b.gt_mask) & far_from_source
        assert keep.sum() > 300
        dc = (c1 - c0)[keep]
        ks.append(-(dc * div[keep]).sum() / (div[keep] ** 2).sum())
        residuals.append(np.linalg.norm(dc + div[keep]) / np.linalg.norm(dc))
    assert 0.85 < np.mean(ks) < 1.1, ks
    assert np.mean(residuals) < 0.35, residuals


def test_field_preset_gas_drifts_with_the_anemometer_wind() -> None:
    """The appliance's simulated cameras: 30 Hz frames, gas ~5.5 m away moving with the wind
    (coarse 12 cm voxels to stay fast)."""
    from processing.synthetic.sequences import generate_sequence, preset

    wind = np.array([2.0, 0.0, 0.5])
    cfg = preset("field", n_frames=2, wind_m_s=tuple(wind), b_m=0.25, voxel_m=0.12)
    assert cfg.frame_interval_s == pytest.approx(1.0 / 30.0)
    assert cfg.camera.b_m == 0.25
    frames = list(generate_sequence(cfg))
    f = frames[-1]
    assert f.gt_mask.sum() > 500
    v = f.gt_velocity[f.gt_mask].mean(axis=0)
    # horizontal drift follows the wind; buoyancy adds a rise (negative Y), not a fall
    np.testing.assert_allclose(v[[0, 2]], wind[[0, 2]], rtol=0.25, atol=0.15)
    assert v[1] < 0.1
    assert np.nanmean(f.gt_position[f.gt_mask][:, 2]) == pytest.approx(5.5, abs=0.5)


def test_eq4_reference_inverts_eq4_on_a_rendered_frame() -> None:
    """(u, v, d, d') from the ground truth, put through Eq. 4, give back V* (paper Eq. 4 written
    out here independently of the scene-flow chain)."""
    from processing.synthetic.reference import eq4_reference, triplet_reference

    cfg = _translating_config((1.0, -2.0, 0.5))
    scene = _scene_with_blob(cfg)
    f0, f1 = scene.next_frame(), scene.next_frame()
    ref = eq4_reference(f0.gt_position, f0.gt_velocity, CAM.s_px, CAM.b_m, cfg.frame_interval_s)
    m = f0.gt_mask
    fr = 1.0 / cfg.frame_interval_s
    ys, xs = np.mgrid[:240, :320].astype(float)
    u, v, d, dp = (a.astype(float) for a in (ref.u, ref.v, ref.d, ref.d_prime))
    vx = fr * CAM.b_m * ((xs - CAM.cx + u) / (d + dp) - (xs - CAM.cx) / d)
    vy = fr * CAM.b_m * ((ys - CAM.cy + v) / (d + dp) - (ys - CAM.cy) / d)
    vz = fr * CAM.b_m * (CAM.s_px / (d + dp) - CAM.s_px / d)
    np.testing.assert_allclose(np.stack((vx, vy, vz), -1)[m], f0.gt_velocity[m], atol=2e-3)
    assert np.all(ref.d[m] > 0)  # d = x_L - x_R > 0
    np.testing.assert_allclose(ref.d[m], 780 * 0.2 / f0.gt_position[m][:, 2], rtol=1e-5)
    assert np.isnan(ref.u[~np.isfinite(f0.gt_velocity[..., 0])]).all()
    vel, mask = triplet_reference(f0, f1)
    np.testing.assert_allclose(vel[mask], np.broadcast_to([1.0, -2.0, 0.5], (mask.sum(), 3)),
                               atol=1e-5)
    with pytest.raises(ValueError, match="consecutive"):
        triplet_reference(f1, f0)


def test_jitter_moves_the_gas_without_blurring_it() -> None:
    from processing.synthetic.imaging import shift_image

    yy, xx = np.mgrid[0:40, 0:50].astype(float)

    def blob(cx: float, cy: float) -> np.ndarray:
        return np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 3.0**2))

    out = shift_image(blob(20.0, 18.0), (0.5, -0.37))
    # content moves by +shift, as the background's shifted rays move it
    np.testing.assert_allclose(out, blob(20.5, 17.63), atol=1e-4)
    # the bilinear warp used before lost 2.6 % of the peak here (error 0.025)
    assert out.max() > 0.999 * blob(20.5, 17.63).max()


def test_a_textured_background_is_integrated_over_the_pixel_so_jitter_does_not_alias_it(
) -> None:
    # A jittered frame of the plant wall, moved back by its jitter, must match the still
    # frame as a real detector's would; with one ray per pixel the wall's sharp edges alias
    # differently at every sub-pixel shift (measured: 6.6e-6 -> 3.2e-6 W m^-2 sr^-1 of
    # low-frequency residual with 2 x 2 rays, 1.5e-6 with 3 x 3).
    import cv2

    from processing.preprocess.translation import warp_translation
    from processing.synthetic.cameras import PIXEL_SAMPLES, StereoRenderer, pixel_mean_background
    from processing.synthetic.imaging import background_radiance
    from processing.synthetic.presets import preset_no_release

    cfg = preset_no_release()
    ren = StereoRenderer(cfg)
    cam, rad = ren.camera, cfg.radiometry
    shift = (0.5, 0.3)

    def point(s: tuple[float, float]) -> np.ndarray:
        return background_radiance(cam, rad, ray_directions(cam, s), 0.0, 0.0, None,
                                   cfg.background)

    def residual(still: np.ndarray, moved: np.ndarray) -> float:
        # what survives the chain's smoothing: aliasing folds the edges' detail into low
        # frequencies, the warp's own error stays at the highest ones
        back = warp_translation(moved.astype(np.float32), shift)
        low = cv2.GaussianBlur((back - still).astype(np.float32), (0, 0), 2.0)
        return float(np.sqrt(np.mean(low[12:-12, 12:-12] ** 2)))

    def area_mean(s: tuple[float, float]) -> np.ndarray:
        return pixel_mean_background(cam, rad, s, 0.0, 0.0, None, cfg.background,
                                     PIXEL_SAMPLES)

    area = residual(area_mean((0.0, 0.0)), area_mean(shift))
    single = residual(point((0.0, 0.0)), point(shift))
    assert area < 0.6 * single, (area, single)


@pytest.mark.parametrize("kind", ["plant", "sky"])
@pytest.mark.parametrize("k1", [0.0, -0.2])
def test_a_background_evaluated_on_a_row_and_a_column_is_the_full_grids_to_the_bit(
        kind: str, k1: float) -> None:
    # Undistorted rays (k1 = 0) take the row-and-column shortcut, distorted ones the full
    # grid; laid out as one long row the same rays never take it: the references.
    from processing.synthetic.imaging import Background, background_radiance

    cam = replace(CAM, k1=k1)
    rad, background = Radiometry(), Background(kind=kind, seed=5)
    dirs = ray_directions(cam, (0.37, -0.21))
    shortcut = background_radiance(cam, rad, dirs, 0.2, 0.0, None, background)
    flat = background_radiance(cam, rad, dirs.reshape(1, -1, 3), 0.2, 0.0, None, background)
    assert shortcut.shape == (cam.height, cam.width)
    assert np.array_equal(shortcut, flat.reshape(shortcut.shape))
    assert float(shortcut.std()) > 0.0
