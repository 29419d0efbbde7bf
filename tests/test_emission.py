"""Emission rate: column density (Eq. 1 inverted), curtain flux, placement, window, gas cell."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from processing.calibration.radiometric import band_radiance
from processing.emission import (
    METHANE,
    Curtain,
    FrameRate,
    RateWindow,
    column_density,
    curtain_flux,
    fit_alpha,
    g_s_to_kg_h,
    out_of_plane_deg,
    place_curtains,
    ppm_m_to_kg_m2,
)
from processing.emission.column import BackgroundModel, nanmedian_first_axis
from processing.emission.estimator import (
    CurtainRates,
    EmissionEstimator,
    EmissionSettings,
    grow_mask,
)

S_PX, CX, CY = 780.0, 159.5, 119.5
H, W = 240, 320


def _eq1(cl_ppm_m: np.ndarray, l_bg: float, l_gas: float, alpha: float) -> np.ndarray:
    tau = np.exp(-alpha * cl_ppm_m)
    return l_bg * tau + l_gas * (1 - tau)


def test_column_density_inverts_eq1_exactly() -> None:
    rng = np.random.default_rng(0)
    cl = rng.uniform(0, 5000, (H, W))
    l_bg, l_gas = float(band_radiance(300.0)), float(band_radiance(285.0))
    L = _eq1(cl, l_bg, l_gas, METHANE.alpha_per_ppm_m)
    res = column_density(L, np.full((H, W), l_bg), l_gas, METHANE.alpha_per_ppm_m)
    assert res.defined.all()
    np.testing.assert_allclose(res.ppm_m, cl, rtol=1e-4, atol=0.05)


def test_column_density_undefined_without_thermal_contrast() -> None:
    l_gas = float(band_radiance(290.0))
    L = np.full((4, 4), l_gas)
    res = column_density(L, np.full((4, 4), l_gas), l_gas, 5e-5)
    assert not res.defined.any()
    assert np.all(res.ppm_m == 0) and res.low_contrast_fraction == 1.0


def test_unit_conversions() -> None:
    # 1 ppm*m of methane at 15 degC, 1 atm: 1e-6 m of pure gas at 0.67836 kg/m^3.
    sigma = ppm_m_to_kg_m2(1.0, molar_mass_kg_mol=0.01604, temperature_k=288.15)
    assert sigma == pytest.approx(6.7836e-7, rel=1e-4)
    assert g_s_to_kg_h(1.0) == pytest.approx(3.6)
    with pytest.raises(ValueError):
        ppm_m_to_kg_m2(1.0, molar_mass_kg_mol=0.016, temperature_k=0.0)


def _slab_scene(v: tuple[float, float, float], z0: float = 5.0, thickness: float = 0.2,
                rows: tuple[int, int] = (100, 140), rho: float = 2e-3):
    """A gas slab of density rho (kg/m^3), thickness t at depth z0, rows y in [r0, r1)."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r_norm = np.sqrt((x - CX) ** 2 + (y - CY) ** 2 + S_PX**2)
    gas = (y >= rows[0]) & (y < rows[1])
    sigma = np.where(gas, rho * thickness * r_norm / S_PX, 0.0)  # path t |r| / s through it
    vel = np.broadcast_to(np.asarray(v, np.float64), (H, W, 3)).copy()
    depth = np.full((H, W), z0)
    return sigma, vel, depth, np.ones((H, W), bool), gas


@pytest.mark.parametrize("x_c", [60.0, 159.5, 290.0])
def test_flux_of_an_analytic_slab_is_exact(x_c: float) -> None:
    v = (1.5, -0.2, 0.4)
    rho, t, z0, rows = 2e-3, 0.2, 5.0, (100, 140)
    sigma, vel, depth, valid, gas = _slab_scene(v, z0, t, rows, rho)
    curtain = Curtain((x_c, 80.0), (x_c, 170.0), normal_sign=-1.0)  # n toward +X
    res = curtain_flux(curtain, sigma, vel, depth, valid, gas,
                       principal_point=(CX, CY), camera_constant=S_PX)
    k = (x_c - CX) / S_PX
    height_m = (rows[1] - rows[0]) * z0 / S_PX
    expected = rho * t * height_m * (v[0] - k * v[2])  # rho V.n over the plane X = k Z
    assert res.defined and res.gas_samples == rows[1] - rows[0]
    assert res.rate_kg_s == pytest.approx(expected, rel=0.01)


