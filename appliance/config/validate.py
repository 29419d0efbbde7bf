"""Validation of the raw configuration mapping into :class:`~appliance.config.schema.Config`.

It happens once, before any device is opened, and reports *every* problem at once, each
line naming the key path and the bad value, with a suggestion for near misses::

    site.yaml: recording.rotate_mb: must be > 0, got -5
    site.yaml: live.mod: unknown key (did you mean 'mode'?)
    site.yaml: cameras.left.backend: unknown camera back end 'simulted' (did you mean
        'simulated'?); known: aravis, opencv, replay_folder, replay_mcap, simulated

Beyond types and ranges (from each field's rules in :mod:`appliance.config.schema`) it checks
what can be known before devices open: back-end and protocol names, the option keys each
back end accepts, the processing parameters, the mounting, the calibration file and paths.
Option *values* are checked by the back end when it is created.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import ipaddress
import math
import os
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

from appliance.config.schema import Config, ConfigError

__all__ = ["validate_config"]


def _did_you_mean(value: Any, choices: Iterable[Any]) -> str:
    """`` (did you mean 'x'?)`` for a near miss among ``choices``, else ``""``."""
    close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


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
            errors.append(f"{path}: must be one of {', '.join(map(str, choices))}, "
                          f"got {_describe(value)}{_did_you_mean(value, choices)}")
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
    if origin is list and meta.get("polygons"):
        return _convert_polygons(path, value, errors)
    if origin is list and meta.get("intervals"):
        return _convert_intervals(path, value, errors)
    raise TypeError(f"config field {path} has unsupported type {tp!r}")  # programming error


def _convert_polygons(path: str, value: Any, errors: list[str]) -> Any:
    """A list of polygons, each a list of at least 3 finite [x, y] points."""
    def point_ok(pt: Any) -> bool:
        return (isinstance(pt, list) and len(pt) == 2 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
            for c in pt))

    if not isinstance(value, list):
        errors.append(f"{path}: expected a list of polygons, got {_describe(value)}")
        return value
    for i, poly in enumerate(value):
        if not (isinstance(poly, list) and len(poly) >= 3 and all(map(point_ok, poly))):
            errors.append(f"{path}[{i}]: expected a polygon [[x, y], [x, y], [x, y], ...] "
                          f"(at least 3 points), got {_describe(poly)}")
            return value
    return [[[float(c) for c in pt] for pt in poly] for poly in value]


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
            hint = _did_you_mean(key, fields) or f" (known keys: {', '.join(fields)})"
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


def _convert_intervals(path: str, value: Any, errors: list[str]) -> Any:
    """A list of time intervals [on_s, off_s] (finite numbers, on_s >= 0)."""
    def ok(iv: Any) -> bool:
        return (isinstance(iv, list) and len(iv) == 2 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c)
            for c in iv) and 0 <= iv[0] < iv[1])

    if not isinstance(value, list):
        errors.append(f"{path}: expected a list of [on_s, off_s] intervals, got "
                      f"{_describe(value)}")
        return value
    for i, iv in enumerate(value):
        if not ok(iv):
            errors.append(f"{path}[{i}]: expected [on_s, off_s] with 0 <= on_s < off_s, "
                          f"got {_describe(iv)}")
            return value
    return [[float(c) for c in iv] for iv in value]


def _check_schedule(cfg: Config, errors: list[str]) -> None:
    """The release schedule fits in the simulated loop, sorted and without overlap."""
    from processing.synthetic.presets import FIELD_FRAME_RATE_HZ
    from processing.synthetic.schedule import ReleaseSchedule

    sim = cfg.simulation
    if not sim.release_schedule:
        return
    if sim.scene != "leak":
        errors.append("simulation.release_schedule: only the leak scene releases gas "
                      f"(simulation.scene is {sim.scene!r})")
        return
    try:
        ReleaseSchedule.from_lists(sim.release_schedule, sim.frames / FIELD_FRAME_RATE_HZ)
    except ValueError as exc:
        errors.append(f"simulation.release_schedule: {exc} (the loop is simulation.frames "
                      f"= {sim.frames} frames at {FIELD_FRAME_RATE_HZ:g} Hz)")


def _cross_checks(cfg: Config, errors: list[str]) -> None:
    """Rules that involve more than one key."""
    live = cfg.live
    if live.mode == "serve":
        _check_serve(live, errors)
    if live.page.enabled:
        _check_page(live, errors)
    if live.mode == "connect" and not live.url.startswith(("rerun+http://", "rerun+https://",
                                                           "rerun://")):
        errors.append(f"live.url: must be a Rerun gRPC URL such as "
                      f"rerun+http://127.0.0.1:9876/proxy, got {live.url!r}")
    if cfg.recording.quota_gb is not None and cfg.recording.quota_gb * 1000 < (
            2 * cfg.recording.rotate_mb):
        errors.append(
            f"recording.quota_gb: {cfg.recording.quota_gb} GB cannot hold two files of "
            f"recording.rotate_mb = {cfg.recording.rotate_mb} MB; raise the quota or rotate "
            f"sooner")
    for key, path in (("recording.dir", cfg.recording.dir),
                      ("simulation.cache_dir", cfg.simulation.cache_dir)):
        if path is not None and path.exists() and not path.is_dir():
            errors.append(f"{key}: {str(path)!r} exists and is not a directory")
    if cfg.live.mode == "save" and cfg.live.file.is_dir():
        errors.append(f"live.file: {str(cfg.live.file)!r} is a directory")
    _check_calibration(cfg, errors)
    _check_processing(cfg, errors)
    _check_schedule(cfg, errors)


def _check_serve(live: Any, errors: list[str]) -> None:
    if live.grpc_port == live.web_port:
        errors.append(f"live.web_port: must differ from live.grpc_port, both are "
                      f"{live.grpc_port}")
    _check_bind("live.bind", live.bind, errors)
    if os.geteuid() != 0:
        for key in ("grpc_port", "web_port"):
            if getattr(live, key) < 1024:
                errors.append(f"live.{key}: ports below 1024 need root, got "
                              f"{getattr(live, key)}")


def _check_bind(key: str, bind: str, errors: list[str]) -> None:
    """A bind address: ``localhost`` or an IP address of this machine."""
    if bind == "localhost":
        return
    try:
        ipaddress.ip_address(bind)
    except ValueError:
        errors.append(f"{key}: must be an IP address of this machine (127.0.0.1, "
                      f"0.0.0.0, ...), got {bind!r}")


def _check_page(live: Any, errors: list[str]) -> None:
    page = live.page
    _check_bind("live.page.bind", page.bind, errors)
    if 0 < page.port < 1024 and os.geteuid() != 0:
        errors.append(f"live.page.port: ports below 1024 need root, got {page.port}")
    if live.mode == "serve" and page.port in (live.grpc_port, live.web_port) and (
            page.bind == live.bind):
        errors.append(f"live.page.port: {page.port} is also the Rerun viewer's port; "
                      f"choose another")


def _check_calibration(cfg: Config, errors: list[str]) -> None:
    from processing.calibration import load_calibration

    if cfg.calibration is None:
        if cfg.cameras.right is not None and not any(
                c is not None and c.backend == "simulated" and "source" not in c.options
                for c in (cfg.cameras.left, cfg.cameras.right)):
            errors.append("calibration: a stereo calibration file is required unless a "
                          "simulated camera renders the scene (run `ogiflow calibrate "
                          "stereo`, then set calibration: to its file) or the site has "
                          "one camera (cameras.right: null)")
        return
    if not cfg.calibration.is_file():
        errors.append(f"calibration: file not found: {str(cfg.calibration)!r}")
        return
    try:
        load_calibration(cfg.calibration)
    except (ValueError, OSError, TypeError, KeyError) as exc:
        errors.append(f"calibration: {exc}")


def _check_processing(cfg: Config, errors: list[str]) -> None:
    from processing.chain.driver import ChainParameters

    try:
        ChainParameters.from_mapping(cfg.processing.parameters)
    except (ValueError, TypeError) as exc:
        errors.append(f"processing.parameters: {exc}")


def _accepted_options(cls: type, *also: type) -> set[str]:
    """Keyword names ``cls(...)`` accepts (and the classes it forwards ``**kwargs`` to)."""
    names: set[str] = set()
    for c in (cls, *also):
        params = inspect.signature(c.__init__).parameters  # type: ignore[misc]
        names |= {n for n, p in params.items() if n != "self"
                  and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
    return names


def _check_options(path: str, options: Mapping[str, Any], accepted: set[str],
                   errors: list[str]) -> bool:
    """Report option keys the back end does not take; True when all are known."""
    unknown = sorted(set(options) - accepted)
    for key in unknown:
        errors.append(f"{path}.{key}: not an option of this back end"
                      f"{_did_you_mean(key, accepted)}; accepted: {', '.join(sorted(accepted))}")
    return not unknown


def _check_name(path: str, name: str, table: Mapping[str, str], kind: str,
                errors: list[str]) -> bool:
    if name in table:
        return True
    errors.append(f"{path}: unknown {kind} {name!r}{_did_you_mean(name, table)}; "
                  f"known: {', '.join(sorted(table))}")
    return False


def _check_cameras(cfg: Config, errors: list[str]) -> bool:
    """Which cameras the site has: both, or the left one alone (the left camera is the
    reference of the chain, its pixels those of the zones). False when it makes no sense."""
    if cfg.cameras.left is None and cfg.cameras.right is None:
        errors.append("cameras: no camera configured (cameras.left and cameras.right are "
                      "both null); set cameras.left to the camera (a single-camera site "
                      "has cameras.right: null)")
        return False
    if cfg.cameras.left is None:
        errors.append("cameras.left: null while cameras.right names a camera; set "
                      "cameras.left to the camera and cameras.right: null (a single-camera "
                      "site uses the left camera, the chain's reference)")
        return False
    return True


def _device_checks(cfg: Config, errors: list[str]) -> None:
    """Back-end and protocol names and option keys: known before any device opens."""
    from drivers.anemometer import registry as anemometers
    from drivers.anemometer.base import AnemometerConfigError
    from drivers.anemometer.mounting import Mounting
    from drivers.camera import registry as cameras
    from drivers.camera.base import CameraBackendMissing

    if not _check_cameras(cfg, errors):
        return
    for side in ("left", "right"):
        cam = getattr(cfg.cameras, side)
        if cam is None:
            continue
        path = f"cameras.{side}"
        if not _check_name(f"{path}.backend", cam.backend, cameras.BACKENDS,
                           "camera back end", errors):
            continue
        try:
            cls = cameras.camera_class(cam.backend)
        except CameraBackendMissing as exc:
            errors.append(f"{path}.backend: {exc}")
            continue
        accepted = _accepted_options(cls)
        if _check_options(f"{path}.options", cam.options, accepted, errors):
            try:  # values: building a camera object opens nothing
                cls(**cam.options)
            except (ValueError, TypeError) as exc:
                errors.append(f"{path}.options: {exc}")
    a = cfg.anemometer
    protocol_ok = _check_name("anemometer.protocol", a.protocol, anemometers.PROTOCOLS,
                              "anemometer protocol", errors)
    if _check_name("anemometer.backend", a.backend, anemometers.BACKENDS,
                   "anemometer back end", errors):
        try:
            cls = anemometers._load(anemometers.BACKENDS, "back end", a.backend)
            serial = anemometers._load(anemometers.BACKENDS, "back end", "serial")
        except AnemometerConfigError as exc:
            errors.append(f"anemometer.backend: {exc}")
        else:
            # The simulated anemometer hands its remaining options to the serial back end.
            accepted = _accepted_options(cls, serial) if a.backend == "simulated" else (
                _accepted_options(cls))
            _check_options("anemometer.options", a.options, accepted, errors)
    if a.backend == "serial" and not a.port:
        errors.append("anemometer.port: the serial back end needs a port "
                      "(e.g. /dev/ttyUSB0), got null")
    if protocol_ok:
        try:
            Mounting.from_config(a.protocol, a.mounting)
        except AnemometerConfigError as exc:
            errors.append(f"anemometer.mounting: {exc}")


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
        _device_checks(cfg, errors)
        _cross_checks(cfg, errors)
    if errors:
        raise ConfigError(errors, source)
    return cfg
