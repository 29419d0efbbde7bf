"""The appliance configuration: one YAML file, validated at start into typed dataclasses.

Every key has a default (the dataclass defaults below, which ``config/default.yaml`` spells
out: everything simulated). A site file only names what differs. Validation happens once,
before any device is opened, and reports *every* problem at once, each line naming the key
path and the bad value::

    site.yaml: recording.rotate_mb: must be > 0, got -5
    site.yaml: live.mod: unknown key (did you mean 'mode'?)

Back-end option dicts (``cameras.left.options``, ``anemometer.options``,
``processing.parameters``) stay plain dicts here; each back end validates its own.

Command-line overrides: ``--set key.path=value`` (value parsed as YAML, so ``5``, ``0.5``,
``null``, ``[1, 2]`` and ``off`` mean what they mean in the file) and dedicated flags such as
``--record-dir`` are applied to the raw mapping *before* validation, so an override is
checked exactly like a key in the file.

Relative paths (``recording.dir``, ``live.file``, ``calibration``) are taken relative to the
current working directory, as every other command-line path; a unit file should use absolute
paths.
"""

# Every field is built by _opt() so that its documentation and validation rules live beside it.
# ruff: noqa: RUF009

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

__all__ = [
    "AnemometerConfig",
    "CameraConfig",
    "CamerasConfig",
    "Config",
    "ConfigError",
    "HealthConfig",
    "LiveConfig",
    "PairingConfig",
    "ProcessingConfig",
    "RecordingConfig",
    "RingConfig",
    "apply_overrides",
    "config_to_dict",
    "config_to_yaml",
    "load_config",
    "parse_set_option",
    "validate_config",
]


class ConfigError(ValueError):
    """The configuration is invalid; ``errors`` lists one ``"key.path: problem"`` per line.

    A ``ValueError`` so the CLI reports it as bad input (exit code 2).
    """

    def __init__(self, errors: Sequence[str], source: str = "config") -> None:
        self.errors = list(errors)
        self.source = source
        super().__init__("\n".join(f"{source}: {e}" for e in self.errors))


def _opt(doc: str, default: Any = dataclasses.MISSING, *, factory: Any = None, **rules: Any):
    """A dataclass field carrying its documentation and validation rules.

    ``rules``: ``min``/``max`` (inclusive), ``gt`` (exclusive lower bound), ``nonempty``,
    ``shape`` for nested float lists, ``orthonormal`` for rotation matrices.
    """
    meta = {"doc": doc, **rules}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class CameraConfig:
    """One camera of the stereo pair."""

    backend: str = _opt(
        "camera back end name (simulated, replay, aravis, opencv, ...)", "simulated",
        nonempty=True,
    )
    options: dict[str, Any] = _opt("back-end specific options, checked by the back end",
                                   factory=dict)
    frame_rate_hz: float = _opt("nominal frame rate in Hz", 30.0, gt=0.0, max=1000.0)


@dataclass(frozen=True)
class CamerasConfig:
    """The stereo pair: ``left`` is the reference camera of the scene flow."""

    left: CameraConfig = _opt("left (reference) camera", factory=CameraConfig)
    right: CameraConfig = _opt("right camera", factory=CameraConfig)


@dataclass(frozen=True)
class AnemometerConfig:
    """The 3D ultrasonic anemometer on a serial line."""

    backend: str = _opt("anemometer back end (simulated, serial, replay, ...)", "simulated",
                        nonempty=True)
    protocol: str = _opt(
        "wire protocol of the sensor (gill, gill_polar, campbell_csat3b, young_81000, "
        "young_81000_uvw, metek_usonic3)", "gill", nonempty=True)
    port: str | None = _opt(
        "serial port URL for pyserial (/dev/ttyUSB0, loop://, spy:///dev/ttyUSB0); null lets "
        "the simulated back end create its own pseudo terminal", None,
    )
    baud: int = _opt("baud rate", 9600, min=50, max=4_000_000)
    parity: Literal["N", "E", "O", "M", "S"] = _opt("parity: N, E, O, M or S", "N")
    options: dict[str, Any] = _opt("back-end specific options, checked by the back end",
                                   factory=dict)
    mounting: dict[str, Any] = _opt(
        "mounting into the left camera frame: azimuth_deg / tilt_deg / roll_deg, or a 3x3 "
        "'matrix' (rows X, Y, Z; columns the sensor's F, L, U), and optionally "
        "'native_axes'; checked by drivers.anemometer.mounting", factory=dict)