def test_static_gas_has_zero_flux_and_empty_curtain_is_a_defined_zero() -> None:
    sigma, vel, depth, valid, gas = _slab_scene((0.0, 0.0, 0.0))
    res = curtain_flux(Curtain((100, 80), (100, 170)), sigma, vel, depth, valid, gas,
                       principal_point=(CX, CY), camera_constant=S_PX)
    assert res.defined and res.rate_kg_s == 0.0
    empty = curtain_flux(Curtain((100, 0), (100, 50)), sigma, vel, depth, valid, gas,
                         principal_point=(CX, CY), camera_constant=S_PX)
    assert empty.defined and empty.gas_samples == 0 and empty.rate_kg_s == 0.0


def test_curtain_without_valid_velocity_is_undefined_not_nan() -> None:
    sigma, vel, depth, valid, gas = _slab_scene((1.0, 0.0, 0.0))
    valid[:] = False
    res = curtain_flux(Curtain((100, 80), (100, 170)), sigma, vel, depth, valid, gas,
                       principal_point=(CX, CY), camera_constant=S_PX)
    assert not res.defined and res.rate_kg_s == 0.0


def _plume_mask() -> tuple[np.ndarray, np.ndarray]:
    """A wedge-shaped plume from a source at (40, 120) drifting right, with its flow."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    gas = (x >= 40) & (x <= 280) & (np.abs(y - 120) <= 5 + 0.15 * (x - 40))
    flow = np.zeros((H, W, 2))
    flow[..., 0] = 2.0
    return gas, flow


def test_placement_finds_the_source_and_orients_curtains_downstream() -> None:
    gas, flow = _plume_mask()
    p = place_curtains(gas, flow, n_curtains=4, exclusion_px=15)
    assert p.reason == "" and len(p.curtains) == 4
    assert p.source_xy is not None and p.source_xy[0] < 50
    assert p.direction_xy == pytest.approx((1.0, 0.0))
    for c in p.curtains:  # perpendicular to the motion, past the exclusion zone
        assert c.start[0] == pytest.approx(c.end[0]) and c.start[0] >= 40 + 15
    # A uniform slab moving right gives a positive flux through every curtain.
    sigma = np.where(gas, 1e-4, 0.0)
    vel = np.zeros((H, W, 3))
    vel[..., 0] = 1.0
    for c in p.curtains:
        f = curtain_flux(c, sigma, vel, np.full((H, W), 5.0), np.ones((H, W), bool), gas,
                         principal_point=(CX, CY), camera_constant=S_PX)
        assert f.defined and f.rate_kg_s > 0


def test_placement_leaves_out_the_first_fifth_of_the_plume() -> None:
    """The flow reads the young plume near its source too fast (docs/accuracy.md, emission rate):
    by default no curtain lies in the first 20 % of the plume's length."""
    gas, flow = _plume_mask()  # x = 40 .. 280
    xs = np.nonzero(gas)[1]
    lo, hi = np.percentile(xs, [2.0, 98.0])
    p = place_curtains(gas, flow)
    assert p.reason == "" and len(p.curtains) == 5
    assert min(c.start[0] for c in p.curtains) == pytest.approx(lo + 0.2 * (hi - lo))
    short = place_curtains(gas, flow, exclusion_fraction=0.0)  # then exclusion_px rules
    assert min(c.start[0] for c in short.curtains) == pytest.approx(lo + 12.0)
    with pytest.raises(ValueError, match="exclusion_fraction"):
        place_curtains(gas, flow, exclusion_fraction=1.0)


def test_placement_reports_why_there_are_no_curtains() -> None:
    gas, flow = _plume_mask()
    assert place_curtains(np.zeros_like(gas), flow).reason == "no gas"
    assert place_curtains(gas, np.zeros_like(flow)).reason == "no motion"


