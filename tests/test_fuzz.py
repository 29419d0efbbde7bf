"""Untrusted input, fuzzed: MCAP files (recover, the reader behind replay and export, the
export command), configuration YAML and calibration files.

Every mutated input must give a clear error (``ValueError``/``OSError``, exit code 1 or 2 from
the CLI) or a counted skip - never a hang, a huge allocation or a traceback. Hypothesis runs
a fixed number of examples from a fixed seed (``derandomize``), so CI is deterministic and
bounded; pytest-timeout catches a hang.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from appliance import cli
from appliance.config import ConfigError, load_config
from appliance.recording import schemas as S
from appliance.recording.reader import LogReader
from appliance.recording.recovery import recover

FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@pytest.fixture(scope="module")
def mcap_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A small but complete recording: frames, JSON messages, metadata, several chunks."""
    import dataclasses

    import numpy as np

    from appliance.config import RecordingConfig
    from appliance.recording.recorder import Recorder, closed_files

    d = tmp_path_factory.mktemp("mcap")
    rc = dataclasses.replace(RecordingConfig(), dir=d, quota_gb=None, chunk_kb=16)
    with Recorder(rc, {"config": {"yaml": "a: 1"}}) as rec:
        for i in range(12):
            field = np.random.default_rng(i).normal(size=(24, 32, 2)).astype(np.float32)
            rec.record("/sceneflow/flow", S.GRID, S.grid(field, i, "camera_left", ("u", "v")), i)
            rec.record("/sceneflow/summary", S.SCENEFLOW_SUMMARY, S.encode_json(
                S.SCENEFLOW_SUMMARY, {"t_mono_ns": i, "t_wall_ns": i, "pair_index": i,
                                      "gas_pixels": 0, "mean_velocity_m_s": None,
                                      "speed_m_s": None, "angles_deg": None, "c_usf": None,
                                      "latency_ms": None, "skipped_pairs": 0, "valid": False,
                                      "flags": []}, validate=False), i)
    (path,) = closed_files(d)
    return path.read_bytes()


@st.composite
def mutated(draw: st.DrawFn, data: bytes) -> bytes:
    """Truncation, bit flips, and huge declared record lengths."""
    buf = bytearray(data)
    kind = draw(st.sampled_from(["truncate", "flip", "length", "all"]))
    if kind in ("flip", "all"):
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(buf) - 1))
            buf[i] ^= 1 << draw(st.integers(0, 7))
    if kind in ("length", "all"):
        # Record heads are opcode (1 byte) + length (uint64): claim an absurd length.
        i = draw(st.integers(8, max(8, len(buf) - 9)))
        buf[i + 1:i + 9] = struct.pack("<Q", draw(st.sampled_from(
            [2**63 - 1, 2**64 - 1, 2**40, len(buf) * 10])))
    if kind in ("truncate", "all"):
        buf = buf[:draw(st.integers(0, len(buf)))]
    return bytes(buf)


def _write(tmp_path: Path, data: bytes, name: str = "x.mcap") -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_recover_reader_and_export_survive_mutated_mcap(
        mcap_bytes: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = {"runs": 0, "recovered": 0, "clear_errors": 0}

    @FUZZ
    @given(data=mutated(mcap_bytes))
    def check(data: bytes) -> None:
        n["runs"] += 1
        src = _write(tmp_path, data)
        out = tmp_path / "out.mcap"
        try:
            report = recover(src, out, overwrite=True)
            n["recovered"] += 1
            assert report.messages_kept <= 24
        except ValueError:
            n["clear_errors"] += 1
        try:
            msgs = list(LogReader(src))  # what replay and export read with
            assert len(msgs) <= 24
        except ValueError:
            pass
        code = cli.main(["export", str(src), "--to", "csv", "--out", str(tmp_path / "e")])
        assert code in (0, 1, 2)

    check()
    capsys.readouterr()
    print(f"MCAP fuzzing: {n}")
    assert n["runs"] >= 100 and n["recovered"] > 0


CONFIG_KEYS = ["cameras.left.backend", "cameras.right.options", "anemometer.protocol",
               "anemometer.port", "recording.rotate_mb", "recording.dir", "live.mode",
               "live.grpc_port", "ring.capacity", "processing.parameters", "calibration",
               "pairing.tolerance_s", "health", "simulation.voxel_m", "nonsense"]
YAML_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=True)
    | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=3),
    max_leaves=8)


@FUZZ
@given(overrides=st.lists(st.tuples(st.sampled_from(CONFIG_KEYS), YAML_VALUES), max_size=5))
def test_config_values_fuzzed_give_config_errors(overrides: list) -> None:
    try:
        load_config(None, overrides)
    except ConfigError as exc:
        assert exc.errors and all(":" in e for e in exc.errors)


@FUZZ
@given(text=st.text(max_size=200) | st.binary(max_size=200).map(
    lambda b: b.decode("latin-1")))
def test_config_file_text_fuzzed(text: str, tmp_path_factory: pytest.TempPathFactory) -> None:
    p = tmp_path_factory.getbasetemp() / "fuzz-site.yaml"
    p.write_text(text, encoding="utf-8")
    try:
        load_config(p)
    except ValueError as exc:  # ConfigError or malformed YAML, naming the file
        assert str(p) in str(exc) or "config" in str(exc)


@pytest.fixture(scope="module")
def calibration_text(tmp_path_factory: pytest.TempPathFactory) -> str:
    from processing.calibration import ideal_calibration, save_calibration

    p = tmp_path_factory.mktemp("cal") / "stereo.yaml"
    save_calibration(p, ideal_calibration(400.0, 0.25))
    return p.read_text()


def test_calibration_files_fuzzed(calibration_text: str, tmp_path: Path) -> None:
    from processing.calibration import load_calibration

    data = yaml.safe_load(calibration_text)
    keys = sorted(data)
    n = {"runs": 0, "rejected": 0}

    @FUZZ
    @given(key=st.sampled_from(keys), value=YAML_VALUES,
           cut=st.integers(0, len(calibration_text)), mode=st.sampled_from(["value", "cut"]))
    def check(key: str, value: object, cut: int, mode: str) -> None:
        n["runs"] += 1
        p = tmp_path / "cal.yaml"
        if mode == "value":
            p.write_text(yaml.safe_dump({**data, key: value}))
        else:
            p.write_text(calibration_text[:cut])
        try:
            load_calibration(p)
        except (ValueError, OSError):
            n["rejected"] += 1

    check()
    print(f"calibration fuzzing: {n}")
    assert n["runs"] >= 100 and n["rejected"] > 0
