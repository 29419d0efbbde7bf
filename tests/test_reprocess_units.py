"""Reprocessing without Ray: segmenting, sweeps, inputs, replay's guarantees, Parquet export."""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from appliance import cli
from appliance.recording.reader import LogReader
from appliance.reprocess.jobs import expand_inputs, parameter_grid, split_values
from appliance.reprocess.segments import cut_segments
from tests.recording_helpers import cut_recording, interrupt_cli, write_recording


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 400_000_000), min_size=0, max_size=60),
       st.floats(0.05, 3.0))
def test_every_pair_and_triple_belongs_to_exactly_one_segment(gaps: list[int],
                                                               segment_s: float) -> None:
    times = np.cumsum([10**9, *gaps]).tolist()
    segments = cut_segments(times, segment_s)
    n = len(times)
    pairs = [i for s in segments for i in range(s.first, s.stop)]
    triples = [k for s in segments for k in s.triples(n)]
    assert pairs == list(range(n))
    assert triples == list(range(max(0, n - 2)))
    for s in segments:  # a segment spans less than segment_s of recording
        assert times[s.stop - 1] - times[s.first] < segment_s * 1e9


def test_no_segmenting_is_one_segment() -> None:
    assert len(cut_segments([1, 2, 3, 4], None)) == 1
    with pytest.raises(ValueError, match="segment-s"):
        cut_segments([1, 2, 3], 0.0)


def test_parameter_sweep_is_the_product_of_the_value_lists() -> None:
    grid = parameter_grid(["alpha=0.05,0.1", "nu=0.5", "flow_options={n_sor: 4, n_inner: 2}"])
    assert grid == [{"alpha": 0.05, "nu": 0.5, "flow_options": {"n_sor": 4, "n_inner": 2}},
                    {"alpha": 0.1, "nu": 0.5, "flow_options": {"n_sor": 4, "n_inner": 2}}]
    assert split_values("[1, 2],'a,b',3") == ["[1, 2]", "'a,b'", "3"]
    assert parameter_grid([]) == [{}]
    with pytest.raises(ValueError, match="KEY=VALUE"):
        parameter_grid(["alpha"])


def test_inputs_are_files_folders_and_globs(tmp_path: Path) -> None:
    a = tmp_path / "site1" / "day1" / "a.mcap"
    b = tmp_path / "site2" / "b.mcap.active"
    out = tmp_path / "site1" / "out" / "done.mcap"
    for p in (a, b, out):
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    (tmp_path / "site1" / "notes.txt").write_text("no")
    assert expand_inputs([str(tmp_path)], exclude=out.parent) == [a, b]
    assert expand_inputs([str(tmp_path / "*" / "**" / "*.mcap")]) == [a, out]
    assert expand_inputs([str(a), str(a)]) == [a]
    assert expand_inputs([str(tmp_path / "site*") + "/"], exclude=out.parent) == [a, b]
    with pytest.raises(ValueError, match="no MCAP"):
        expand_inputs([str(tmp_path / "missing")])


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("rec") / "rec.mcap", 60)


def test_replay_with_segments_restarts_cold_at_borders(recording: Path, tmp_path: Path) -> None:
    from appliance.reprocess.segments import Segment, run_segments
    from appliance.reprocess.source import Recording
    from tests.recording_helpers import GEOMETRY, PARAMS

    class Collect:
        def __init__(self) -> None:
            self.results: list = []
            self.window_restarts: list[int] = []  # results before each restart

        def record_pair(self, index: int, pair: object) -> None:
            pass

        def publish(self, res: object, fields: bool) -> None:
            self.results.append(res)

        def restart_rate_window(self) -> None:
            self.window_restarts.append(len(self.results))

    rec = Recording.open(recording)
    one, two = Collect(), Collect()
    run_segments(rec, GEOMETRY, PARAMS, [Segment(0, 0, 58)], one)
    run_segments(rec, GEOMETRY, PARAMS, [Segment(0, 0, 20), Segment(1, 20, 58)], two)
    assert [r.pair_indices for r in one.results] == [r.pair_indices for r in two.results]
    scale = [r.diff_scale for r in one.results], [r.diff_scale for r in two.results]
    assert scale[0][:20] == scale[1][:20]  # same state before the border
    assert scale[0][20] != scale[1][20]  # a fresh normalisation scale after it
    # ... and a fresh emission-rate window, as a Ray task running the segment alone has
    assert one.window_restarts == [0] and two.window_restarts == [0, 20]