def test_single_camera_equals_stereo_for_in_plane_motion_at_the_right_distance() -> None:
    """The estimator's two rates through the same curtains: equal for in-plane motion at the
    typed-in distance; a typed-in distance twice the true one reads four times the rate."""
    gas, flow = _plume_mask()
    z, dt = 5.0, 1 / 30
    sigma = np.where(gas, 1e-4, 0.0)
    vel = np.zeros((H, W, 3))
    vel[..., 0] = flow[..., 0] * z / (S_PX * dt)  # the flow of an in-plane motion at Z

    def rates(z_typed: float) -> CurtainRates:
        est = EmissionEstimator(EmissionSettings(typed_distance_m=z_typed), (CX, CY), S_PX,
                                None)
        return est.rates(sigma, flow=flow, velocity=vel, depth=np.full((H, W), z),
                         valid=np.ones((H, W), bool), gas_mask=gas, dt_s=dt)

    right = rates(z)
    stereo, single = right.stereo().rate_g_s, right.single().rate_g_s
    assert len(right.curtains) == 5 and stereo is not None and single is not None
    assert single == pytest.approx(stereo, rel=0.01)
    assert rates(2 * z).single().rate_g_s == pytest.approx(4 * stereo, rel=0.01)  # Z twice
    assert rates(2 * z).stereo().rate_g_s == pytest.approx(stereo, rel=1e-12)


def test_rate_window_mean_uncertainty_and_eviction() -> None:
    win = RateWindow(window_s=1.0)
    for k in range(10):
        est = win.push(k * 0.1, FrameRate(2.0, (2.0, 2.0)))
    assert est.rate_g_s == pytest.approx(2.0) and est.uncertainty_g_s == pytest.approx(0.0)
    assert est.rate_kg_h == pytest.approx(7.2) and est.frames == 10
    est = win.push(1.05, FrameRate(None, (), "no gas"))
    assert est.frames_total == 10 and est.frames == 9  # t=0 left the window
    rng = np.random.default_rng(1)
    noisy = RateWindow(window_s=100.0)
    for k in range(200):
        q = float(rng.normal(3.0, 0.5))
        est = noisy.push(k * 0.1, FrameRate(q, (q - 0.1, q + 0.1)))
    assert est.rate_g_s == pytest.approx(3.0, abs=0.15)
    assert 0.02 < est.uncertainty_g_s < 0.1  # ~ 0.5 / sqrt(200) for white noise


def test_rate_window_curtain_spread_is_the_frames_standard_errors_in_quadrature() -> None:
    # Four frames at 2 g/s from curtains (1, 3): each frame's standard error of its curtain
    # mean is std(1, 3) / sqrt(2) = 1. A one-curtain frame at 2 g/s counts as a frame but has
    # no curtain spread, a frame without a rate counts for neither: sqrt(mean(1^2) / 5); the
    # rates do not vary over time, so that is all.
    win = RateWindow(window_s=10.0)
    for k in range(4):
        win.push(k * 0.1, FrameRate(2.0, (1.0, 3.0)))
    win.push(0.45, FrameRate(None, (), "no gas"))
    est = win.push(0.5, FrameRate(2.0, (2.0,)))
    assert est.frames == 5 and est.frames_total == 6
    assert est.uncertainty_g_s == pytest.approx(np.sqrt(4 * 1.0 / 4 / 5))


@pytest.mark.parametrize(("vel", "expected"), [((1.0, 0.0, 0.0), 0.0), ((0.0, 0.0, 2.0), 90.0),
                                               ((1.0, 0.0, 1.0), 45.0),
                                               ((-0.6, 0.0, -1.8), 71.57)])
