"""``ogiflow eval detection`` on folder sets: a drifting plume from a fixed source vs noise."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from appliance import cli

N_FRAMES = 100


def _write_set(folder: Path, plume: bool, seed: int) -> None:
    """8-bit frames: a textured static background with noise, plus (optionally) gas puffs
    released every 3 frames at (60, 120) and drifting right at 2 px/frame, darkening it."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:240, 0:320].astype(np.float32)
    background = 120 + 20 * np.sin(x / 17.0) * np.cos(y / 23.0)
    for k in range(N_FRAMES):
        img = background + rng.normal(0, 1.0, background.shape)
        if plume:
            for born in (b for b in range(0, k + 1, 3) if b >= k - 80):
                cx = 60 + 2.0 * (k - born)
                sigma = 6 + 0.15 * (k - born)
                img -= 12 * np.exp(-((x - cx) ** 2 + (y - 120) ** 2) / (2 * sigma**2))
        cv2.imwrite(str(folder / f"set.frame{k}.png"), np.clip(img, 0, 255).astype(np.uint8))


def test_detection_finds_the_plume_and_nothing_in_noise(tmp_path: Path) -> None:
    _write_set(tmp_path / "data" / "plume", True, 0)
    _write_set(tmp_path / "data" / "quiet", False, 1)
    out = tmp_path / "det.json"
    assert cli.main(["eval", "detection", "--data", str(tmp_path / "data"), "--json",
                     str(out), "--min-duration-s", "1.0"]) == cli.EXIT_OK
    report = json.loads(out.read_text())
    assert report["quiet"]["events"] == []
    events = report["plume"]["events"]
    assert len(events) == 1, report["plume"]["per_frame"][:10]
    ev = events[0]
    assert ev["start_frame"] <= 5 and ev["end_frame"] >= N_FRAMES - 10  # back-dated start
    assert abs(ev["source_xy"][0] - 60) < 25 and abs(ev["source_xy"][1] - 120) < 15
    assert report["plume"]["frames"] == N_FRAMES
    assert report["plume"]["gas_frames"] > report["quiet"]["gas_frames"]


def test_detection_bad_data_exits_2(tmp_path: Path) -> None:
    assert cli.main(["eval", "detection", "--data", str(tmp_path / "missing")]) == cli.EXIT_USAGE
    (tmp_path / "empty").mkdir()
    assert cli.main(["eval", "detection", "--data", str(tmp_path / "empty")]) == cli.EXIT_USAGE
