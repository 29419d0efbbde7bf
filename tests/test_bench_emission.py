"""The emission-rate benchmark (benchmarks/bench_emission.py) runs and reports its figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_emission


def test_bench_emission_times_the_rates_after_the_stack_fills(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "emission.json"
    assert bench_emission.main(["--source", "blob", "--triples", "4", "--rates", "5",
                                "--cache-dir", str(tmp_path), "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["rates"] == 5 and 0 <= figures["rates_defined"] <= 5
    assert 0 < figures["rate_median_ms"] <= figures["rate_max_ms"]
    assert figures["farneback_ms"] > 0
    assert figures["ratio_to_farneback"] == pytest.approx(
        figures["rate_median_ms"] / figures["farneback_ms"])
    assert "emission rate per triple, 5 rates" in capsys.readouterr().out


def test_bench_emission_refuses_no_rates() -> None:
    with pytest.raises(SystemExit):
        bench_emission.main(["--rates", "0"])
