"""The site's gas temperature and the opaque-edge gate that follows it (``processing.opaque_gate``).

Unit checks of the temperature's sources (a real ``multiprocessing.Value`` as the daemon
shares the sonic temperature), the configuration's refusals, then the whole daemon with the
simulated site (whose geometry carries its cameras' counts models as curves) and a replay of
its file.
"""

from __future__ import annotations

import json
import multiprocessing as mp
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pytest

from appliance import cli
from appliance.config import ConfigError, load_config
from appliance.recording.reader import LogReader, read_metadata
from appliance.reprocess.segments import recorded_gas_temperature_k, replay_parameters
from appliance.reprocess.source import Recording
from appliance.runtime.daemon import Appliance
from appliance.runtime.gas_temperature import (
    GateTemperature,
    configured_gas_temperature_k,
    site_gas_temperature_k,
)
from processing.chain import ChainParameters
from processing.emission.estimator import DEFAULT_GAS_TEMPERATURE_K
from processing.stereo_geometry import StereoGeometry
from tests.conftest import SMALL_SCENE
from tests.test_daemon import stop_when


def test_configured_wins_then_the_sonic_temperature_then_15_degc() -> None:
    sonic = mp.get_context("spawn").Value("d", float("nan"), lock=False)
    assert site_gas_temperature_k(None, sonic) == DEFAULT_GAS_TEMPERATURE_K  # none yet
    sonic.value = 279.4
    assert site_gas_temperature_k(None, sonic) == 279.4
    assert site_gas_temperature_k(290.0, sonic) == 290.0
    sonic.value = 1000.0  # a faulty sensor, not the air
    assert site_gas_temperature_k(None, sonic) == DEFAULT_GAS_TEMPERATURE_K
    assert site_gas_temperature_k(None, None) == DEFAULT_GAS_TEMPERATURE_K


def test_the_gate_follows_the_sonic_temperature_triple_by_triple() -> None:
    sonic = mp.get_context("spawn").Value("d", 281.0, lock=False)
    gate = GateTemperature(None)
    first = gate.parameters(ChainParameters(), sonic)
    assert first.opaque_gate_gas_k == 281.0
    assert gate.parameters(first, sonic) is first  # unchanged: no new parameters
    sonic.value = 296.5  # noon
    assert gate.parameters(first, sonic).opaque_gate_gas_k == 296.5
    assert GateTemperature(285.0).parameters(first, sonic).opaque_gate_gas_k == 285.0


def test_configured_temperature_is_the_emission_sections_else_the_simulated_scenes() -> None:
    truth = SimpleNamespace(meta={"radiometry": {"t_gas_k": 285.0}})  # as SceneTruth reads it
    cfg = load_config(None, [])
    assert configured_gas_temperature_k(cfg, None) is None
    assert configured_gas_temperature_k(cfg, truth) == 285.0
    cfg = load_config(None, [("emission.gas_temperature_k", 291.0)])
    assert configured_gas_temperature_k(cfg, truth) == 291.0


def test_a_fixed_gate_temperature_beside_it_and_an_evaluation_are_refused() -> None:
    with pytest.raises(ConfigError, match="opaque_gate"):
        load_config(None, [("processing.opaque_gate", True),
                           ("processing.parameters", {"opaque_gate_gas_k": 288.0})])
    cfg = load_config(None, [("processing.opaque_gate", True)])
    with pytest.raises(ValueError, match="opaque_gate_gas_k"):
        cfg.processing.chain_parameters({})  # an evaluation: no anemometer
    assert cfg.processing.chain_parameters({}, site=True).opaque_gate_gas_k is None


def test_a_simulated_pair_carries_its_counts_models_as_curves() -> None:
    cam = {"s_px": 780.0, "cx_px": 159.5, "cy_px": 119.5, "b_m": 0.3, "width": 320,
           "height": 240}
    counts = {"left": {"gain": 4e5, "offset": 2000.0}, "right": {"gain": 4.2e5, "offset": 1900.0}}
    g = StereoGeometry.from_synthetic_camera(cam, counts)
    assert (g.curve_left.gain, g.curve_left.offset) == (4e5, 2000.0)
    assert (g.curve_right.gain, g.curve_right.offset) == (4.2e5, 1900.0)
    assert StereoGeometry.from_synthetic_camera(cam).curve_left is None


def test_recorded_temperature_configured_else_median_sonic() -> None:
    wind = [{"sonic_temperature_c": 10.0}, {"sonic_temperature_c": 12.0},
            {"sonic_temperature_c": None}, {"sonic_temperature_c": 11.0}]
    assert recorded_gas_temperature_k(None, {}, wind) == pytest.approx(284.15)
    assert recorded_gas_temperature_k(None, {"emission": {"gas_temperature_k": 290.0}},
                                      wind) == 290.0
    assert recorded_gas_temperature_k(None, {}, []) is None


@pytest.fixture(scope="module")
def gated(tmp_path_factory: pytest.TempPathFactory, scene_cache: Path) -> dict:
    """A simulated run with ``processing.opaque_gate`` on; its recording."""
    tmp = tmp_path_factory.mktemp("gate")
    cfg = load_config(None, [*SMALL_SCENE, ("simulation.cache_dir", str(scene_cache)),
                             ("recording.dir", str(tmp / "rec")), ("live.mode", "off"),
                             ("processing.opaque_gate", True)])
    app = Appliance(cfg, duration_s=240.0)
    stop_when(app, lambda c: c.results >= 8)
    assert app.run() == 0
    return {"app": app, "files": sorted((tmp / "rec").glob("ogiflow-*.mcap")), "tmp": tmp}


def test_the_daemon_runs_the_gate_at_the_simulated_scenes_gas_temperature(gated: dict) -> None:
    app = gated["app"]
    t_gas = float(app.site.truth.meta["radiometry"]["t_gas_k"])
    assert app.params.opaque_gate_gas_k == t_gas
    assert app.counters.results >= 8 and app.counters.result_errors == 0
    meta = read_metadata(gated["files"][0])
    assert json.loads(meta["processing"]["json"])["opaque_gate_gas_k"] == t_gas


def test_a_replay_takes_the_recordings_gas_temperature_unless_told(gated: dict,
                                                                  tmp_path: Path) -> None:
    app, src = gated["app"], gated["files"][0]
    t_gas = float(app.site.truth.meta["radiometry"]["t_gas_k"])
    rec = Recording.open(src)
    assert replay_parameters(rec, {}).opaque_gate_gas_k == t_gas
    assert replay_parameters(rec, {"opaque_gate_gas_k": 290.0}).opaque_gate_gas_k == 290.0
    out = tmp_path / "replayed.mcap"
    assert cli.main(["replay", str(src), "--fast", "--out", str(out)]) == 0
    assert json.loads(read_metadata(out)["processing"]["json"])["opaque_gate_gas_k"] == t_gas
    # The recorded geometry carries the simulated cameras' curves: the gate runs on every
    # triple of the replay, none fails for want of radiance.
    geometry = json.loads(read_metadata(src)["geometry"]["json"])
    assert geometry["curve_left"]["gain"] > 0 and geometry["curve_right"]["gain"] > 0
    counts = Counter(t for t, *_ in LogReader(out))
    assert counts["/pairs"] >= 10 and counts["/sceneflow/summary"] == counts["/pairs"] - 2
