"""``ogiflow eval footage`` end to end on a tiny synthetic image set, and its error paths."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from appliance import cli
from appliance.evaluation.footage import consecutive_runs


def _write_set(folder: Path, numbers: list[int], *, seed: int = 0) -> None:
    """8-bit frames of a static textured background with a moving bright blob."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    background = cv2.GaussianBlur(rng.uniform(60, 120, (48, 64)).astype(np.float32), (0, 0), 2)
    y, x = np.mgrid[0:48, 0:64]
    for n in numbers:
        blob = 30.0 * np.exp(-((x - 20 - 1.5 * n) ** 2 + (y - 24) ** 2) / 40.0)
        frame = np.clip(background + blob + rng.normal(0, 0.5, (48, 64)), 0, 255)
        cv2.imwrite(str(folder / f"test.frame{n}.png"), frame.astype(np.uint8))


def test_consecutive_runs() -> None:
    assert consecutive_runs([0, 1, 2, 5, 6, 9]) == [(0, 2), (5, 6), (9, 9)]
    assert consecutive_runs([]) == []


def test_reports_consecutive_triples_json_and_figure(tmp_path: Path) -> None:
    _write_set(tmp_path / "data" / "leak_set", [0, 1, 2, 3, 7, 8, 9])
    _write_set(tmp_path / "data" / "other", [4, 5])
    out = tmp_path / "out.json"
    fig = tmp_path / "fig.png"
    code = cli.main(
        [
            "eval", "footage", "--data", str(tmp_path / "data"), "--scale", "10",
            "--json", str(out), "--figure", str(fig),
        ]
    )  # fmt: skip
    assert code == 0
    rep = json.loads(out.read_text())
    leak = rep["sets"]["leak_set"]
    assert leak["runs"] == [[0, 3], [7, 9]]
    assert [e["frame"] for e in leak["frames"]] == [0, 1, 7]
    for e in leak["frames"]:
        assert 0.0 <= e["gas_fraction"] <= 1.0
    assert rep["sets"]["other"]["triples_used"] == 0
    assert rep["sets"]["other"]["gas_fraction"]["mean"] is None
    image = cv2.imread(str(fig))
    assert image is not None and image.shape[1] == 4 * (64 + 2)


def test_bad_data_folder_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["eval", "footage", "--data", str(tmp_path / "missing")]) == 2
    assert "not a directory" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli.main(["eval", "footage", "--data", str(tmp_path)]) == 2
    assert "no image sets" in capsys.readouterr().err


def test_corrupt_image_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _write_set(tmp_path / "s", [0, 1])
    (tmp_path / "s" / "x.frame2.png").write_bytes(b"not a png")
    assert cli.main(["eval", "footage", "--data", str(tmp_path)]) == 2
    assert "cannot read image" in capsys.readouterr().err


def test_bad_scale_exits_2(tmp_path: Path) -> None:
    _write_set(tmp_path / "s", [0, 1, 2])
    assert cli.main(["eval", "footage", "--data", str(tmp_path), "--scale", "0"]) == 2
