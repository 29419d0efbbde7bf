"""The flow-level benchmark (benchmarks/bench_flow_level.py) times both solvers at both sizes."""

from __future__ import annotations

import re

import pytest

from benchmarks import bench_flow_level


def test_bench_flow_level_reports_both_solvers_at_both_sizes(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert bench_flow_level.main(["--runs", "1"]) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"(\d+)x(\d+): the chain's level\s+([\d.]+) ms, OpenCV "
                      r"VariationalRefinement\s+([\d.]+) ms, ratio\s+([\d.]+)", out)
    assert [(int(w), int(h)) for w, h, *_ in rows] == [(w, h) for h, w in
                                                      bench_flow_level.SIZES]
    for _, _, ours, theirs, ratio in rows:
        assert float(ours) > 0 and float(theirs) > 0
        assert float(ratio) == pytest.approx(float(ours) / float(theirs), rel=0.02)


def test_bench_flow_level_refuses_no_runs() -> None:
    with pytest.raises(SystemExit):
        bench_flow_level.main(["--runs", "0"])
