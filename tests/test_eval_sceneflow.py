"""``ogiflow eval sceneflow`` end to end on a tiny generated sequence, and its error paths."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import pytest

from appliance import cli
from appliance.evaluation import sceneflow as eval_sceneflow
from processing.synthetic import write_sequence
from processing.synthetic.render import StereoCamera
from processing.synthetic.sequences import generate_sequence, preset_table2_1

METHODS = ("proposed", "sgm_brox", "sgm_farneback")


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One 4-frame sequence: Table-2 preset 1 on a 24^3 grid, 128 x 96 px (s scaled by 0.4).

    The gas is ~2 m away, so d ~ 312 * 0.2 / 2 = 31 px: SGM range 64, d0 = 20 px.
    """
    root = tmp_path_factory.mktemp("synthetic")
    cfg = preset_table2_1()
    n = 24
    fluid = replace(cfg.fluid, shape=(n, n, n), voxel_m=cfg.fluid.voxel_m * 100 / n)
    cfg = replace(cfg, fluid=fluid, n_frames=4, spinup_steps=10,
                  camera=StereoCamera(width=128, height=96, s_px=312.0))
    write_sequence(root / "tiny", cfg.meta(), generate_sequence(cfg))
    return root


def _finite_or_none(v: object) -> bool:
    return v is None or (isinstance(v, float) and math.isfinite(v))


def test_end_to_end_json_table_and_figures(tiny_data: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "t3.json"
    figs = tmp_path / "figs"
    rc = cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--json", str(out),
                   "--figures", str(figs), "--d0", "20", "--sgm-range", "64"])
    assert rc == cli.EXIT_OK
    res = json.loads(out.read_text())
    assert set(res) == {"tiny"}
    seq = res["tiny"]
    assert seq["reference"]["triples"] == 2
    assert seq["reference"]["mean_speed_m_s"] > 0.5
    for m in METHODS:
        r = seq[m]
        assert r["n_frames"] == 2 and len(r["frames"]) == 2
        for key in ("rmve", "rmve_std", "aemv", "aemv_std", "aee_3d_mm_s", "aae_3d_deg",
                    "c_usf", "sa"):
            assert _finite_or_none(r[key]), (m, key, r[key])
        assert len(r["r_sf"]) == 3 and all(_finite_or_none(x) for x in r["r_sf"])
        # Every per-frame value is a number or a flagged None, never NaN.
        assert "NaN" not in out.read_text()
        assert r["rmve"] >= 0 and 0 <= r["aemv"] <= 180 and 0 <= r["aae_3d_deg"] <= 90
        assert 0 < r["c_usf"] <= 1 and r["sa"] > 0
    # The same segmentation scores all three methods.
    assert seq["proposed"]["sa"] == seq["sgm_brox"]["sa"] == seq["sgm_farneback"]["sa"]
    # The chain recovers the mean gas velocity of even this coarse scene (measured ~7 %,
    # AEMV ~6 deg); the bounds catch a broken chain or a sign error, not small drifts.
    assert seq["proposed"]["rmve"] < 30 and seq["proposed"]["aemv"] < 30
    text = capsys.readouterr().out
    assert "RMVE" in text and "tiny" in text and "ours" in text
    for name in ("tiny_mean_velocity.png", "tiny_fields.png"):
        img = cv2.imread(str(figs / name))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 300


def test_single_sequence_directory_and_frame_limit(tiny_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "one.json"
    rc = cli.main(["eval", "sceneflow", "--data", str(tiny_data / "tiny"), "--json", str(out),
                   "--d0", "20", "--sgm-range", "64", "--frames", "1"])
    assert rc == cli.EXIT_OK
    assert json.loads(out.read_text())["tiny"]["proposed"]["n_frames"] == 1


def test_missing_data_names_the_simulate_command(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nothing_here"
    assert cli.main(["eval", "sceneflow", "--data", str(missing)]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert f"ogiflow simulate --out {missing}" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["eval", "sceneflow", "--data", str(empty)]) == cli.EXIT_USAGE
    assert f"ogiflow simulate --out {empty}" in capsys.readouterr().err


def test_bad_options_exit_2(tiny_data: Path) -> None:
    for extra in (["--sgm-range", "50"], ["--d0", "-1"], ["--frames", "0"]):
        assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), *extra]) == \
            cli.EXIT_USAGE


