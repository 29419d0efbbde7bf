"""benchmarks/stride_cost.py: CPU per warm triple of a worker taking every N-th triple."""

from __future__ import annotations

import pytest

from appliance.evaluation import bench_input as bm
from benchmarks.stride_cost import WARMUP, main, warm_cpu_ms
from processing.chain import ChainParameters


def test_both_strides_time_warm_triples_only() -> None:
    frames = bm.blob_frames(n_frames=12)
    params = ChainParameters()
    # 12 frames = 10 triples per lap, the wrap a cold start: of the timed triples after the
    # warm-up, the ones after a wrap are cold and left out.
    one = warm_cpu_ms(frames, params, 1, 12)
    two = warm_cpu_ms(frames, params, 2, 12)
    assert 0 < len(one) < 12 and 0 < len(two) < 6
    assert all(c > 0 for c in (*one, *two))
    with pytest.raises(ValueError, match="stride"):
        warm_cpu_ms(frames, params, 0, 12)
    assert WARMUP >= 2  # compilation and the first cold start are never timed


def test_the_command_prints_a_line_per_stride(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--source", "blob", "--triples", "4", "--stride", "1", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[0] for ln in lines] == ["stride 1", "stride 2"]
    assert all("warm triple CPU median" in ln for ln in lines)
