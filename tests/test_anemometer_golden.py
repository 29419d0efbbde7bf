"""Golden tests on real captures (gpsd style: each capture sits beside its expected output).

Regenerate an expected file only after checking the change by hand:
``ogiflow wind decode --protocol P CAPTURE --json CAPTURE.expected.json``.
"""

from __future__ import annotations

import functools
import json
import math
import operator
import re
from pathlib import Path

import pytest

from appliance.commands.wind_decode import decode_file

DATA = Path(__file__).parent / "data" / "anemometer"
CSAT_RAW = DATA / "campbell_csat3b" / "csat3b_ascii_dsm5_id60_raw_stream.txt"
CSAT_TSV = DATA / "campbell_csat3b" / "csat3b_ascii_dsm5_id60_timestamped.tsv"
GILL_LOG = DATA / "gill_windobserver" / "NBP1406_mwx1-2014-08-01.part1"


@pytest.mark.parametrize(
    ("capture", "protocol"), [(CSAT_RAW, "campbell_csat3b"), (GILL_LOG, "gill")]
)
def test_capture_decodes_to_its_expected_output(capture: Path, protocol: str) -> None:
    expected = json.loads(Path(f"{capture}.expected.json").read_text())
    counts, samples = decode_file(protocol, capture)
    assert counts == expected["counts"]
    assert samples == expected["samples"]


def test_every_csat3b_line_verifies_and_decodes_to_the_logged_values() -> None:
    lines = CSAT_RAW.read_bytes().splitlines()
    counts, samples = decode_file("campbell_csat3b", CSAT_RAW)
    assert len(lines) == 2999
    assert counts["valid"] == counts["messages"] == len(lines)
    assert counts["checksum_failures"] == counts["malformed"] == counts["counter_gaps"] == 0
    for line, s in zip(lines, samples, strict=True):
        ux, uy, uz, ts, diag, counter, _sig = line.decode().split(",")
        assert (s["u"], s["v"], s["w"], s["sonic_temperature"]) == tuple(
            map(float, (ux, uy, uz, ts))
        )
        assert (s["status_code"], s["counter"]) == (int(diag), int(counter))
        assert s["speed_of_sound"] == pytest.approx(math.sqrt(403 * (float(ts) + 273.15)))


def test_timestamped_csat3b_gives_the_same_samples_as_the_raw_stream() -> None:
    counts, samples = decode_file("campbell_csat3b", CSAT_TSV)
    _, raw = decode_file("campbell_csat3b", CSAT_RAW)
    assert samples == raw
    # The header comment is the only line that is not a record; the logger's receive time
    # in front of each record is skipped.
    assert counts["malformed"] == 1 and counts["valid"] == 2999
    assert counts["checksum_failures"] == 0 and counts["resyncs"] == 0


def test_every_gill_frame_of_the_ship_log_verifies() -> None:
    text = GILL_LOG.read_bytes()
    frames = re.findall(rb"\x02([^\x03]*)\x03([0-9A-F]{2})", text)
    tags = re.findall(rb"^\S+ (PUS|SUS|MET),", text, flags=re.M)
    assert len(frames) == tags.count(b"PUS") + tags.count(b"SUS") == 958
    for payload, check in frames:  # independent XOR, byte by byte
        assert functools.reduce(operator.xor, payload, 0) == int(check, 16)
    counts, samples = decode_file("gill", GILL_LOG)
    assert counts["valid"] == counts["messages"] == 958
    assert counts["checksum_failures"] == counts["malformed"] == counts["resyncs"] == 0
    for (payload, _), s in zip(frames, samples, strict=True):
        _node, direction, speed, units, sos, ts, status = payload.decode().rstrip(",").split(",")
        assert units == "M"
        assert math.hypot(s["u"], s["v"]) == pytest.approx(float(speed), abs=1e-9)
        if float(speed) > 0:
            # Direction the wind comes from, clockwise from the mark: u = -S cos d, v = S sin d.
            got = math.degrees(math.atan2(s["v"], -s["u"])) % 360
            assert got == pytest.approx(float(direction) % 360, abs=1e-6)
        assert s["w"] is None  # 2-D sensor
        assert (s["speed_of_sound"], s["sonic_temperature"]) == (float(sos), float(ts))
        assert s["status_code"] == int(status, 16) and s["valid"]
