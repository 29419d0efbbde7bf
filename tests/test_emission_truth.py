"""Emission ground truth of the simulator: the time-correlated release, the true
release rate and the exact curtain flux from the flux moment, and the background fill."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from processing.emission import Curtain, curtain_flux
from processing.emission.column import BackgroundModel, spatial_fill
from processing.emission.truth import true_curtain_flux
from processing.synthetic.fluid import FluidParams, FluidSimulation, GasSource

S_PX, CX, CY = 780.0, 159.5, 119.5
H, W = 240, 320


def _release_series(tau_s: float, n: int = 4000, dt: float = 1 / 60) -> np.ndarray:
    src = GasSource(position_m=(0.1, 0.1, 0.1), radius_m=0.02, release_rate_g_s=1.0,
                    release_fluctuation=0.4, release_correlation_s=tau_s)
    sim = FluidSimulation(FluidParams(shape=(8, 8, 8), voxel_m=0.03, sources=(src,)), seed=3)
    return np.array([sim._release_step(0, src, dt) for _ in range(n)])


def test_release_fluctuation_is_time_correlated_with_unit_variance() -> None:
    x = _release_series(0.7)
    lag1 = np.corrcoef(x[:-1], x[1:])[0, 1]
    assert lag1 == pytest.approx(np.exp(-(1 / 60) / 0.7), abs=0.02)
    assert np.std(x) == pytest.approx(1.0, abs=0.15)
    white = _release_series(0.0)
    assert abs(np.corrcoef(white[:-1], white[1:])[0, 1]) < 0.06


def test_released_mass_is_the_integral_of_the_release() -> None:
    src = GasSource(position_m=(0.12, 0.12, 0.12), radius_m=0.03, release_rate_g_s=2.0,
                    release_fluctuation=0.0)
    p = FluidParams(shape=(8, 8, 8), voxel_m=0.03, dt_s=0.01, sources=(src,),
                    viscosity_m2_s=0.0, diffusivity_m2_s=0.0)
    sim = FluidSimulation(p, seed=1)
    sim.step()
    sim.step()
    assert sim.released_kg == pytest.approx(2.0e-3 * 0.02, rel=1e-9)


@pytest.mark.parametrize("x_c", [60.0, 159.5, 290.0])
def test_true_flux_of_a_thin_slab_equals_the_measured_formula(x_c: float) -> None:
    """For a slab thin along the ray, M = integral c V Z dl = sigma V Z: the true flux is
    the measured Q = sum sigma (V.n) ds with the exact depth."""
    rho, t, z0, v = 2e-3, 0.2, 5.0, np.array([1.5, -0.2, 0.4])
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r_norm = np.sqrt((x - CX) ** 2 + (y - CY) ** 2 + S_PX**2)
    gas = (y >= 100) & (y < 140)
    sigma = np.where(gas, rho * t * r_norm / S_PX, 0.0)
    moment = sigma[..., None] * v[None, None] * z0
    curtain = Curtain((x_c, 80.0), (x_c, 170.0), normal_sign=-1.0)
    truth = true_curtain_flux(curtain, moment, principal_point=(CX, CY), camera_constant=S_PX)
    measured = curtain_flux(curtain, sigma, np.broadcast_to(v, (H, W, 3)), np.full((H, W), z0),
                            np.ones((H, W), bool), gas, principal_point=(CX, CY),
                            camera_constant=S_PX)
    k = (x_c - CX) / S_PX
    expected = rho * t * (40 * z0 / S_PX) * (v[0] - k * v[2])
    assert truth == pytest.approx(expected, rel=0.01)
    assert measured.rate_kg_s == pytest.approx(truth, rel=1e-9)


def test_simulated_sequence_carries_release_and_flux_truth(tmp_path) -> None:
    """A coarse field scene: the per-frame release is recorded and round-trips through the
    sequence files, and the true flux through a curtain across the plume has the release's
    order (mass conservation of the simulation, up to storage and transport delay)."""
    from processing.synthetic import read_frame, write_sequence
    from processing.synthetic.sequences import generate_sequence, preset_field

    cfg = preset_field(n_frames=12, voxel_m=0.12, release_rate_g_s=3.0)
    cfg = replace(cfg, spinup_steps=150)
    write_sequence(tmp_path / "s", cfg.meta(), generate_sequence(cfg))
    frames = [read_frame(tmp_path / "s", i) for i in range(cfg.n_frames)]
    assert all(f.release_rate_g_s is not None and f.release_rate_g_s >= 0 for f in frames)
    assert np.mean([f.release_rate_g_s for f in frames]) == pytest.approx(3.0, rel=0.8)
    cam = cfg.camera
    flux = [true_curtain_flux(Curtain((220.0, 0.0), (220.0, H - 1.0)), f.flux_moment_kg_s,
                              principal_point=(cam.cx, cam.cy), camera_constant=cam.s_px)
            for f in frames]
    assert frames[0].flux_moment_kg_s.dtype == np.float32
    assert frames[0].flux_moment_kg_s.shape == (H, W, 3)
    # n = r x e points to -X for a downward curtain: gas blown to +X crosses negatively.
    assert -np.mean(flux) * 1e3 == pytest.approx(np.mean([f.release_rate_g_s
                                                           for f in frames]), rel=0.5)


def test_spatial_fill_reconstructs_a_smooth_background() -> None:
    y, x = np.mgrid[0:60, 0:80].astype(np.float64)
    field = 10.0 + 0.01 * x + 0.005 * y
    known = np.ones(field.shape, bool)
    known[20:40, 30:50] = False
    filled = spatial_fill(np.where(known, field, -99.0), known)
    assert np.abs(filled - field).max() < 0.05


def test_background_model_fills_pixels_that_never_saw_the_background() -> None:
    bg = BackgroundModel(capacity=10, min_samples=3, refresh=1)
    gas = np.zeros((16, 16), bool)
    gas[4:10, 4:10] = True  # a plume that never leaves these pixels
    for _ in range(10):
        frame = np.full((16, 16), 10.0)
        frame[gas] = 9.0
        bg.update(frame, gas)
    est = bg.estimate()
    assert est is not None and np.allclose(est, 10.0, atol=1e-6)
    assert bg.fallback_fraction == pytest.approx(36 / 256)


def test_eval_emission_command_writes_table_json_and_figure(tmp_path, capsys) -> None:
    """``ogiflow eval emission`` end to end on a tiny coarse sequence (accuracy is measured
    by benchmarks/emission_sequences.sh, not here)."""
    import json

    from appliance import cli

    data = tmp_path / "data"
    assert cli.main(["simulate", "--preset", "field", "--name", "tiny", "--out", str(data / "a"),
                     "--frames", "6", "--grid-scale", "0.25", "--spinup-steps", "150",
                     "--distance", "4"]) == cli.EXIT_OK
    out = tmp_path / "emission.json"
    assert cli.main(["eval", "emission", "--data", str(data), "--json", str(out),
                     "--figures", str(tmp_path / "fig"), "--frames", "3"]) == cli.EXIT_OK
    res = json.loads(out.read_text())
    rec = res["a_tiny"]
    for key in ("true_release_g_s", "true_flux_g_s", "stereo_g_s", "stereo_uncertainty_g_s",
                "single_camera_g_s", "out_of_plane_deg", "flags"):
        assert key in rec
    assert rec["flags"] in ([], ["line_of_sight"])
    assert rec["out_of_plane_deg"] is None or 0 <= rec["out_of_plane_deg"] <= 90
    assert rec["true_release_g_s"] > 0 and rec["distance_m"] == pytest.approx(4.0, abs=0.5)
    assert (tmp_path / "fig" / "a_tiny_rate.png").is_file()
    assert "a_tiny" in capsys.readouterr().out
    assert cli.main(["eval", "emission", "--data", str(tmp_path / "none")]) == cli.EXIT_USAGE


def test_eval_emission_table_marks_a_line_of_sight_rate() -> None:
    from appliance.evaluation.emission import format_table

    def rec(angle: float, flags: list[str], wind_z: float) -> dict:
        return {"true_release_g_s": 2.0, "true_flux_g_s": 1.5, "stereo_g_s": 1.8,
                "stereo_uncertainty_g_s": 0.1, "single_camera_g_s": 1.6, "stereo_error": 0.2,
                "single_camera_error": 0.07, "wind_m_s": [0.6, 0.0, wind_z], "distance_m": 5.2,
                "camera_effects": False, "frames_defined": 4, "frames_total": 4,
                "out_of_plane_deg": angle, "flags": flags}

    vanishing = {**rec(40.0, [], 1.2), "vanishes_in_view": True}
    table = format_table({"along_view": rec(62.0, ["line_of_sight"], 1.8),
                          "across": rec(3.0, [], 0.0), "shallow": vanishing})
    rows = {line.split()[0]: line for line in table.splitlines()[2:5]}
    assert rows["along_view"].endswith("62 deg LOS")
    assert rows["across"].endswith("3 deg")
    assert rows["shallow"].startswith("shallow v ") and " v " not in rows["across"]