def test_out_of_plane_angle_of_a_plume_on_the_optical_axis(
        vel: tuple[float, float, float], expected: float) -> None:
    # A plume centred on the principal point: its mean ray is the optical axis, so the
    # angle is that of V against the X-Y plane. Pixels without gas or velocity, and their
    # nonsense velocity, do not count; the column density weights.
    gas = np.zeros((H, W), bool)
    gas[100:140, 140:180] = True
    valid = gas.copy()
    valid[100:103] = False  # symmetric about the principal point: the mean ray stays on axis
    valid[137:140] = False
    velocity = np.zeros((H, W, 3))
    velocity[gas] = vel
    velocity[~valid] = (0.0, 0.0, 50.0)
    sigma = np.where(gas, 1e-4, 0.0)
    ang = out_of_plane_deg(sigma, velocity, valid, gas, principal_point=(159.5, 119.5),
                           camera_constant=S_PX)
    assert ang == pytest.approx(expected, abs=0.05)
    assert out_of_plane_deg(sigma, velocity, np.zeros((H, W), bool), gas,
                            principal_point=(CX, CY), camera_constant=S_PX) is None


def test_out_of_plane_angle_is_measured_against_the_plumes_viewing_ray() -> None:
    # Off axis, motion along the plume's own viewing ray is 90 deg out of the image plane
    # (the camera sees none of it), though it has X and Z parts.
    gas = np.zeros((H, W), bool)
    gas[110:130, 290:310] = True
    ray = np.array([300.0 - CX, 120.0 - CY, S_PX])
    velocity = np.zeros((H, W, 3))
    velocity[gas] = ray / np.linalg.norm(ray)
    ang = out_of_plane_deg(np.where(gas, 1.0, 0.0), velocity, gas, gas, principal_point=(CX, CY),
                           camera_constant=S_PX)
    assert ang > 89.0


def test_rate_window_flags_a_rate_whose_gas_moves_along_the_line_of_sight() -> None:
    win = RateWindow(window_s=10.0)
    for k in range(5):
        est = win.push(k * 0.1, FrameRate(2.0, (2.0,), out_of_plane_deg=30.0))
    assert est.out_of_plane_deg == pytest.approx(30.0) and est.flags == ()
    for k in range(5, 20):
        est = win.push(k * 0.1, FrameRate(2.0, (2.0,), out_of_plane_deg=75.0))
    assert est.out_of_plane_deg == pytest.approx((5 * 30 + 15 * 75) / 20)
    assert est.flags == ("line_of_sight",)
    # A frame without a rate carries no angle; the single-camera rate has none at all.
    est = win.push(2.1, FrameRate(None, (), "no gas"))
    assert est.flags == ("line_of_sight",)
    assert RateWindow().push(0.0, FrameRate(2.0, (2.0,))).out_of_plane_deg is None


def test_background_model_ignores_gas_samples() -> None:
    bg = BackgroundModel(capacity=20, min_samples=5, refresh=1)
    rng = np.random.default_rng(2)
    for k in range(20):
        frame = 10.0 + rng.normal(0, 0.01, (8, 8))
        gas = np.zeros((8, 8), bool)
        if k % 2:
            frame[:4] -= 1.0  # gas darkens the top half in every other frame
            gas[:4] = True
        bg.update(frame, gas)
    est = bg.estimate()
    assert est is not None and np.allclose(est, 10.0, atol=0.02)
    assert bg.fallback_fraction == 0.0


@pytest.mark.parametrize("n", [1, 2, 7, 60])
def test_nanmedian_first_axis_is_numpys_nanmedian(n: int) -> None:
    rng = np.random.default_rng(n)
    stack = rng.normal(0.0, 1.0, (n, 9, 11)).astype(np.float32)
    stack[rng.random(stack.shape) < 0.4] = np.nan  # odd and even counts per pixel
    stack[:, 0, 0] = np.nan  # a pixel without any sample
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want = np.nanmedian(stack.astype(np.float64), axis=0)
    got = nanmedian_first_axis(stack)
    assert got.shape == (9, 11) and np.isnan(got[0, 0])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6, equal_nan=True)


