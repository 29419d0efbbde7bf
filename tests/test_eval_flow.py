"""``ogiflow eval flow`` end to end on a small Middlebury-layout dataset made here."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from appliance import cli
from processing.metrics.flo import write_flo
from tests.flow_helpers import pair_with_flow, texture


def _make_sequence(folder: Path, shift: float, seed: int) -> None:
    folder.mkdir(parents=True)
    img1 = texture((64, 80), seed=seed)
    gt = np.zeros((64, 80, 2), np.float32)
    gt[..., 0] = shift
    img0 = pair_with_flow(img1, gt)
    cv2.imwrite(str(folder / "frame10.png"), np.rint(img0 * 255).astype(np.uint8))
    cv2.imwrite(str(folder / "frame11.png"), np.rint(img1 * 255).astype(np.uint8))
    gt[0, 0] = 1e10  # one unknown pixel, excluded from the AEE
    write_flo(folder / "flow10.flo", gt)


def test_eval_flow_writes_the_documented_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _make_sequence(tmp_path / "data" / "SeqA", 1.0, seed=1)
    _make_sequence(tmp_path / "data" / "SeqB", -0.5, seed=2)
    (tmp_path / "data" / "not_a_sequence").mkdir()
    out = tmp_path / "r.json"
    code = cli.main(
        ["eval", "flow", "--dataset", str(tmp_path / "data"), "--json", str(out), "--repeats", "1"]
    )
    assert code == 0
    result = json.loads(out.read_text())
    assert set(result) == {"SeqA", "SeqB"}
    for seq in result.values():
        assert set(seq) == {"brox(alpha=0.05,beta=0.1)", "farneback", "dis_medium"}
        for scores in seq.values():
            assert set(scores) == {"aee", "ms"}
            assert np.isfinite(scores["aee"]) and scores["ms"] > 0
        assert seq["brox(alpha=0.05,beta=0.1)"]["aee"] < 0.2
    assert "dis_medium" in capsys.readouterr().out


def test_eval_flow_grid_runs_every_table1_cell(tmp_path: Path) -> None:
    _make_sequence(tmp_path / "data" / "S", 0.5, seed=3)
    out = tmp_path / "g.json"
    assert (
        cli.main(
            [
                "eval",
                "flow",
                "--dataset",
                str(tmp_path / "data"),
                "--grid",
                "--repeats",
                "1",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    methods = json.loads(out.read_text())["S"]
    # the 12 cells of Table 1 plus the requested (alpha, beta)
    assert sum(m.startswith("brox(") for m in methods) == 13
    assert "brox(alpha=0.01,beta=0.01)" in methods


def test_missing_dataset_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["eval", "flow", "--dataset", str(tmp_path / "nope")]) == cli.EXIT_USAGE
    assert "does not exist" in capsys.readouterr().err


def test_corrupt_ground_truth_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _make_sequence(tmp_path / "d" / "S", 0.5, seed=4)
    (tmp_path / "d" / "S" / "flow10.flo").write_bytes(b"JUNKJUNKJUNK")
    assert cli.main(["eval", "flow", "--dataset", str(tmp_path / "d")]) == cli.EXIT_USAGE
    assert "not a .flo file" in capsys.readouterr().err