@dataclass(frozen=True)
class PairingConfig:
    """Left/right frame pairing by nearest arrival time."""

    tolerance_s: float | None = _opt(
        "largest |t_left - t_right| of a pair in seconds; null = half a frame period", None,
        gt=0.0, max=10.0,
    )


@dataclass(frozen=True)
class RingConfig:
    """Shared-memory ring of stereo pairs between acquisition and the worker processes."""

    capacity: int = _opt("number of stereo-pair slots (>= 3: the method needs t0, t1, t2)",
                         32, min=3, max=100_000)


@dataclass(frozen=True)
class ProcessingConfig:
    """Scene-flow worker processes."""

    enabled: bool = _opt("run the scene-flow chain at all", True)
    workers: int = _opt("number of worker processes", 2, min=1, max=64)
    parameters: dict[str, Any] = _opt(
        "parameters passed to the processing chain as they are (checked by it)", factory=dict,
    )


@dataclass(frozen=True)
class RecordingConfig:
    """MCAP recording of every raw frame, wind sample, pair, result and health snapshot."""

    enabled: bool = _opt("write MCAP files", True)
    dir: Path = _opt("directory of the MCAP files", Path("recordings"))
    rotate_mb: float = _opt("start a new file past this size, MB (1e6 bytes)", 1024.0, gt=0.0)
    rotate_s: float = _opt("start a new file after this many seconds", 3600.0, gt=0.0)
    quota_gb: float | None = _opt(
        "delete the oldest closed recordings when their total passes this, GB (1e9 bytes); "
        "null = no quota", 50.0, gt=0.0,
    )
    fsync_s: float = _opt("flush the open chunk and fsync at least this often, seconds",
                          5.0, gt=0.0, max=3600.0)
    compression: Literal["zstd", "lz4", "none"] = _opt("chunk compression", "zstd")
    chunk_kb: int = _opt("uncompressed chunk size, KiB", 1024, min=16, max=65536)
    queue_size: int = _opt(
        "messages the recorder queue holds before it drops (>= 2 s of 2 x 30 Hz frames)",
        4096, min=16, max=1_000_000,
    )
    fields_every: int = _opt(
        "record the full result fields (flow, disparity, velocity, mask) of every N-th "
        "processed pair; summaries are recorded for every pair and the raw frames allow "
        "any field to be recomputed with `ogiflow replay`", 10, min=1, max=1_000_000,
    )


@dataclass(frozen=True)
class LiveConfig:
    """Rerun live view."""

    mode: Literal["serve", "connect", "save", "off"] = _opt(
        "serve: web viewer on this box; connect: stream to a viewer at url; "
        "save: write an .rrd file; off", "serve",
    )
    bind: str = _opt("address the gRPC and web servers bind to (serve mode)", "127.0.0.1",
                     nonempty=True)
    grpc_port: int = _opt("gRPC port of the served recording", 9876, min=1, max=65535)
    web_port: int = _opt("HTTP port of the web viewer", 9090, min=1, max=65535)
    url: str = _opt("viewer to stream to in connect mode", "rerun+http://127.0.0.1:9876/proxy",
                    nonempty=True)
    file: Path = _opt(".rrd file written in save mode", Path("ogiflow.rrd"))
    queue_size: int = _opt("live items queued before new ones are dropped", 8, min=1,
                           max=10_000)
    jpeg_quality: int = _opt("JPEG quality of live images", 80, min=1, max=100)


@dataclass(frozen=True)
class HealthConfig:
    """Health snapshots and the systemd watchdog."""

    interval_s: float = _opt("seconds between health snapshots", 1.0, gt=0.0, max=3600.0)
    watchdog: bool = _opt("send WATCHDOG=1 to systemd when it asks for it", True)
    stall_s: float = _opt(
        "stop the watchdog pings when no new frame arrived for this many seconds", 10.0,
        gt=0.0, max=3600.0,
    )


@dataclass(frozen=True)
class SimulationConfig:
    """The synthetic gas scene that simulated cameras show (ignored for real cameras).

    The plume is simulated once (Stable Fluids, paper ref. [22]) with the simulated
    anemometer's mean wind, rendered into both cameras, cached on disk and looped.
    """

    frames: int = _opt("length of the pre-rendered loop, frames (30 Hz)", 240, min=10,
                       max=100_000)
    voxel_m: float = _opt("voxel size of the fluid grid, m (smaller = finer and slower)",
                          0.04, min=0.005, max=0.2)
    distance_m: float = _opt("distance of the plume from the cameras, m", 5.5, gt=0.5,
                             max=100.0)
    baseline_m: float = _opt("stereo baseline of the simulated cameras, m", 0.3, gt=0.0,
                             max=10.0)
    release_rate_g_s: float = _opt("gas release rate of the simulated leak, g/s", 3.0,
                                   gt=0.0, max=1000.0)
    seed: int = _opt("random seed of the simulated turbulence", 7, min=0)
    cache_dir: Path | None = _opt(
        "where rendered scenes are cached; null = $XDG_CACHE_HOME/ogiflow or "
        "~/.cache/ogiflow", None,
    )


