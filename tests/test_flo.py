"""Middlebury .flo reading and writing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from processing.metrics.flo import known_mask, read_flo, write_flo


def test_round_trip(tmp_path: Path) -> None:
    flow = np.random.default_rng(0).normal(size=(5, 7, 2)).astype(np.float32)
    write_flo(tmp_path / "a.flo", flow)
    np.testing.assert_array_equal(read_flo(tmp_path / "a.flo"), flow)


def test_unknown_marker() -> None:
    flow = np.zeros((2, 2, 2), np.float32)
    flow[0, 1, 0] = 1e10
    assert known_mask(flow).tolist() == [[True, False], [True, True]]


def test_reference_file_reads(data_dir: Path) -> None:
    flow = read_flo(data_dir / "middlebury" / "Dimetrodon" / "flow10.flo")
    assert flow.shape == (388, 584, 2)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"PIEH", "too short"),
        (b"XXXX" + np.array([2, 2], "<i4").tobytes() + bytes(32), "not a .flo file"),
        (b"PIEH" + np.array([-1, 2], "<i4").tobytes(), "implausible size"),
        (b"PIEH" + np.array([2, 2], "<i4").tobytes() + bytes(8), "header announces"),
    ],
)
def test_bad_header_is_rejected(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / "bad.flo").write_bytes(content)
    with pytest.raises(ValueError, match=message):
        read_flo(tmp_path / "bad.flo")