def test_corrupt_frame_is_a_clear_failure(tiny_data: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    copy = tmp_path / "data" / "tiny"
    shutil.copytree(tiny_data / "tiny", copy)
    (copy / "frame_00002.npz").write_bytes(b"truncated")
    rc = cli.main(["eval", "sceneflow", "--data", str(copy.parent)])
    assert rc == cli.EXIT_FAILURE
    assert "frame_00002.npz" in capsys.readouterr().err


def test_paper_table_covers_the_three_table2_presets() -> None:
    assert set(eval_sceneflow.PAPER_TABLE3) == {"table2_1", "table2_2", "table2_3"}
    for row in eval_sceneflow.PAPER_TABLE3.values():
        assert set(row) == set(METHODS)


def test_frame_metrics_of_a_perfect_field_and_aggregate_flags() -> None:
    import numpy as np

    rng = np.random.default_rng(0)
    ref = rng.normal(size=(12, 16, 3)).astype(np.float32)
    ref[..., 1] -= 3.0
    mask = np.zeros((12, 16), bool)
    mask[2:10, 3:13] = True
    ref_nan = np.where(mask[..., None], ref, np.nan).astype(np.float32)
    ones = np.ones((12, 16), bool)
    u_sf = np.zeros((12, 16), np.float32)
    fm = eval_sceneflow.frame_metrics(np.where(mask[..., None], ref, 0.0).astype(np.float32),
                                      ones, mask, u_sf, ones, ref_nan, mask)
    assert fm["rmve"] == pytest.approx(0.0, abs=1e-6)
    assert fm["aemv"] == pytest.approx(0.0, abs=1e-3)
    assert fm["aee_3d_mm_s"] == pytest.approx(0.0, abs=1e-6)
    assert fm["aae_3d_deg"] == pytest.approx(0.0, abs=0.1)
    assert fm["c_usf"] == pytest.approx(1.0) and fm["sa"] == pytest.approx(100.0)
    assert fm["r_sf"] == pytest.approx([1.0, 1.0, 1.0])
    # An empty segmentation: every method metric undefined, flagged, none NaN.
    empty = eval_sceneflow.frame_metrics(ref, ones, np.zeros((12, 16), bool), u_sf, ones,
                                         ref_nan, mask)
    assert empty["rmve"] is None and empty["aee_3d_mm_s"] is None and empty["sa"] == 0.0
    agg = eval_sceneflow.aggregate([fm, empty])
    assert agg["rmve"] == pytest.approx(0.0, abs=1e-6) and agg["rmve_std"] == 0.0
    assert agg["undefined"]["rmve"] == 1 and agg["undefined"]["r_sf_X"] == 1
    assert agg["sa"] == pytest.approx(50.0)


# ------------------------------------------------- geometry and chain from each sequence


def test_values_come_from_meta_and_flags_override(tiny_data: Path) -> None:
    from appliance.evaluation.sceneflow_setup import Overrides, sequence_setup
    from processing.synthetic import read_sequence_meta

    seq = tiny_data / "tiny"
    meta = read_sequence_meta(seq)
    setup = sequence_setup(meta, seq)
    # the Table-2 volume lies 1.8-2.2 m away: d0 = floor(312 * 0.2 / 2.2) = 28 px
    assert setup.params.d0 == 28 and setup.params.sgm_num_disparities == 64
    assert not setup.params.register  # the paper's conditions
    assert setup.sources["d0"] == "from the gas depth band"
    assert setup.sources["focal length s"] == "meta.json"
    assert setup.geometry.camera_constant == 312.0
    assert setup.frame_interval_s == pytest.approx(meta["frame_interval_s"])
    ov = Overrides(focal_length_px=300.0, depth_band_m=(1.0, 1.2), frame_interval_s=0.002,
                   sgm_range=32)
    setup = sequence_setup(meta, seq, overrides=ov)
    assert setup.geometry.camera_constant == 300.0
    assert setup.params.d0 == math.floor(300 * 0.2 / 1.2)
    assert setup.params.sgm_num_disparities == 32
    assert setup.frame_interval_s == 0.002
    assert setup.sources["gas depth band"] == setup.sources["SGM range"] == "command line"


def test_appliance_chain_runs_the_configuration_files_parameters(tiny_data: Path,
                                                                  tmp_path: Path) -> None:
    from appliance.evaluation.sceneflow_setup import Overrides, sequence_setup
    from processing.synthetic import read_sequence_meta

    seq = tiny_data / "tiny"
    meta = read_sequence_meta(seq)
    builtin = sequence_setup(meta, seq, chain="appliance")
    assert builtin.params.register and builtin.params.depth_gate
    assert builtin.params.d0 == 28  # the band, as the daemon's simulated site sets it
    site = tmp_path / "site.yaml"
    site.write_text("processing:\n  parameters: {d0: 25, disparity_options: {n_warps: 3}}\n"
                    "cameras: {left: {backend: aravis}}\ncalibration: /nonexistent.yaml\n")
    setup = sequence_setup(meta, seq, chain="appliance", config=site)
    assert setup.params.d0 == 25 and dict(setup.params.disparity_options) == {"n_warps": 3}
    assert setup.sources["d0"] == f"configuration {site}"
    flagged = sequence_setup(meta, seq, chain="appliance", config=site,
                             overrides=Overrides(d0=30.0))
    assert flagged.params.d0 == 30 and flagged.sources["d0"] == "command line"
    with pytest.raises(ValueError, match="--chain appliance only"):
        sequence_setup(meta, seq, chain="paper", config=site)
    site.write_text("processing:\n  parameters: {alhpa: 0.1}\n")
    with pytest.raises(ValueError, match="alpha"):
        sequence_setup(meta, seq, chain="appliance", config=site)


def test_no_flag_gives_the_figures_of_the_equivalent_hand_set_flags(
        tiny_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    auto, hand = tmp_path / "auto.json", tmp_path / "hand.json"
    assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--frames", "1",
                     "--json", str(auto)]) == cli.EXIT_OK
    text = capsys.readouterr().out
    assert "d0 = 28 px (from the gas depth band)" in text
    assert "baseline b = 0.2 m (meta.json)" in text
    assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--frames", "1",
                     "--d0", "28", "--sgm-range", "64", "--json", str(hand)]) == cli.EXIT_OK
    a = json.loads(auto.read_text())["tiny"]["proposed"]
    h = json.loads(hand.read_text())["tiny"]["proposed"]
    assert a["rmve"] == pytest.approx(h["rmve"]) and a["aemv"] == pytest.approx(h["aemv"])
    # the old fixed Table-3 start (d0 = 60 px) misses this gas (d = 28-35 px) entirely
    far = tmp_path / "far.json"
    assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--frames", "1",
                     "--d0", "60", "--json", str(far)]) == cli.EXIT_OK
    assert json.loads(far.read_text())["tiny"]["setup"]["d0"]["source"] == "command line"