@pytest.mark.parametrize("block", [7, 99, 4096])
def test_nanmedian_first_axis_drops_samples_as_if_they_were_nan(block: int) -> None:
    """``drop`` leaves samples out exactly as NaN would, whatever the block size (blocks
    that split the pixels unevenly included)."""
    rng = np.random.default_rng(block)
    stack = rng.normal(0.0, 1.0, (12, 9, 11)).astype(np.float32)
    drop = rng.random(stack.shape) < 0.5
    drop[:, 2, 3] = True  # a pixel with every sample dropped
    want = nanmedian_first_axis(np.where(drop, np.nan, stack), block=block)
    got = nanmedian_first_axis(stack, drop=drop, block=block)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[2, 3])
    np.testing.assert_array_equal(nanmedian_first_axis(stack, block=block),
                                  nanmedian_first_axis(stack, block=10 ** 6))


def test_gas_cell_fit_recovers_a_known_coefficient() -> None:
    alpha = 4.2e-5
    l_bb, l_gas = float(band_radiance(323.15)), float(band_radiance(293.15))
    cls = [500.0, 2000.0, 8000.0]
    filled = _eq1(np.asarray(cls), l_bb, l_gas, alpha)
    fit = fit_alpha(cls, filled.tolist(), l_bb, l_gas)
    assert fit.alpha_per_ppm_m == pytest.approx(alpha, rel=1e-9)
    assert fit.residual_rms < 1e-12
    with pytest.raises(ValueError, match="transmittance"):
        fit_alpha([500.0], [l_bb * 1.01], l_bb, l_gas)
    with pytest.raises(ValueError, match="contrast"):
        fit_alpha([500.0], [l_gas], l_gas, l_gas)


def test_curtain_samples_every_pixel_once() -> None:
    # Gas on odd rows only: a sampler that skipped or doubled rows would get it wrong.
    sigma, vel, depth, valid, gas = _slab_scene((1.0, 0.0, 0.0))
    odd = np.zeros((H, W), bool)
    odd[1::2] = True
    c = Curtain((CX, 100.0), (CX, 140.0), normal_sign=-1.0)
    assert len(c.samples()) == 40 and c.spacing_px == 1.0
    full = curtain_flux(c, sigma, vel, depth, valid, gas, principal_point=(CX, CY),
                        camera_constant=S_PX)
    half = curtain_flux(c, sigma, vel, depth, valid, gas & odd, principal_point=(CX, CY),
                        camera_constant=S_PX)
    assert half.gas_samples == 20
    assert half.rate_kg_s == pytest.approx(full.rate_kg_s / 2, rel=1e-3)


def test_estimator_background_is_not_learnt_from_a_plumes_faint_edge() -> None:
    """A pixel under a steady plume's faint edge, which the segmentation marks as gas in
    only 60 % of the frames, is never free of gas: its 40 % "free" samples must not make
    its background (the former 8-of-60 rule took them and read CL = 0 there)."""
    from processing.emission.estimator import EmissionEstimator, EmissionSettings

    t_gas = 285.0
    l_bg, l_gas = float(band_radiance(300.0)), float(band_radiance(t_gas))
    cl = np.zeros((60, 80))
    cl[20:40, 30:50] = 200.0  # the faint edge, there in every frame
    frame = _eq1(cl, l_bg, l_gas, METHANE.alpha_per_ppm_m)
    est = EmissionEstimator(EmissionSettings(faint_gas_px=0, background_margin_px=0),
                            (40.0, 30.0), S_PX, None)
    for k in range(60):
        mask = np.zeros(cl.shape, bool)
        mask[20:40, 30:50] = k % 5 < 3  # segmented in 3 of every 5 frames
        sigma = est.column_kg_m2(frame, mask, t_gas)
    expected = ppm_m_to_kg_m2(200.0, molar_mass_kg_mol=METHANE.molar_mass_kg_mol,
                              temperature_k=t_gas)
    assert sigma[20:40, 30:50] == pytest.approx(np.full((20, 20), expected), rel=0.01)
    assert np.abs(sigma[cl == 0]).max() < 1e-3 * expected