@dataclass(frozen=True)
class Config:
    """The whole appliance configuration (one YAML file)."""

    cameras: CamerasConfig = _opt("the two OGI cameras", factory=CamerasConfig)
    anemometer: AnemometerConfig = _opt("the anemometer", factory=AnemometerConfig)
    pairing: PairingConfig = _opt("stereo pairing", factory=PairingConfig)
    ring: RingConfig = _opt("ring buffer", factory=RingConfig)
    processing: ProcessingConfig = _opt("scene flow workers", factory=ProcessingConfig)
    recording: RecordingConfig = _opt("MCAP recording", factory=RecordingConfig)
    live: LiveConfig = _opt("Rerun live view", factory=LiveConfig)
    health: HealthConfig = _opt("health and watchdog", factory=HealthConfig)
    calibration: Path | None = _opt(
        "stereo calibration file (YAML from `ogiflow calibrate stereo`); null = none", None,
    )
    simulation: SimulationConfig = _opt("scene of the simulated cameras",
                                        factory=SimulationConfig)


# --------------------------------------------------------------------------- validation


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _type_name(tp: Any) -> str:
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false",
            Path: "a path string", dict: "a mapping"}.get(tp, str(tp))


def _check_range(path: str, value: float, meta: Mapping[str, Any], errors: list[str]) -> None:
    if "gt" in meta and not value > meta["gt"]:
        errors.append(f"{path}: must be > {meta['gt']}, got {_describe(value)}")
    if "min" in meta and value < meta["min"]:
        errors.append(f"{path}: must be >= {meta['min']}, got {_describe(value)}")
    if "max" in meta and value > meta["max"]:
        errors.append(f"{path}: must be <= {meta['max']}, got {_describe(value)}")