def test_appliance_chain_end_to_end_and_bad_config_exit_2(tiny_data: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    out = tmp_path / "a.json"
    assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--frames", "1",
                     "--chain", "appliance", "--json", str(out)]) == cli.EXIT_OK
    setup = json.loads(out.read_text())["tiny"]["setup"]
    assert setup["registration"]["value"] == "on"
    bad = tmp_path / "bad.yaml"
    bad.write_text("processing:\n  parameters: {registr: false}\n")
    capsys.readouterr()
    assert cli.main(["eval", "sceneflow", "--data", str(tiny_data), "--chain", "appliance",
                     "--config", str(bad)]) == cli.EXIT_USAGE
    assert "registr" in capsys.readouterr().err


@pytest.fixture(scope="module")
def six_frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny sequence with 6 frames: 4 triples, so each of two workers warm-starts once."""
    root = tmp_path_factory.mktemp("synthetic6")
    cfg = preset_table2_1()
    fluid = replace(cfg.fluid, shape=(24, 24, 24), voxel_m=cfg.fluid.voxel_m * 100 / 24)
    cfg = replace(cfg, fluid=fluid, n_frames=6, spinup_steps=10,
                  camera=StereoCamera(width=128, height=96, s_px=312.0))
    write_sequence(root / "six", cfg.meta(), generate_sequence(cfg))
    return root / "six"


def test_two_workers_take_every_other_triple_warm_from_two_frames_back(six_frames: Path
                                                                       ) -> None:
    """``workers=2`` is the daemon's two workers: triple i on state i % 2 at stride 2 (the
    third triple warm from the first), not one state taking every triple."""
    from appliance.evaluation.sceneflow_setup import Overrides, sequence_setup
    from processing.chain import ChainState, compute_scene_flow
    from processing.synthetic import read_frame, read_sequence_meta
    from processing.synthetic.reference import triplet_reference

    meta = read_sequence_meta(six_frames)
    setup = sequence_setup(meta, six_frames, chain="appliance")
    assert setup.workers == 2  # the built-in configuration's processing.workers
    assert setup.sources["workers"] == "built-in configuration"
    assert sequence_setup(meta, six_frames).workers == 1  # the paper's conditions
    one_worker = sequence_setup(meta, six_frames, chain="appliance",
                                overrides=Overrides(workers=1))
    assert one_worker.workers == 1 and one_worker.sources["workers"] == "command line"
    frames = [read_frame(six_frames, i, meta) for i in range(6)]
    g, p = setup.geometry, setup.params
    two, _ = eval_sceneflow.evaluate_frames(frames, g, p, methods=("proposed",), workers=2)
    one, _ = eval_sceneflow.evaluate_frames(frames, g, p, methods=("proposed",), workers=1)
    states = [ChainState(stride=2), ChainState(stride=2)]
    expected = []
    for i in range(4):
        f0, f1, f2 = frames[i:i + 3]
        res = compute_scene_flow([f0.left, f1.left, f2.left], [f0.right, f1.right, f2.right],
                                 [f0.t_s, f1.t_s, f2.t_s], g, p, states[i % 2])
        ref, ref_mask = triplet_reference(f0, f1)
        expected.append(eval_sceneflow.frame_metrics(res.velocity, res.valid, res.gas_mask,
                                                     res.u_sf, res.u_sf_valid, ref, ref_mask))
    assert [s.warm_starts for s in states] == [1, 1]
    got = two["proposed"]["frames"]
    for key in ("rmve", "aemv", "aee_3d_mm_s"):
        assert [f[key] for f in got] == [e[key] for e in expected]
    # one state: triples 1-3 warm from the triple before, so the two differ from triple 1 on
    assert [f["aee_3d_mm_s"] for f in one["proposed"]["frames"]][1:] != \
        [f["aee_3d_mm_s"] for f in got][1:]
    with pytest.raises(ValueError, match="1 or 2 worker"):
        eval_sceneflow.evaluate_frames(frames, g, p, methods=("proposed",), workers=3)


def test_workers_come_from_the_configuration_or_the_command_line(
        six_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "a.json"
    assert cli.main(["eval", "sceneflow", "--data", str(six_frames), "--frames", "1",
                     "--chain", "appliance", "--json", str(out)]) == cli.EXIT_OK
    assert json.loads(out.read_text())["six"]["setup"]["workers"] == {
        "value": "2 (every other triple each, warm from two frames back)",
        "source": "built-in configuration"}
    assert "workers = 2 (every other triple each" in capsys.readouterr().out
    assert cli.main(["eval", "sceneflow", "--data", str(six_frames), "--frames", "1",
                     "--chain", "appliance", "--workers", "1"]) == cli.EXIT_OK
    assert "workers = 1 (every triple warm from the one before) (command line)" in \
        capsys.readouterr().out
    many = tmp_path / "many.yaml"
    many.write_text("processing:\n  workers: 4\n")
    assert cli.main(["eval", "sceneflow", "--data", str(six_frames), "--chain", "appliance",
                     "--config", str(many)]) == cli.EXIT_USAGE
    assert "processing.workers is 4" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # argparse: 1 or 2 only
        cli.main(["eval", "sceneflow", "--data", str(six_frames), "--workers", "3"])
    assert exc.value.code == cli.EXIT_USAGE