def test_v_z_enters_a_curtain_flux_only_through_the_depth_at_t1() -> None:
    """On a curtain of viewing rays V . n = Z1 f (w . n) / s with Z1 = s b / (d + d'):
    a d' that changes V_Z by metres per second changes the rate by d / (d + d') only
    (docs/method.md, "What the rate takes from the scene flow"), even far off the optical axis."""
    from processing.velocity.triangulate import scene_flow_velocity

    b, dt, d = 0.3, 1 / 30, 40.0
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0], flow[..., 1] = 2.0, 0.5
    disp = np.full((H, W), d, np.float32)
    sigma = np.full((H, W), 1e-4)
    gas = np.ones((H, W), bool)
    curtain = Curtain((280, 20), (290, 220))  # off-axis: n has a Z component
    rates, vz = [], []
    for dd in (0.0, 0.4):
        vel, ok = scene_flow_velocity(flow, disp, np.full((H, W), dd, np.float32),
                                      principal_point=(CX, CY), camera_constant=S_PX,
                                      baseline=b, dt=dt)
        f = curtain_flux(curtain, sigma, vel, np.full((H, W), S_PX * b / d), ok, gas,
                         principal_point=(CX, CY), camera_constant=S_PX)
        rates.append(f.rate_kg_s)
        vz.append(float(vel[120, 285, 2]))
    assert abs(vz[1] - vz[0]) > 1.0  # m/s
    assert rates[1] / rates[0] == pytest.approx(d / (d + 0.4), rel=2e-3)


def test_estimator_keeps_a_wide_margin_around_the_gas_out_of_the_background() -> None:
    """Gas 20 px beyond the segmentation (outside the 15 px faint edge that is counted, as
    downstream of a widening plume) must not become background: its CL is measured."""
    from processing.emission.estimator import EmissionEstimator, EmissionSettings

    t_gas = 285.0
    l_bg, l_gas = float(band_radiance(300.0)), float(band_radiance(t_gas))
    cl = np.zeros((100, 120))
    cl[45:55, 75:85] = 200.0  # 20-30 px right of the segmented gas
    frame = _eq1(cl, l_bg, l_gas, METHANE.alpha_per_ppm_m)
    mask = np.zeros(cl.shape, bool)
    mask[40:60, 35:55] = True
    est = EmissionEstimator(EmissionSettings(), (60.0, 50.0), S_PX, None)
    for _ in range(20):
        sigma = est.column_kg_m2(frame, mask, t_gas)
    expected = ppm_m_to_kg_m2(200.0, molar_mass_kg_mol=METHANE.molar_mass_kg_mol,
                              temperature_k=t_gas)
    assert sigma[45:55, 75:85] == pytest.approx(np.full((10, 10), expected), rel=0.01)


@pytest.mark.parametrize("kelvin", [0.2, -0.2])
def test_a_shutter_step_does_not_read_as_gas_or_hide_it(kelvin: float) -> None:
    """After 30 frames the camera's offset steps by 0.2 K either way (a flat-field shutter):
    the next frames are levelled onto the background, so the plume's column density reads
    as before and the background none, although the background model has not followed yet
    (unlevelled, the plume reads 0 after a step up, the background as gas after one down)."""
    from processing.emission.estimator import EmissionEstimator, EmissionSettings

    t_gas = 285.0
    l_bg, l_gas = float(band_radiance(300.0)), float(band_radiance(t_gas))
    step = float(band_radiance(300.0 + kelvin)) - l_bg
    rng = np.random.default_rng(4)
    cl = np.zeros((100, 120))
    cl[40:60, 35:55] = 200.0
    mask = cl > 0
    est = EmissionEstimator(EmissionSettings(), (60.0, 50.0), S_PX, None)
    noise = 2e-3 * abs(step)
    for k in range(40):
        frame = _eq1(cl, l_bg, l_gas, METHANE.alpha_per_ppm_m) + rng.normal(0, noise, cl.shape)
        sigma = est.column_kg_m2(frame + (step if k >= 30 else 0.0), mask, t_gas)
        if k == 29:
            before = sigma.copy()
    assert est.background.frames == 40
    assert sigma[mask].mean() == pytest.approx(before[mask].mean(), rel=0.005)
    expected = ppm_m_to_kg_m2(200.0, molar_mass_kg_mol=METHANE.molar_mass_kg_mol,
                              temperature_k=t_gas)
    assert abs(sigma[~mask].mean()) < 0.01 * expected


