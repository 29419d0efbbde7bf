"""``ogiflow eval detection`` on clips of real GasVid videos (``data/ogi/gasvid``): one
minute of leak class 0 (5.3 g/h, not visible) and one of class 3 (959 g/h) of the videos at
6.9 m and 9.8 m, one frame per second, with their labels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from appliance import cli

DATA = Path(__file__).resolve().parents[1] / "data" / "ogi" / "gasvid"


def test_one_event_at_the_labelled_source_and_none_before_the_leak_is_visible(
        tmp_path: Path) -> None:
    out = tmp_path / "det.json"
    assert cli.main(["eval", "detection", "--data", str(DATA), "--json", str(out)]) == cli.EXIT_OK
    report = json.loads(out.read_text())
    assert {"1237", "1238"} <= set(report)
    for video in ("1237", "1238"):
        r = report[video]
        labels = json.loads((DATA / video / "labels.json").read_text())
        x, y, w, h = labels["source_box_xywh"]
        events = r["events"]
        assert len(events) == 1, (video, events)
        ev = events[0]
        # alarmed in the class 3 minute (600-659 s), nothing in the class 0 one (20-79 s)
        assert 600 <= ev["alarm_t_s"] <= 659, (video, ev)
        assert np.hypot(ev["source_xy"][0] - (x + w / 2), ev["source_xy"][1] - (y + h / 2)) <= 10
        scored = r["labelled"]
        assert scored["false_events"] == []
        by_class = {c["class"]: c for c in scored["classes"]}
        assert by_class[0]["windows"] > 0 and by_class[0]["windows_alarmed"] == 0
        assert by_class[3]["windows_alarmed"] >= 1
        assert by_class[3]["source_error_px"] <= 10
        assert by_class[3]["apparent_size"] > 0
        # the per-frame list stays as it was: one row per processed triple
        assert len(r["per_frame"]) == 2 * (60 - 2)
