"""Configuration: defaults, the shipped files, every kind of error, overrides."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
import yaml

from appliance import config as C

ROOT = Path(__file__).resolve().parents[1]


def _errors(data: object) -> list[str]:
    with pytest.raises(C.ConfigError) as exc:
        C.validate_config(data, "site.yaml")
    return exc.value.errors


def test_default_file_equals_builtin_defaults() -> None:
    assert C.load_config(ROOT / "config" / "default.yaml") == C.Config()
    assert C.load_config(None) == C.Config()


def test_site_example_is_valid_apart_from_its_calibration_path(tmp_path: Path) -> None:
    from processing.calibration import ideal_calibration, save_calibration

    cal = tmp_path / "stereo.yaml"
    save_calibration(cal, ideal_calibration(400.0, 0.25))
    cfg = C.load_config(ROOT / "config" / "site.example.yaml", [("calibration", str(cal))])
    assert cfg.anemometer.backend == "serial"
    assert cfg.cameras.left.options == {"serial": "LEFT-SERIAL"}
    assert cfg.calibration == cal


@pytest.mark.parametrize("path", sorted((ROOT / "benchmarks" / "configs").glob("*.yaml")),
                         ids=lambda p: p.name)
def test_benchmark_configurations_load_as_ogiflow_run_loads_them(path: Path) -> None:
    """Every file the docs pass to `--config` is a valid configuration whose chain
    parameters differ from the defaults."""
    cfg = C.load_config(path)
    assert cfg.processing.chain_parameters() != C.Config().processing.chain_parameters()


def test_site_example_documents_every_key() -> None:
    """Every key of the full config appears in the example with a comment above it."""
    text = (ROOT / "config" / "site.example.yaml").read_text()
    data = yaml.safe_load(text)

    def walk(full: dict, got: dict, prefix: str) -> None:
        for key, value in full.items():
            assert key in got, f"site.example.yaml lacks {prefix}{key}"
            if isinstance(value, dict) and key not in ("options", "parameters"):
                walk(value, got[key], f"{prefix}{key}.")

    walk(C.config_to_dict(C.Config()), data, "")


def test_partial_file_merges_with_defaults(tmp_path: Path) -> None:
    f = tmp_path / "site.yaml"
    f.write_text("recording:\n  rotate_mb: 200\nlive:\n  mode: off\n")
    cfg = C.load_config(f)
    assert cfg.recording.rotate_mb == 200.0
    assert isinstance(cfg.recording.rotate_mb, float)
    assert cfg.live.mode == "off"  # YAML 1.1 reads bare `off` as false: still the mode
    assert cfg.recording.rotate_s == C.RecordingConfig().rotate_s
    assert cfg.cameras == C.CamerasConfig()


def test_empty_file_is_the_defaults(tmp_path: Path) -> None:
    f = tmp_path / "empty.yaml"
    f.write_text("# nothing\n")
    assert C.load_config(f) == C.Config()


def test_unknown_key_suggests_close_match() -> None:
    errs = _errors({"recording": {"rotat_mb": 3}})
    assert errs == ["recording.rotat_mb: unknown key (did you mean 'rotate_mb'?)"]


def test_unknown_top_level_key_lists_known_keys() -> None:
    (err,) = _errors({"zzz": 1})
    assert err.startswith("zzz: unknown key (known keys: cameras, anemometer")


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"ring": {"capacity": "many"}}, "ring.capacity: expected an integer, got 'many'"),
        ({"ring": {"capacity": 3.5}}, "ring.capacity: expected an integer, got 3.5"),
        ({"ring": {"capacity": True}}, "ring.capacity: expected an integer, got True"),
        ({"recording": {"rotate_s": "1h"}}, "recording.rotate_s: expected a number, got '1h'"),
        ({"recording": {"enabled": "yes please"}},
         "recording.enabled: expected true or false, got 'yes please'"),
        ({"live": {"bind": 127}}, "live.bind: expected a string, got 127"),
        ({"live": {"bind": " "}}, "live.bind: must not be empty"),
        ({"cameras": {"left": {"options": [1, 2]}}},
         "cameras.left.options: expected a mapping, got [1, 2]"),
        ({"pairing": 5}, "pairing: expected a mapping of keys, got 5"),
        ({"recording": {"dir": None}}, "recording.dir: must not be null"),
    ],
)
def test_type_errors_name_key_and_value(data: dict, expected: str) -> None:
    assert _errors(data) == [expected]


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"ring": {"capacity": 2}}, "ring.capacity: must be >= 3, got 2"),
        ({"recording": {"rotate_mb": -5}}, "recording.rotate_mb: must be > 0.0, got -5"),
        ({"recording": {"rotate_mb": 0}}, "recording.rotate_mb: must be > 0.0, got 0"),
        ({"live": {"jpeg_quality": 101}}, "live.jpeg_quality: must be <= 100, got 101"),
        ({"live": {"grpc_port": 0}}, "live.grpc_port: must be >= 1, got 0"),
        ({"recording": {"fsync_s": float("nan")}}, "recording.fsync_s: must be finite, got nan"),
    ],
)
def test_range_errors(data: dict, expected: str) -> None:
    assert _errors(data) == [expected]


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"live": {"mode": "serv"}},
         "live.mode: must be one of serve, connect, save, off, got 'serv' (did you mean 'serve'?)"),
        ({"recording": {"compression": "gzip"}},
         "recording.compression: must be one of zstd, lz4, none, got 'gzip'"),
        ({"anemometer": {"parity": "X"}},
         "anemometer.parity: must be one of N, E, O, M, S, got 'X'"),
    ],
)
def test_enum_errors(data: dict, expected: str) -> None:
    assert _errors(data) == [expected]


def test_mounting_is_checked_by_the_anemometer_driver() -> None:
    (err,) = _errors({"anemometer": {"mounting": {"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}}})
    assert err.startswith("anemometer.mounting:")
    (err,) = _errors({"anemometer": {"mounting": {"azimth_deg": 10}}})
    assert "unknown mounting key" in err and "azimth_deg" in err
    C.validate_config({"anemometer": {"mounting": {"azimuth_deg": 30, "tilt_deg": 5}}})


def test_cross_key_rules(tmp_path: Path) -> None:
    assert _errors({"live": {"grpc_port": 9000, "web_port": 9000}}) == [
        "live.web_port: must differ from live.grpc_port, both are 9000"]
    (err,) = _errors({"recording": {"quota_gb": 1, "rotate_mb": 800}})
    assert err.startswith("recording.quota_gb: 1.0 GB cannot hold two files")
    (err,) = _errors({"calibration": str(tmp_path / "missing.yaml")})
    assert err.startswith("calibration: file not found")


def test_all_errors_reported_at_once_with_file_name() -> None:
    with pytest.raises(C.ConfigError) as exc:
        C.validate_config({"ring": {"capacity": 1}, "live": {"mode": "x"}, "y": 2}, "site.yaml")
    assert len(exc.value.errors) == 3
    assert all(line.startswith("site.yaml: ") for line in str(exc.value).splitlines())
    assert isinstance(exc.value, ValueError)  # the CLI maps it to exit code 2


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="config file not found"):
        C.load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("recording: [\n")
    with pytest.raises(ValueError, match="not valid YAML"):
        C.load_config(bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(C.ConfigError, match="the top level: expected a mapping"):
        C.load_config(top)


def test_set_option_parsing() -> None:
    assert C.parse_set_option("recording.rotate_mb=200") == ("recording.rotate_mb", 200)
    assert C.parse_set_option("calibration=null") == ("calibration", None)
    assert C.parse_set_option("live.bind=0.0.0.0") == ("live.bind", "0.0.0.0")
    for bad in ("recording.rotate_mb", "=3", "a..b=3"):
        with pytest.raises(ValueError, match="--set expects"):
            C.parse_set_option(bad)
    with pytest.raises(ValueError, match="not valid YAML"):
        C.parse_set_option("a.b=[1,")


def test_overrides_are_validated_like_file_keys(tmp_path: Path) -> None:
    cfg = C.load_config(None, [("recording.rotate_mb", 5), ("ring.capacity", 8)])
    assert (cfg.recording.rotate_mb, cfg.ring.capacity) == (5.0, 8)
    with pytest.raises(C.ConfigError, match=r"recording\.rotate_mbb: unknown key"):
        C.load_config(None, [("recording.rotate_mbb", 5)])
    with pytest.raises(C.ConfigError, match=r"ring\.capacity: must be >= 3, got 0"):
        C.load_config(None, [("ring.capacity", 0)])


def test_dedicated_flags_win_over_set(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    C.add_config_arguments(parser)
    args = parser.parse_args([
        "--set", "recording.dir=/a", "--record-dir", str(tmp_path),
        "--live", "save", str(tmp_path / "x.rrd"), "--workers", "1",
    ])
    cfg = C.config_from_args(args)
    assert cfg.recording.dir == tmp_path
    assert (cfg.live.mode, cfg.live.file) == ("save", tmp_path / "x.rrd")
    assert cfg.processing.workers == 1
    args = parser.parse_args(["--live", "connect", "rerun+http://10.0.0.1:9876/proxy"])
    assert C.config_from_args(args).live.url == "rerun+http://10.0.0.1:9876/proxy"
    for bad in (["--live", "save"], ["--live", "stream"], ["--live", "off", "x"]):
        with pytest.raises(ValueError, match="--live"):
            C.config_from_args(parser.parse_args(bad))


def test_config_yaml_round_trip() -> None:
    cfg = C.load_config(None, [("recording.dir", "/data/rec"), ("live.mode", "off")])
    again = C.validate_config(yaml.safe_load(C.config_to_yaml(cfg)))
    assert again == cfg


def _problems(overrides: list[tuple[str, object]]) -> list[str]:
    with pytest.raises(C.ConfigError) as info:
        C.validate_config(C.apply_overrides({}, overrides))
    return info.value.errors


def test_misspelt_back_end_is_a_config_error_with_a_suggestion() -> None:
    errors = _problems([("cameras.left.backend", "simulted")])
    assert len(errors) == 1
    assert errors[0].startswith("cameras.left.backend: unknown camera back end 'simulted'")
    assert "did you mean 'simulated'?" in errors[0]


def test_option_keys_protocols_and_ports_are_checked_all_at_once() -> None:
    errors = _problems([("cameras.right.options", {"fsp": 25}),
                      ("anemometer.protocol", "gil"),
                      ("anemometer.options", {"rate_hx": 10}),
                      ("processing.parameters", {"alhpa": 0.1})])
    text = "\n".join(errors)
    assert "cameras.right.options.fsp: not an option of this back end (did you mean 'fps'?)" \
        in text
    assert "anemometer.protocol: unknown anemometer protocol 'gil' (did you mean 'gill'?)" \
        in text
    assert "anemometer.options.rate_hx" in text and "did you mean 'rate_hz'?" in text
    assert ("processing.parameters: unknown processing parameter(s) 'alhpa' "
            "(did you mean 'alpha'?)") in text
    assert len(errors) == 4


def test_serial_back_end_needs_a_port_and_real_cameras_a_calibration() -> None:
    errors = _problems([("anemometer.backend", "serial"),
                      ("cameras.left.backend", "opencv"), ("cameras.right.backend", "opencv")])
    assert any(e.startswith("anemometer.port: the serial back end needs a port") for e in errors)
    assert any(e.startswith("calibration: a stereo calibration file is required")
               for e in errors)


def test_unreadable_calibration_and_file_in_place_of_a_directory(tmp_path: Path) -> None:
    bad = tmp_path / "cal.yaml"
    bad.write_text("format: something-else\n")
    blocker = tmp_path / "rec"
    blocker.write_text("not a directory")
    errors = _problems([("calibration", str(bad)), ("recording.dir", str(blocker))])
    assert any(e.startswith("calibration: ") and "format" in e for e in errors)
    assert any(e.startswith("recording.dir: ") and "not a directory" in e for e in errors)


def test_camera_option_values_are_checked_before_devices_open() -> None:
    errors = _problems([("cameras.left.options", {"drop_rate": 2.0})])
    assert errors == ["cameras.left.options: drop_rate must be in [0, 1), got 2.0"]


def test_live_view_address_and_url_are_checked() -> None:
    errors = _problems([("live.bind", "my-laptop"), ("live.web_port", 9876)])
    assert any(e.startswith("live.bind: must be an IP address") for e in errors)
    assert any(e.startswith("live.web_port: must differ") for e in errors)
    errors = _problems([("live.mode", "connect"), ("live.url", "http://127.0.0.1:9876")])
    assert errors[0].startswith("live.url: must be a Rerun gRPC URL")