def _convert_scalar(path: str, tp: Any, value: Any, meta: Mapping[str, Any],
                    errors: list[str]) -> Any:
    """Check one scalar against its annotated type and rules; return the converted value."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        choices = typing.get_args(tp)
        if value is False and "off" in choices:
            value = "off"  # YAML 1.1 reads a bare `off` as false
        if value not in choices:
            close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            errors.append(f"{path}: must be one of {', '.join(map(str, choices))}, "
                          f"got {_describe(value)}{hint}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            errors.append(f"{path}: expected true or false, got {_describe(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            errors.append(f"{path}: expected an integer, got {_describe(value)}")
            return value
        _check_range(path, value, meta, errors)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            errors.append(f"{path}: expected a number, got {_describe(value)}")
            return value
        if not math.isfinite(value):
            errors.append(f"{path}: must be finite, got {_describe(value)}")
            return value
        _check_range(path, value, meta, errors)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            errors.append(f"{path}: expected a string, got {_describe(value)}")
        elif meta.get("nonempty") and not value.strip():
            errors.append(f"{path}: must not be empty")
        return value
    if tp is Path:
        if not isinstance(value, (str, Path)) or not str(value).strip():
            errors.append(f"{path}: expected a path string, got {_describe(value)}")
            return value
        return Path(value).expanduser()
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            errors.append(f"{path}: expected a mapping, got {_describe(value)}")
            return value
        bad = [k for k in value if not isinstance(k, str)]
        if bad:
            errors.append(f"{path}: keys must be strings, got {_describe(bad[0])}")
        return dict(value)
    if origin is list:
        return _convert_array(path, value, meta, errors)
    raise TypeError(f"config field {path} has unsupported type {tp!r}")  # programming error


def _convert_array(path: str, value: Any, meta: Mapping[str, Any], errors: list[str]) -> Any:
    shape = meta["shape"]
    try:
        ok = isinstance(value, list) and len(value) == shape[0]
        if len(shape) == 2:
            ok = ok and all(isinstance(r, list) and len(r) == shape[1] for r in value)
        flat = [x for r in value for x in r] if len(shape) == 2 else list(value)
        ok = ok and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                        and math.isfinite(x) for x in flat)
    except TypeError:
        ok = False
    if not ok:
        want = "x".join(map(str, shape))
        errors.append(f"{path}: expected a {want} list of numbers, got {_describe(value)}")
        return value
    out = [float(x) for x in value] if len(shape) == 1 else [[float(x) for x in r]
                                                              for r in value]
    if meta.get("orthonormal"):
        m = out
        gram_err = max(abs(sum(m[k][i] * m[k][j] for k in range(3)) - (1.0 if i == j else 0.0))
                       for i in range(3) for j in range(3))
        det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
               - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
               + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
        if gram_err > 1e-3 or det < 0:
            errors.append(f"{path}: must be a rotation (orthonormal, determinant +1; "
                          f"R^T R error {gram_err:.2g}, det {det:.3g}), got {_describe(value)}")
    return out


def _build(cls: type, data: Any, prefix: str, errors: list[str]) -> Any:
    """Build dataclass ``cls`` from mapping ``data``, appending problems to ``errors``."""
    where = prefix or "the top level"
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        errors.append(f"{where}: expected a mapping of keys, got {_describe(data)}")
        return cls()
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else (
                f" (known keys: {', '.join(fields)})")
            errors.append(f"{prefix + '.' if prefix else ''}{key}: unknown key{hint}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name not in data:
            continue
        path = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        value = data[name]
        args = typing.get_args(tp)
        optional = (typing.get_origin(tp) in (typing.Union, types.UnionType)
                    and type(None) in args)
        if optional:
            if value is None:
                kwargs[name] = None
                continue
            tp = next(a for a in args if a is not type(None))
        elif value is None and not dataclasses.is_dataclass(tp):
            errors.append(f"{path}: must not be null")
            continue
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, path, errors)
        else:
            kwargs[name] = _convert_scalar(path, tp, value, f.metadata, errors)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError):  # only reachable with errors already recorded
        return cls()


def _cross_checks(cfg: Config, errors: list[str]) -> None:
    """Rules that involve more than one key."""
    live = cfg.live
    if live.mode == "serve" and live.grpc_port == live.web_port:
        errors.append(f"live.web_port: must differ from live.grpc_port, both are "
                      f"{live.grpc_port}")
    if cfg.recording.quota_gb is not None and cfg.recording.quota_gb * 1000 < (
            2 * cfg.recording.rotate_mb):
        errors.append(
            f"recording.quota_gb: {cfg.recording.quota_gb} GB cannot hold two files of "
            f"recording.rotate_mb = {cfg.recording.rotate_mb} MB; raise the quota or rotate "
            f"sooner")
    from drivers.anemometer.base import AnemometerConfigError
    from drivers.anemometer.mounting import Mounting

    try:
        Mounting.from_config(cfg.anemometer.protocol, cfg.anemometer.mounting)
    except AnemometerConfigError as exc:
        errors.append(f"anemometer.mounting: {exc}")
    if cfg.calibration is not None and not cfg.calibration.is_file():
        errors.append(f"calibration: file not found: {str(cfg.calibration)!r}")


def validate_config(data: Any, source: str = "config") -> Config:
    """Validate a raw mapping (as loaded from YAML) into a :class:`Config`.

    Raises
    ------
    ConfigError
        Listing every problem found, each naming its key path and bad value.
    """
    errors: list[str] = []
    cfg = _build(Config, data, "", errors)
    if not errors:
        _cross_checks(cfg, errors)
    if errors:
        raise ConfigError(errors, source)
    return cfg


# --------------------------------------------------------------------------- overrides


def parse_set_option(text: str) -> tuple[str, Any]:
    """Parse one ``--set key.path=value``; the value is YAML (``5``, ``null``, ``[1, 2]``).

    Raises
    ------
    ValueError
        When there is no ``=`` or the key path is empty.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ValueError(f"--set expects key.path=value, got {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        raise ValueError(f"--set {key}: value {raw!r} is not valid YAML ({exc})") from None
    return key, value


def apply_overrides(data: Mapping[str, Any] | None,
                    overrides: Iterable[tuple[str, Any]]) -> dict[str, Any]:
    """Return a deep copy of ``data`` with ``(key.path, value)`` overrides set.

    Intermediate mappings are created as needed; a non-mapping in the way is replaced, and
    unknown keys are left for :func:`validate_config` to report.
    """
    overrides = list(overrides)
    if data is not None and not isinstance(data, Mapping):
        if not overrides:
            return data  # type: ignore[return-value]  # validate_config reports it
        raise ValueError("the configuration file's top level must be a mapping of keys")
    out: dict[str, Any] = _deep_copy(dict(data or {}))
    for key, value in overrides:
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        node[parts[-1]] = value
    return out


def _deep_copy(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _deep_copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_deep_copy(v) for v in value]
    return value


def read_yaml(path: Path) -> Any:
    """Read one YAML file, raising ``ValueError`` naming the file and line on bad syntax."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"config file not found: {str(path)!r}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None


def load_config(path: str | Path | None = None,
                overrides: Iterable[tuple[str, Any]] = ()) -> Config:
    """Load, merge with defaults, apply overrides and validate the configuration.

    Parameters
    ----------
    path
        YAML file; ``None`` means the built-in defaults (= ``config/default.yaml``).
    overrides
        ``(key.path, value)`` pairs, e.g. from :func:`parse_set_option`, applied last.

    Raises
    ------
    ConfigError
        Invalid keys or values (a ``ValueError``: exit code 2 in the CLI).
    ValueError
        Missing file or malformed YAML.
    """
    data = read_yaml(Path(path)) if path is not None else {}
    source = str(path) if path is not None else "defaults"
    return validate_config(apply_overrides(data, overrides), source)


# --------------------------------------------------------------------------- output


def config_to_dict(cfg: Any) -> Any:
    """Plain YAML-able data (paths as strings) from a config dataclass."""
    if dataclasses.is_dataclass(cfg):
        return {f.name: config_to_dict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    if isinstance(cfg, Path):
        return str(cfg)
    if isinstance(cfg, Mapping):
        return {k: config_to_dict(v) for k, v in cfg.items()}
    if isinstance(cfg, (list, tuple)):
        return [config_to_dict(v) for v in cfg]
    return cfg


def config_to_yaml(cfg: Config) -> str:
    """The effective configuration as YAML text (stored in every MCAP file)."""
    return yaml.safe_dump(config_to_dict(cfg), sort_keys=False)


# --------------------------------------------------------------------------- command line


def live_overrides(tokens: Sequence[str]) -> list[tuple[str, Any]]:
    """Translate ``--live serve|connect URL|save FILE|off`` into config overrides.

    Raises
    ------
    ValueError
        Unknown mode or wrong number of arguments.
    """
    if not tokens:
        raise ValueError("--live expects serve, connect URL, save FILE or off")
    mode, rest = tokens[0], list(tokens[1:])
    needs = {"serve": 0, "off": 0, "connect": 1, "save": 1}
    if mode not in needs:
        raise ValueError(f"--live: unknown mode {mode!r} (serve, connect URL, save FILE, off)")
    if len(rest) != needs[mode]:
        raise ValueError(f"--live {mode}: expects {needs[mode]} argument(s), got {rest!r}")
    out: list[tuple[str, Any]] = [("live.mode", mode)]
    if mode == "connect":
        out.append(("live.url", rest[0]))
    elif mode == "save":
        out.append(("live.file", rest[0]))
    return out


def add_config_arguments(parser: Any) -> None:
    """Add ``--config``, ``--set`` and the dedicated override flags to an argparse parser."""
    parser.add_argument("--config", metavar="FILE", type=Path, default=None,
                        help="YAML configuration (default: the built-in simulated setup, "
                             "as in config/default.yaml)")
    parser.add_argument("--set", metavar="KEY.PATH=VALUE", action="append", default=[],
                        dest="set_options",
                        help="override one config key, value in YAML syntax "
                             "(repeatable), e.g. --set recording.rotate_mb=200")
    parser.add_argument("--record-dir", metavar="DIR", default=None,
                        help="directory for MCAP files (recording.dir)")
    parser.add_argument("--live", metavar="MODE", nargs="+", default=None,
                        help="live view: serve | connect URL | save FILE | off (live.mode)")
    parser.add_argument("--calibration", metavar="FILE", default=None,
                        help="stereo calibration file (calibration)")
    parser.add_argument("--workers", metavar="N", type=int, default=None,
                        help="scene-flow worker processes (processing.workers)")


def config_from_args(args: Any) -> Config:
    """Load the configuration named by :func:`add_config_arguments`' options.

    Dedicated flags win over ``--set``, which wins over the file.
    """
    overrides = [parse_set_option(s) for s in getattr(args, "set_options", [])]
    if getattr(args, "record_dir", None) is not None:
        overrides.append(("recording.dir", args.record_dir))
    if getattr(args, "live", None) is not None:
        overrides.extend(live_overrides(args.live))
    if getattr(args, "calibration", None) is not None:
        overrides.append(("calibration", args.calibration))
    if getattr(args, "workers", None) is not None:
        overrides.append(("processing.workers", args.workers))
    return load_config(getattr(args, "config", None), overrides)
