"""Simulated release schedules and the no-release scene, through the real event logic.

Short versions of ``benchmarks/bench_detection.py`` (which measures the detection delay of
every release of a schedule and the false events of 30 min of no-release scene).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from appliance.config import ConfigError, load_config, parse_set_option
from appliance.evaluation.detection import (
    DetectionSettings,
    detect_frames,
    score_releases,
    simulated_frames,
)
from appliance.runtime.simsite import scene_config, scene_key
from processing.synthetic.presets import preset_field, preset_no_release
from processing.synthetic.schedule import ReleaseSchedule
from processing.synthetic.sequences import SyntheticStereoScene


def test_schedule_intervals_and_validation() -> None:
    s = ReleaseSchedule.from_lists([[1.0, 3.0], [5.0, 6.0]], 8.0)
    assert [s.is_on(t) for t in (0.5, 1.0, 2.9, 3.0, 5.5, 7.0, 9.5, 13.5)] == [
        False, True, True, False, True, False, True, True]
    assert s.starts(20.0) == [1.0, 5.0, 9.0, 13.0, 17.0]
    assert s.releases(10.0)[-1] == (9.0, 10.0)
    assert ReleaseSchedule.from_json(s.to_json()) == s
    for bad in ([[2.0, 1.0]], [[0.0, 9.0]], [[1.0, 3.0], [2.0, 4.0]], []):
        with pytest.raises(ValueError):
            ReleaseSchedule.from_lists(bad, 8.0)


def test_truth_follows_the_gas_that_is_there() -> None:
    """Release off before 0.5 s: no gas at all (the spin-up is the end of the previous
    cycle, also off); on for 0.5 s; after it stops the gas drifts on for a while, and the
    truth shows it."""
    schedule = ReleaseSchedule.from_lists([[0.5, 1.0]], 3.0)
    cfg = replace(preset_field(n_frames=75, voxel_m=0.12), release_schedule=schedule)
    scene = SyntheticStereoScene(cfg)
    gas = [scene.next_gas() for _ in range(cfg.n_frames)]
    px = np.array([g.truth.mask.sum() for g in gas])
    t = np.array([g.t_s for g in gas])
    assert px[t < 0.5].max() == 0
    assert px[(t > 0.9) & (t < 1.0)].min() > 100
    assert px[(t >= 1.1) & (t < 1.4)].min() > 0  # released gas still in view
    assert scene.release_rate_g_s(0.7) == pytest.approx(cfg.fluid.sources[0].release_rate_g_s)
    assert scene.release_rate_g_s(1.2) == 0.0
    assert cfg.meta()["release_schedule"] == schedule.to_json()


def test_a_short_schedule_finds_its_release_within_5_s() -> None:
    # 6 cm voxels as the benchmark (on 10 cm the coarse plume's alarm came after 5.4 s)
    schedule = ReleaseSchedule.from_lists([[1.0, 5.5]], 6.0)
    cfg = replace(preset_field(n_frames=180, voxel_m=0.06), release_schedule=schedule)
    settings = DetectionSettings()
    report = detect_frames(simulated_frames(cfg, 6), cfg.meta(), settings, 6)
    score = score_releases(report, schedule.releases(6.0), settings.events.end_window_s)
    assert score["found"] == 1, report["per_frame"]
    assert score["false_events"] == 0
    assert 0.0 <= score["max_delay_s"] <= 5.0


def test_a_short_no_release_run_raises_no_event() -> None:
    """15 s of noise, jitter, background drift and a warm person walking slowly into the
    view from the left edge (the case that started events before the border and
    persistence rules)."""
    cfg = preset_no_release(n_frames=450, walker_period_s=20.0, drift_period_s=60.0)
    assert not cfg.fluid.sources and cfg.options.moving_object is not None
    report = detect_frames(simulated_frames(cfg, 10), cfg.meta(), DetectionSettings(), 10)
    assert report["gas_frames"] > 10  # the walker and the drift are segmented as "gas"
    assert report["events"] == []


def _load(*sets: str):
    return load_config(None, [parse_set_option(s) for s in sets])


def test_config_release_schedule_and_scene() -> None:
    cfg = _load("simulation.frames=300", "simulation.release_schedule=[[1, 4], [6, 8]]")
    assert cfg.simulation.release_schedule == [[1.0, 4.0], [6.0, 8.0]]
    seq = scene_config(cfg.simulation, (1.5, 0.0, 0.0))
    assert seq.release_schedule == ReleaseSchedule(((1.0, 4.0), (6.0, 8.0)), 10.0)
    default = _load()
    assert scene_key(default.simulation, (1.5, 0.0, 0.0)) != scene_key(
        cfg.simulation, (1.5, 0.0, 0.0))
    nr = _load("simulation.scene=no_release")
    seq = scene_config(nr.simulation, (1.5, 0.0, 0.0))
    assert not seq.fluid.sources and seq.options.moving_object.back_forth_s == 8.0
    for bad in ("simulation.release_schedule=[[1, 9]]",  # beyond the 8 s loop
                "simulation.release_schedule=[[3, 1]]",
                "simulation.release_schedule=[1, 2]"):
        with pytest.raises(ConfigError, match="release_schedule"):
            _load(bad)
    with pytest.raises(ConfigError, match="only the leak scene"):
        _load("simulation.scene=no_release", "simulation.release_schedule=[[1, 2]]")


def test_first_start_shows_a_preview_while_the_scene_renders_in_background(tmp_path) -> None:
    """Cold cache: the site loops the quick preview (coarser grid, its own exact truth) and
    renders the configured scene in a background process that ``close`` stops; a schedule
    gets no preview (it needs its whole loop)."""
    from appliance.runtime.simsite import PREVIEW_VOXEL_M, SimulatedSite, preview_of

    cfg = _load("simulation.frames=30", "simulation.voxel_m=0.08",
                f"simulation.cache_dir={tmp_path}")
    site = SimulatedSite(cfg, np.eye(3))
    try:
        site.prepare()
        assert site.background is not None
        assert site.truth is not None and site.truth.n_frames == 30
        meta = json.loads((site.folder / "meta.json").read_text())
        assert meta["simulation"]["voxel_m"] == pytest.approx(PREVIEW_VOXEL_M)
    finally:
        proc = site.background
        site.close()
    assert proc is not None and proc.poll() is not None and site.background is None
    scheduled = _load("simulation.frames=300", "simulation.release_schedule=[[1, 4]]")
    assert preview_of(scheduled.simulation) is None
    assert preview_of(_load("simulation.scene=no_release").simulation) is None
