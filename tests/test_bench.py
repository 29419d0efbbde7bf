"""``ogiflow bench``: JSON shape and sanity of the values (no timing assertions)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from appliance.config.load import load_config
from appliance.evaluation import bench_input
from appliance.evaluation import benchmark as bm
from processing.chain import ChainParameters


def _positive_finite(x: object) -> bool:
    return isinstance(x, float) and math.isfinite(x) and x > 0


REPO = Path(__file__).resolve().parents[1]
#: A shipped speed setting, so that the run below also checks that the file works.
COARSE = REPO / "benchmarks" / "configs" / "coarse-warm-pyramid.yaml"


def test_bench_json_shape(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench.json"
    args = ["bench", "--source", "blob", "--frames", "6", "--runs", "2", "--warmup", "1",
            "--seconds", "1", "--workers-max", "2", "--cache-dir", str(tmp_path / "cache"),
            "--json", str(out), "--config", str(COARSE)]
    assert cli.main(args) == cli.EXIT_OK
    res = json.loads(out.read_text())
    assert res["config"] == str(COARSE)
    assert set(res["stages_ms"]) == set(bm.STAGES)
    assert all(_positive_finite(v) for v in res["stages_ms"].values())
    assert _positive_finite(res["chain_ms"])
    # the chain's total includes every stage
    assert res["chain_ms"] >= 0.99 * sum(res["stages_ms"].values())
    assert set(res["pairs_per_s"]) == {"1", "2"}
    assert all(_positive_finite(v) for v in res["pairs_per_s"].values())
    # per worker, the share of D(t0) found computed (the one worker: its previous triple's)
    assert [len(res["d0_found"][n]) for n in ("1", "2")] == [1, 2]
    assert all(0 <= f <= 1 for n in ("1", "2") for f in res["d0_found"][n])
    assert res["throughput_frames"] == bm.THROUGHPUT_MIN_FRAMES  # --frames 6 is too short
    assert _positive_finite(res["farneback_ms"]) and _positive_finite(res["chain_cpu_ms"])
    assert set(res["ratio_to_farneback"]) == {*bm.STAGES, "chain"}
    assert set(res["cold"]["stages_ms"]) == set(bm.STAGES)
    assert res["cold"]["chain_ms"] >= 0.99 * sum(res["cold"]["stages_ms"].values())
    # the same warm triples once more with the active region off
    full = res["no_active_region"]
    assert set(full["stages_ms"]) == set(bm.STAGES)
    assert all(_positive_finite(v) for v in full["stages_ms"].values())
    assert full["chain_ms"] >= 0.99 * sum(full["stages_ms"].values())
    assert set(full["ratio_to_farneback"]) == {*bm.STAGES, "chain"}
    region = res["active_region"]
    assert region["warm_triples"] == 2
    assert 0 <= region["full_frame_triples"] <= 2
    assert 0 < region["solved_share"] <= 1
    if region["full_frame_triples"] < 2:
        assert 0 < region["box_share"] < 1
    assert res["image_size"] == [320, 240]
    floor = res["floor"]
    assert all(_positive_finite(floor[k]) for k in
               ("bytes_per_triple", "cache_bandwidth_gb_s", "dram_bandwidth_gb_s"))
    # a floor is a floor: below the measured chain
    assert floor["cache_floor_ms"] < res["chain_ms"]
    text = capsys.readouterr().out
    assert "disparity" in text and "pairs/s" in text and "load average" in text
    assert "roofline floor" in text and "cold" in text
    assert "no region" in text and "active region:" in text
    # the generated inputs (6 frames; 62 for pairs/s) were cached under --cache-dir
    assert len(list((tmp_path / "cache").glob("blob-*.npz"))) == 2


def test_cache_roundtrip_and_corrupt_file(tmp_path: Path) -> None:
    a = bm.load_frames("blob", n_frames=5, seed=3, cache_dir=tmp_path)
    (path,) = tmp_path.glob("blob-*.npz")
    b = bm.load_frames("blob", n_frames=5, seed=3, cache_dir=tmp_path)
    np.testing.assert_array_equal(a.left, b.left)
    np.testing.assert_array_equal(a.right, b.right)
    assert a.left.dtype == np.uint16 and a.left.shape == (5, 240, 320)
    path.write_bytes(b"garbage")
    c = bm.load_frames("blob", n_frames=5, seed=3, cache_dir=tmp_path)
    np.testing.assert_array_equal(a.left, c.left)
    other = bm.load_frames("blob", n_frames=5, seed=4, cache_dir=tmp_path)
    assert not np.array_equal(a.left, other.left)


def test_triples_consecutive_with_gap_at_wrap() -> None:
    frames = bm.blob_frames(n_frames=4)
    it = bm.iter_triples(frames)
    t = [next(it)[2] for _ in range(4)]
    assert t[1][:2] == t[0][1:]  # consecutive: warm start
    assert t[2][0] > t[1][2] and t[2][:2] != t[1][1:]  # wrap: a gap, cold start
    assert all(a < b < c for a, b, c in t)


@pytest.mark.parametrize("change", [
    ["--seconds", "0"], ["--runs", "0"], ["--workers-max", "0"], ["--frames", "3"],
    ["--warmup", "0"], ["--seconds", "nan"], ["--size", "800x600"], ["--size", "640"],
])
def test_bad_options_exit_2(change: list[str], tmp_path: Path) -> None:
    assert cli.main(["bench", "--cache-dir", str(tmp_path), *change]) == cli.EXIT_USAGE


def test_a_wrong_configuration_key_exits_2_before_any_input_is_made(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "site.yaml"
    config.write_text("processing:\n  parameters:\n    warm_flow_option: {n_levels: 4}\n")
    cache = tmp_path / "cache"
    assert cli.main(["bench", "--cache-dir", str(cache), "--config", str(config)]) \
        == cli.EXIT_USAGE
    assert "warm_flow_option" in capsys.readouterr().err
    assert not cache.exists()


def test_the_throughput_workers_run_the_given_parameters() -> None:
    frames = bm.load_frames("blob", n_frames=6)
    # A block size that does not divide 320x240 fails in the chain, so only a worker that
    # runs these parameters fails.
    with pytest.raises(RuntimeError, match="bench worker failed"):
        bm.measure_throughput(frames, 1, seconds=0.2, warmup=1,
                              params=ChainParameters(binning=3))
    assert bm.measure_throughput(frames, 1, seconds=0.2, warmup=1).triples >= 1


def test_field_preset_matches_bench_geometry() -> None:
    cfg = bench_input._field_config(n_frames=4, seed=7)
    cam = cfg.effective_camera()
    geo = bm.geometry()
    assert (cam.width, cam.height) == geo.image_size
    assert cam.s_px == geo.camera_constant and cam.b_m == geo.baseline
    assert (cam.cx, cam.cy) == geo.principal_point
    assert cfg.frame_interval_s == pytest.approx(1 / bm.FRAME_RATE_HZ)
    assert cfg.options.noise_netd_k > 0  # realistic: NETD-like noise on


def test_unwritable_cache_dir_still_gives_frames(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    frames = bm.load_frames("blob", n_frames=4, cache_dir=blocker / "cache")
    assert frames.left.shape == (4, 240, 320)
    assert "not cached" in capsys.readouterr().err


def test_solved_share_of_a_region() -> None:
    class Result:
        valid = np.zeros((240, 320), dtype=bool)
        region: tuple[int, int, int, int] | None = (20, 140, 40, 200)  # 120 x 160 px

    r = Result()
    assert bm._solved_share(r) == pytest.approx(120 * 160 / (240 * 320))
    r.region = None  # the whole frame
    assert bm._solved_share(r) == 1.0


def test_warm_times_report_the_region() -> None:
    """Warm calls through the real chain: the box shares add up with the whole-frame calls."""
    frames = bm.blob_frames(n_frames=6)
    st = bm.measure_stages(frames, ChainParameters(active_region=True), runs=2, warmup=1)
    for t in (st.warm, st.times("warm_full")):
        assert 0 <= t.full_frame_calls <= t.runs == 2
    # with the active region off every warm triple solves the whole frame
    assert st.times("warm_full").full_frame_calls == 2
    assert st.times("warm_full").solved_share == 1.0
    assert st.times("warm_full").box_share is None
    no_region = bm.measure_stages(frames, ChainParameters(active_region=False), runs=1,
                                  warmup=1)
    assert no_region.warm_full is None
    with pytest.raises(ValueError, match="warm_full"):
        no_region.times("warm_full")


@pytest.mark.parametrize("stride", [1, 2])
def test_the_pairs_per_s_input_starts_cold_as_often_as_the_daemon(stride: int) -> None:
    """On THROUGHPUT_MIN_FRAMES cycled frames a worker taking every ``stride``-th triple
    starts cold once in ``cold_every`` of its own triples, as the daemon's workers do; on
    16 frames two workers started cold twice as often as one."""
    import numpy as np

    from processing.chain import ChainParameters, ChainState

    cold_every = ChainParameters().cold_every

    def cold_share(n_frames: int) -> float:
        stack = np.zeros((n_frames, 240, 320), np.uint16)  # only the times matter here
        frames = bm.BenchFrames(left=stack, right=stack,
                                times_s=np.arange(n_frames) / bm.FRAME_RATE_HZ, source="blob")
        triples = bm.iter_triples(frames)
        state = ChainState(stride=stride)
        field = np.zeros((1, 1), np.float32)
        cold = total = 0
        for _ in range(20 * n_frames):
            _, _, times = next(triples)
            for _ in range(stride - 1):
                next(triples)
            cold += state.warm_start(times, True, cold_every) is None
            total += 1
            state.previous_flow, state.previous_disparity = np.zeros((1, 1, 2)), field
            state.previous_change, state.previous_times = field, times
        return cold / total

    assert cold_share(bm.THROUGHPUT_MIN_FRAMES) == pytest.approx(1 / cold_every, rel=0.05)
    assert cold_share(16) == pytest.approx(stride / 14, rel=0.05)


@pytest.mark.parametrize("path", sorted((REPO / "benchmarks" / "configs").glob("*.yaml")),
                         ids=lambda p: p.name)
def test_every_benchmark_configuration_loads_and_gives_chain_parameters(path: Path) -> None:
    """The configurations the docs' figures name are valid as `ogiflow run --config` takes
    them: no misspelt key, parameters the chain accepts."""
    params = load_config(path).processing.chain_parameters()
    assert isinstance(params, ChainParameters)
