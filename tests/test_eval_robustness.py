"""``ogiflow eval robustness``: the matrix runs, caches the gas once per scene, and reports."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from appliance.evaluation import robustness as rb
from processing.calibration.radiometric import apply_characteristic_curve
from processing.synthetic.config import RenderOptions, synthetic_calibration
from processing.synthetic.imaging import CountsModel, to_counts

TINY = rb.Matrix(
    name="tiny",
    scenes=(rb.Scene(7, (1.0, 0.0, 1.0)),),
    conditions=(rb.Condition("ideal"), rb.Condition("jitter 0.3 px", jitter_px=0.3)),
    n_frames=4,
    voxel_m=0.12,
)


def test_matrix_runs_reuses_one_simulation_and_reports(tmp_path: Path) -> None:
    logs: list[str] = []
    res = rb.run_matrix(TINY, tmp_path, log=logs.append)
    assert list(res) == ["ideal", "jitter 0.3 px"]
    # One fluid simulation for the scene, reused by every condition.
    assert sum("simulating" in m for m in logs) == 1
    for r in res.values():
        p = r["pooled"]
        assert p["n_frames"] == 2
        for key in ("rmve", "aemv", "aee_3d_mm_s", "sa", "false_gas"):
            assert p[key] is None or np.isfinite(p[key])
        assert set(r["scenes"]) == {TINY.scenes[0].name}
        # the scene's mean velocity against its reference's, pooled as the scenes' mean
        scene = r["scenes"][TINY.scenes[0].name]
        frames = [f for f in scene["frames"] if f["mean_velocity"] is not None]
        got = np.mean([f["mean_velocity"] for f in frames], axis=0)
        ref = np.mean([f["reference_mean_velocity"] for f in frames], axis=0)
        expected = 100.0 * abs(1.0 - np.linalg.norm(got) / np.linalg.norm(ref))
        assert scene["rmve_of_mean"] == pytest.approx(expected)
        assert p["rmve_of_mean"] == scene["rmve_of_mean"]
        assert p["aemv_of_mean"] == scene["aemv_of_mean"]
    # jitter on the textured plant wall is measured and removed
    assert res["jitter 0.3 px"]["flags"].get("jitter_corrected", 0) >= 1
    text = rb.format_table(res)
    assert "jitter 0.3 px" in text and "false" in text and "mean V: RMVE/%" in text
    doc = json.dumps(rb.public(res))
    assert "NaN" not in doc
    # a second run reads the cache
    logs.clear()
    rb.run_matrix(TINY, tmp_path, conditions=["ideal"], log=logs.append)
    assert not any("simulating" in m for m in logs)


def test_unknown_condition_and_matrix_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown condition"):
        rb.run_matrix(TINY, tmp_path, conditions=["nope"])
    assert cli.main(["eval", "robustness", "--matrix", "nope"]) == cli.EXIT_USAGE


def test_holdout_matrix_is_the_acceptance_set_on_unseen_seeds() -> None:
    holdout, default = rb.MATRICES["holdout"], rb.DEFAULT_MATRIX
    assert {s.seed for s in holdout.scenes}.isdisjoint({s.seed for s in default.scenes})
    assert {s.wind_m_s for s in holdout.scenes} == {s.wind_m_s for s in default.scenes}
    assert [c.name for c in holdout.conditions] == [c.name for c in default.conditions
                                                    if c.realistic]
    assert len(holdout.scenes) == 8 and holdout.n_frames == default.n_frames


def test_simulator_calibration_inverts_the_cameras_counts() -> None:
    cfg = rb.scene_config(TINY.scenes[0], TINY)
    cfg = cfg.__class__(**{**cfg.__dict__, "options": RenderOptions(gain_mismatch=0.06)})
    calib = synthetic_calibration(cfg)
    left, right = cfg.effective_counts()
    assert right.gain == pytest.approx(1.06 * left.gain)
    radiance = np.full((4, 4), 0.012)
    for model, curve in ((left, calib.radiometric.left), (right, calib.radiometric.right)):
        counts = to_counts(radiance, CountsModel(model.gain, model.offset))
        back = apply_characteristic_curve(counts, curve)
        assert np.allclose(back, radiance, atol=0.6 / model.gain)


def test_the_run_that_simulates_a_scene_reads_what_the_cache_gives_later(
        tmp_path: Path) -> None:
    """The gas a first run simulates and the gas later runs load from the cache are the
    same numbers, so a matrix reads the same whether its gas was cached or not."""
    base = rb.scene_config(TINY.scenes[0], TINY)
    fresh, cached = rb.gas_frames(base, tmp_path), rb.gas_frames(base, tmp_path)
    assert len(fresh) == len(cached) == TINY.n_frames
    for a, b in zip(fresh, cached, strict=True):
        np.testing.assert_array_equal(a.column_left, b.column_left)
        np.testing.assert_array_equal(a.column_right, b.column_right)
        np.testing.assert_array_equal(a.truth.velocity, b.truth.velocity)


def test_lens_condition_rectifies_frames_and_moves_the_truth_with_them(tmp_path: Path) -> None:
    """A calibrated lens row hands the chain rectification maps, and the ground truth is
    resampled by the same maps (a rectified pixel sees the ray of the distorted pixel its
    map points to); an uncalibrated one leaves both on the distorted grid."""
    from processing.synthetic.cameras import StereoRenderer

    cal = rb.Condition("lens cal.", lens_k1=rb.LENS_K1)
    uncal = rb.Condition("lens uncal.", lens_k1=rb.LENS_K1, calibrated=False)
    base = rb.scene_config(TINY.scenes[0], TINY, lens_k1=rb.LENS_K1)
    assert base.effective_camera().k1 == rb.LENS_K1
    geo = rb.condition_geometry(rb.condition_config(base, cal), cal)
    assert geo.maps_left is not None and geo.curve_left is not None
    assert rb.condition_geometry(rb.condition_config(base, uncal), uncal).maps_left is None
    frame = StereoRenderer(rb.condition_config(base, cal)).render(
        rb.gas_frames(base, tmp_path)[1])
    moved = rb.rectified_truth(frame, geo)
    mx, my = geo.maps_left
    ys, xs = np.nonzero(moved.gt_mask)
    assert len(ys) > 50
    src_x = np.rint(mx[ys, xs]).astype(int)
    src_y = np.rint(my[ys, xs]).astype(int)
    assert frame.gt_mask[src_y, src_x].all()
    np.testing.assert_array_equal(moved.gt_velocity[ys, xs], frame.gt_velocity[src_y, src_x])
    # barrel distortion: the maps pull the corners outwards, so the truth really moved
    assert abs(mx[0, 0] - 0.0) > 1.0


def test_a_configuration_file_sets_the_workers_the_matrix_is_run_with(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--config FILE`` runs the triples as the file's workers take them (the shipped
    configuration: two), ``--workers`` says otherwise; more than two is refused before any
    scene is simulated."""
    matrix = tmp_path / "m.yaml"
    matrix.write_text("name: m\nn_frames: 5\nvoxel_m: 0.12\nconditions: [{name: ideal}]\n"
                      "scenes: [{seed: 7, wind_m_s: [1.0, 0.0, 1.0]}]\n")
    cfg = tmp_path / "two.yaml"
    cfg.write_text("processing:\n  workers: 2\n")
    runs = {}
    for extra in ([], ["--workers", "1"]):
        out = tmp_path / f"r{len(extra)}.json"
        assert cli.main(["eval", "robustness", "--matrix", str(matrix), "--config", str(cfg),
                         "--cache-dir", str(tmp_path / "cache"), "--json", str(out),
                         *extra]) == cli.EXIT_OK
        runs[len(extra)] = json.loads(out.read_text())["ideal"]
    assert runs[0]["workers"] == 2 and runs[2]["workers"] == 1
    # three triples: the third is warm from the first (two workers) or the second (one)
    assert runs[0]["pooled"]["aee_3d_mm_s"] != runs[2]["pooled"]["aee_3d_mm_s"]
    text = capsys.readouterr().out
    assert "two workers (every other triple each" in text and "one worker" in text
    cfg.write_text("processing:\n  workers: 3\n")
    assert cli.main(["eval", "robustness", "--matrix", str(matrix), "--config", str(cfg),
                     "--cache-dir", str(tmp_path / "cache")]) == cli.EXIT_USAGE
    assert "processing.workers is 3" in capsys.readouterr().err
