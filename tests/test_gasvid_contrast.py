"""The GasVid contrast analysis (benchmarks/gasvid_contrast.py) on the project's clips and on
made-up frames whose plume direction and contrast are known."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks import gasvid_contrast as gc

CLIPS = Path(__file__).resolve().parents[1] / "data" / "ogi" / "gasvid"


def test_the_clip_reports_its_release_class_only(capsys) -> None:
    assert gc.main([str(CLIPS / "1237")]) == 0
    lines = capsys.readouterr().out.splitlines()
    # The clip holds class 0 and class 3: only class 3 has windows to report.
    assert [ln.split()[1] for ln in lines[1:]] == ["3"]
    assert "958.8 g/h" in lines[1]


def test_a_flickering_patch_up_and_right_of_the_source_points_at_45_degrees() -> None:
    rng = np.random.default_rng(0)
    stack = rng.normal(100.0, 0.5, size=(20, 120, 120)).astype(np.float32)
    stack[:, 30:40, 80:90] += rng.normal(0.0, 20.0, size=(20, 10, 10))  # centre (84.5, 34.5)
    angle = gc.plume_angle_deg(stack, np.full((120, 120), 0.5, np.float32), (60.0, 59.0), 80.0)
    assert abs(angle - 45.0) < 3.0


def test_a_window_with_most_frames_missing_has_no_contrast() -> None:
    frames = {n: np.full((8, 8), n, np.uint8) for n in (0, 1, 2, 9)}
    near = np.ones((8, 8), bool)
    assert gc.window_contrast(frames, 0, 3, near) == 64.0  # |1-0| and |2-1| over 64 px
    assert gc.window_contrast(frames, 3, 10, near) is None


def test_a_folder_without_labels_is_refused(tmp_path: Path, capsys) -> None:
    (tmp_path / "v").mkdir()
    assert gc.main([str(tmp_path / "v")]) == 2
    assert "no labels.json" in capsys.readouterr().err