@pytest.mark.parametrize("steps", [0, 1, 4, 30])
def test_grow_mask_is_scipys_iterated_binary_dilation(steps: int) -> None:
    """The estimator's mask growth equals ``scipy.ndimage.binary_dilation(mask,
    iterations=steps)`` to the bit, also where the mask touches the image's edge."""
    from scipy import ndimage

    rng = np.random.default_rng(steps)
    mask = rng.random((48, 64)) > 0.97
    mask[0, 10] = mask[47, 63] = mask[20, 0] = True  # on the edges
    grown = grow_mask(mask, steps)
    assert grown.dtype == bool and grown.shape == mask.shape
    expected = ndimage.binary_dilation(mask, iterations=steps) if steps else mask
    np.testing.assert_array_equal(grown, expected)


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_the_estimators_margins_grow_with_the_cameras_pixels(scale: float) -> None:
    """The scene of the test above on a camera with twice the pixels (same field of view):
    with ``pixel_scale`` 2 the faint gas 40-60 px beyond the segmentation is measured; with
    the 320x240 settings unscaled the background takes it."""
    from processing.emission.estimator import EmissionEstimator, EmissionSettings

    t_gas = 285.0
    l_bg, l_gas = float(band_radiance(300.0)), float(band_radiance(t_gas))
    cl = np.zeros((200, 240))
    cl[90:110, 150:170] = 200.0
    frame = _eq1(cl, l_bg, l_gas, METHANE.alpha_per_ppm_m)
    mask = np.zeros(cl.shape, bool)
    mask[80:120, 70:110] = True
    est = EmissionEstimator(EmissionSettings(pixel_scale=scale), (120.0, 100.0), 2 * S_PX,
                            None)
    assert est.background.fill_sigma_px == 8.0 * scale
    for _ in range(20):
        sigma = est.column_kg_m2(frame, mask, t_gas)
    expected = ppm_m_to_kg_m2(200.0, molar_mass_kg_mol=METHANE.molar_mass_kg_mol,
                              temperature_k=t_gas)
    measured = float(np.median(sigma[90:110, 150:170]))
    if scale == 2.0:
        assert measured == pytest.approx(expected, rel=0.01)
    else:
        assert measured < 0.1 * expected


def test_the_appliance_scales_the_estimator_to_the_cameras_width() -> None:
    from appliance.runtime.emission_setup import EmissionSetup
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.chain import StereoGeometry
    from processing.emission.estimator import EmissionSettings

    setup = EmissionSetup(EmissionSettings(), curve_left=CharacteristicCurve(1000.0, 1e5))
    for width, scale in ((320, 1.0), (640, 2.0)):
        geo = StereoGeometry(camera_constant=780.0 * width / 320, principal_point=(0.0, 0.0),
                             baseline=0.3, image_size=(width, width * 3 // 4))
        est = setup.estimator(geo)
        assert est is not None and est.settings.pixel_scale == scale


def test_the_recorded_emission_setup_keeps_its_curve_whole() -> None:
    """A recording's emission metadata holds the curve as a calibration file does (a
    quadratic model and its band survive a replay); the two-key record of older recordings
    still reads; a wrong one is a ValueError naming the metadata."""
    import json

    from appliance.runtime.emission_setup import EmissionSetup
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.emission.estimator import EmissionSettings

    curve = CharacteristicCurve(1000.0, 1e5, curvature=2e3, band_m=(3.25e-6, 3.45e-6))
    setup = EmissionSetup(EmissionSettings(background_frames=7), 290.0, curve)
    back = EmissionSetup.from_json(setup.to_json())
    assert back.curve_left == curve and back.gas_temperature_k == 290.0
    assert back.settings.background_frames == 7
    old = json.loads(setup.to_json())
    old["curve_left"] = {"offset": 1000.0, "gain": 1e5}
    assert EmissionSetup.from_json(json.dumps(old)).curve_left == CharacteristicCurve(1000.0,
                                                                                      1e5)
    old["curve_left"] = {"offset": 1000.0}
    with pytest.raises(ValueError, match="emission metadata"):
        EmissionSetup.from_json(json.dumps(old))
