"""``ogiflow wind decode`` end to end."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from appliance import cli
from drivers.anemometer.gill import format_gill_uvw

GILL_LOG = (
    Path(__file__).parent
    / "data"
    / "anemometer"
    / "gill_windobserver"
    / ("NBP1406_mwx1-2014-08-01.part1")
)


def test_decode_prints_counts_and_writes_json_and_csv(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capture = tmp_path / "cap.bin"
    good = format_gill_uvw(1.0, 2.0, -0.5, 340.0, 20.0)
    bad = bytearray(good)
    bad[4] ^= 1
    capture.write_bytes(b"junk " + good + bytes(bad) + format_gill_uvw(0, 0, 0, 340, 20, 0x01))
    out_json, out_csv = tmp_path / "s.json", tmp_path / "s.csv"
    rc = cli.main(
        [
            "wind",
            "decode",
            "--protocol",
            "gill",
            str(capture),
            "--json",
            str(out_json),
            "--csv",
            str(out_csv),
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "checksum failures" in text and "status errors" in text
    doc = json.loads(out_json.read_text())
    assert doc["counts"]["valid"] == 1 and doc["counts"]["checksum_failures"] == 1
    assert doc["counts"]["status_errors"] == 1 and doc["counts"]["skipped_bytes"] == 5
    assert [s["valid"] for s in doc["samples"]] == [True, False]
    assert doc["samples"][0]["u"] == 1.0
    rows = list(csv.DictReader(out_csv.open()))
    assert rows[0]["w"] == "-0.5" and rows[1]["status_text"] == "axis 1 failed"


def test_decode_wrong_protocol_fails_and_missing_file_is_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["wind", "decode", "--protocol", "campbell_csat3b", str(GILL_LOG)]) == 1
    assert "wrong --protocol" in capsys.readouterr().err
    assert cli.main(["wind", "decode", "--protocol", "gill", str(tmp_path / "nope")]) == 2