def test_replay_writes_parquet_through_export(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    assert cli.main(["replay", str(recording), "--fast", "--out", str(out),
                     "--fields-every", "7"]) == 0
    counts = Counter(t for t, *_ in LogReader(out))
    # 60 frames a camera, the first of each stamped from its arrival alone and not paired:
    # 59 pairs, 57 triples
    assert counts["/sceneflow/summary"] == 57 and counts["/pairs"] == 59
    assert counts["/sceneflow/velocity"] == 8  # triples 6, 13, ..., 55
    assert cli.main(["export", str(out), "--to", "parquet", "--out", str(tmp_path / "x")]) == 0
    table = pq.read_table(tmp_path / "x_summary.parquet")
    assert table.num_rows == 57
    assert {"time", "vx_m_s", "angle_z_deg", "c_usf", "gas_pixels"} <= set(table.column_names)
    assert str(table.schema.field("time").type) == "timestamp[ns, tz=UTC]"
    assert pq.read_table(tmp_path / "x_wind.parquet").num_rows == counts["/wind/camera"] + 40


def test_replay_of_a_recording_cut_by_kill_9_warns_and_keeps_everything_before(
        recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cut = cut_recording(recording, tmp_path / "cut.mcap", 0.6)
    out = tmp_path / "cut-replay.mcap"
    assert cli.main(["replay", str(cut), "--fast", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "ends early" in err
    n = Counter(t for t, *_ in LogReader(out))
    assert 10 < n["/sceneflow/summary"] == n["/pairs"] - 2 < 58


def test_replay_ctrl_c_leaves_a_valid_file_with_what_was_processed(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "long.mcap", 240)  # 8 s at the recorded pace
    out = tmp_path / "out.mcap"
    # Ctrl-C once 100 triples are done (paced, so about 140 remain): waiting a fixed time
    # after the output file appeared left no triple done on a machine under load.
    code, err = interrupt_cli(["replay", str(src), "--out", str(out)],
                              lambda text: "100 triples processed" in text)
    assert code == cli.EXIT_INTERRUPTED, err
    assert "interrupted" in err
    with open(out, "rb") as f:  # finished: summary and index present
        summary = make_reader(f).get_summary()
    assert summary is not None
    n = Counter(t for t, *_ in LogReader(out))
    assert 0 < n["/sceneflow/summary"] < 238
    assert not list(tmp_path.glob("*.part"))


@pytest.mark.parametrize("max_delay_s, given_up", [(1.0, 0), (0.2, 9)])
def test_replay_pairs_late_frames_as_the_live_pairer_did(tmp_path: Path, max_delay_s: float,
                                                         given_up: int) -> None:
    """A busy machine stalled the right camera's thread for 15 frames (0.5 s): the live pairer
    waited for them (pairing.max_delay_s, recorded in the file's configuration), so replay
    must wait as long; with the old fixed 0.2 s it gave the 9 frames older than 0.2 s + half
    a period up as unpaired (the failure seen in the daemon test on a loaded machine).
    The stalled frames arrive above the envelope, so they are stamped from it and pair;
    only each camera's first frame (stamped from its arrival alone) is left out besides."""
    from appliance.reprocess.source import PairStream, Recording

    path = write_recording(tmp_path / "stall.mcap", 40, right_stall=range(10, 25))
    rec = Recording.open(path)
    assert rec.max_delay_s == 1.0  # the default configuration, as recorded
    rec = dataclasses.replace(rec, max_delay_s=max_delay_s)
    stream = PairStream(rec)
    pairs = [pair for _, pair in stream]
    unpaired = given_up + 1  # and the first frame
    assert stream.unpaired == {"left": unpaired, "right": unpaired}
    assert len(pairs) == 40 - unpaired and pairs[0].left.seq == 1
    assert all(p.left.seq == p.right.seq for p in pairs)
