"""Loading the configuration: YAML file, command-line overrides, the effective YAML.

Command-line overrides: ``--set key.path=value`` (value parsed as YAML, so ``5``, ``0.5``,
``null``, ``[1, 2]`` and ``off`` mean what they mean in the file) and dedicated flags such as
``--record-dir`` are applied to the raw mapping *before* validation, so an override is
checked exactly like a key in the file.

Relative paths (``recording.dir``, ``live.file``, ``calibration``) are taken relative to the
current working directory, as every other command-line path; a unit file should use absolute
paths.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from appliance.config.schema import Config
from appliance.config.validate import validate_config


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
