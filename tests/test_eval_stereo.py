"""``ogiflow eval stereo`` on the Middlebury tsukuba pair shipped in data/stereo."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from appliance import cli

DATA = Path(__file__).resolve().parent.parent / "data" / "stereo" / "tsukuba"
ARGS = ["eval", "stereo", "--left", str(DATA / "im3.png"), "--right", str(DATA / "im4.png"),
        "--gt", str(DATA / "disp3.pgm"), "--gt-scale", "16"]


def test_tsukuba_both_methods(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "stereo.json"
    assert cli.main([*ARGS, "--json", str(out)]) == cli.EXIT_OK
    res = json.loads(out.read_text())
    assert set(res) == {"variational", "sgbm"}
    var, sgbm = res["variational"], res["sgbm"]
    # Measured 0.48 px / 9.4 % (variational, d0 = 0) and 0.37 px / 20.6 % (SGBM, 85 %
    # valid); bounds leave room for platform differences, not for a broken solver.
    assert var["mae"] < 0.6 and var["bad1"] < 0.13
    assert sgbm["mae"] < 0.6 and sgbm["bad1"] < 0.3 and 0.7 < sgbm["valid"] < 1.0
    text = capsys.readouterr().out
    assert "variational" in text and "sgbm" in text


def test_bad_inputs_exit_2(tmp_path: Path) -> None:
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((20, 30), np.uint8))
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"not a png")
    for change in ({"--right": str(small)}, {"--gt": str(corrupt)},
                   {"--left": str(tmp_path / "missing.png")}, {"--gt-scale": "0"},
                   {"--max-disparity": "50"}):
        args = [*ARGS, "--max-disparity", "64"]
        for key, value in change.items():
            args[args.index(key) + 1] = value
        assert cli.main(args) == cli.EXIT_USAGE, change


def test_all_unknown_ground_truth_is_an_error(tmp_path: Path) -> None:
    gt = tmp_path / "zero.pgm"
    cv2.imwrite(str(gt), np.zeros((288, 384), np.uint8))
    args = list(ARGS)
    args[args.index("--gt") + 1] = str(gt)
    assert cli.main(args) == cli.EXIT_USAGE
