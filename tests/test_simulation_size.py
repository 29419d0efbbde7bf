"""The simulated cameras' image size: 320x240 (default) and 640x480, same field of view.

Configuration checks, the scene and chain settings at 640x480, a short ``ogiflow run`` of a
640x480 pair (bounded by results and frames, not by time) and ``ogiflow bench --size``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from appliance.config import ConfigError, SimulationConfig, load_config
from appliance.evaluation import benchmark as bm
from appliance.recording.reader import read_metadata
from appliance.runtime import simsite
from appliance.runtime.daemon import Appliance
from processing.chain import ChainParameters
from tests.conftest import SMALL_SCENE
from tests.test_daemon import stop_when

SIZE_640 = [("simulation.width_px", 640), ("simulation.height_px", 480)]
WIND = (1.5, 0.0, 0.0)


def test_default_size_is_320x240() -> None:
    sim = load_config(None).simulation
    assert (sim.width_px, sim.height_px) == (320, 240)
    assert simsite.check_image_size(sim) == (320, 240)


def test_640x480_is_accepted() -> None:
    sim = load_config(None, SIZE_640).simulation
    assert simsite.check_image_size(sim) == (640, 480)


@pytest.mark.parametrize("key, value", [("simulation.width_px", 800),
                                        ("simulation.height_px", 600),
                                        ("simulation.width_px", "640")])
def test_unsupported_size_is_a_config_error(key: str, value: object) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")) as info:
        load_config(None, [(key, value)])
    assert "must be one of" in str(info.value)


def test_mismatched_width_and_height_exit_2_before_any_device(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    args = ["run", "--duration", "1", "--set", "simulation.width_px=640",
            "--set", f"recording.dir={tmp_path / 'rec'}"]
    assert cli.main(args) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert "simulation.height_px" in err and "640x480" in err
    assert not (tmp_path / "rec").exists()  # nothing was opened or written


def test_default_scene_key_is_unchanged_by_the_size_keys() -> None:
    """A scene cached before the size keys existed is still found at 320x240."""
    sim = SimulationConfig()
    params = {k: v for k, v in vars(sim).items()
              if k not in ("cache_dir", "scene", "release_schedule", "width_px", "height_px")}
    params["wind_m_s"] = [1.5, 0.0, 0.0]
    params["version"] = simsite.SCENE_VERSION
    import hashlib

    expected = hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:16]
    assert simsite.scene_key(sim, WIND) == expected
    big = SimulationConfig(width_px=640, height_px=480)
    assert simsite.scene_key(big, WIND) != expected


@pytest.mark.parametrize("scene", ["leak", "no_release"])
def test_640x480_scene_keeps_the_field_of_view(scene: str) -> None:
    small = simsite.scene_config(SimulationConfig(scene=scene), WIND).effective_camera()
    big = simsite.scene_config(SimulationConfig(scene=scene, width_px=640, height_px=480),
                               WIND).effective_camera()
    assert (big.width, big.height) == (640, 480)
    assert big.s_px == 2 * small.s_px == 1560.0
    assert (big.cx, big.cy) == (319.5, 239.5)
    # the same half-angle of view across the width and the height
    assert big.width / big.s_px == pytest.approx(small.width / small.s_px)
    assert big.height / big.s_px == pytest.approx(small.height / small.s_px)


def test_chain_settings_in_px_grow_with_the_width(tmp_path: Path) -> None:
    base = ChainParameters()
    cfg = load_config(None, SIZE_640)
    site = simsite.SimulatedSite(cfg, np.eye(3))
    site.folder = tmp_path  # as after prepare(): the rendered scene is in use
    d = site.chain_defaults(1560.0, 0.3)
    assert d["d0"] == pytest.approx(1560.0 * 0.3 / (2 * 5.5))
    assert d["sgm_num_disparities"] == 2 * base.sgm_num_disparities
    assert d["max_motion_px"] == 2 * base.max_motion_px
    assert d["region_margin_px"] == 2 * base.region_margin_px
    assert d["gate_tolerance_px"] == 2 * base.gate_tolerance_px
    ChainParameters.from_mapping(d)  # valid chain parameters
    small = simsite.SimulatedSite(load_config(None), np.eye(3))
    small.folder = tmp_path
    assert set(small.chain_defaults(780.0, 0.3)) == {"register", "d0"}


def test_run_a_640x480_pair(tmp_path: Path) -> None:
    """``ogiflow run`` with 640x480 simulated cameras: recorded at that size, processed."""
    cfg = load_config(None, [*SMALL_SCENE, *SIZE_640,
                             ("simulation.cache_dir", str(tmp_path / "scenes")),
                             ("recording.dir", str(tmp_path / "rec")), ("live.mode", "save"),
                             ("live.file", str(tmp_path / "live.rrd"))])
    app = Appliance(cfg, duration_s=300.0)
    stop_when(app, lambda c: c.results >= 6 and c.frames["left"] >= 60, deadline_s=280.0)
    assert app.run() == cli.EXIT_OK
    assert app.counters.results >= 6 and app.counters.frames["left"] >= 60
    assert app.image_size == (640, 480)
    (mcap,) = sorted((tmp_path / "rec").glob("ogiflow-*.mcap"))
    meta = read_metadata(mcap)
    geometry = json.loads(meta["geometry"]["json"])
    assert geometry["image_size"] == [640, 480]
    assert geometry["camera_constant"] == pytest.approx(1560.0)
    params = json.loads(meta["processing"]["json"])
    assert params["sgm_num_disparities"] == 128 and params["max_motion_px"] == 16
    comparison = app.publisher.truth_comparison()
    assert comparison is not None and comparison["frames"] > 0


def test_bench_at_640x480(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench.json"
    args = ["bench", "--size", "640x480", "--source", "blob", "--frames", "5", "--runs", "1",
            "--warmup", "1", "--seconds", "0.5", "--workers-max", "1",
            "--cache-dir", str(tmp_path / "cache"), "--json", str(out)]
    assert cli.main(args) == cli.EXIT_OK
    res = json.loads(out.read_text())
    assert res["image_size"] == [640, 480]
    assert set(res["no_active_region"]["stages_ms"]) == set(bm.STAGES)
    assert res["pairs_per_s"]["1"] > 0
    assert "frames 640x480" in capsys.readouterr().out
    frames = bm.load_frames("blob", n_frames=5, cache_dir=tmp_path / "cache",
                            image_size=(640, 480))
    assert frames.left.shape == (5, 480, 640) and frames.image_size == (640, 480)
    assert bm.geometry((640, 480)).camera_constant == 1560.0
