"""Types and ranges: the raw configuration mapping converted into the schema's dataclasses.

Each field's annotated type and rules (``gt``, ``min``, ``max`` in its metadata, see
:mod:`appliance.config.schema`) are checked and every problem is appended to ``errors``,
naming the key path and the bad value, with a suggestion for near misses.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal


def did_you_mean(value: Any, choices: Iterable[Any]) -> str:
    """`` (did you mean 'x'?)`` for a near miss among ``choices``, else ``""``."""
    close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def describe(value: Any) -> str:
    """``repr(value)``, cut to 60 characters (a message names the bad value)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_range(path: str, value: float, meta: Mapping[str, Any], errors: list[str]) -> None:
    if "gt" in meta and not value > meta["gt"]:
        errors.append(f"{path}: must be > {meta['gt']}, got {describe(value)}")
    if "min" in meta and value < meta["min"]:
        errors.append(f"{path}: must be >= {meta['min']}, got {describe(value)}")
    if "max" in meta and value > meta["max"]:
        errors.append(f"{path}: must be <= {meta['max']}, got {describe(value)}")


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
                          f"got {describe(value)}{did_you_mean(value, choices)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            errors.append(f"{path}: expected true or false, got {describe(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            errors.append(f"{path}: expected an integer, got {describe(value)}")
            return value
        _check_range(path, value, meta, errors)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            errors.append(f"{path}: expected a number, got {describe(value)}")
            return value
        if not math.isfinite(value):
            errors.append(f"{path}: must be finite, got {describe(value)}")
            return value
        _check_range(path, value, meta, errors)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            errors.append(f"{path}: expected a string, got {describe(value)}")
        elif meta.get("nonempty") and not value.strip():
            errors.append(f"{path}: must not be empty")
        return value
    if tp is Path:
        if not isinstance(value, (str, Path)) or not str(value).strip():
            errors.append(f"{path}: expected a path string, got {describe(value)}")
            return value
        return Path(value).expanduser()
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            errors.append(f"{path}: expected a mapping, got {describe(value)}")
            return value
        bad = [k for k in value if not isinstance(k, str)]
        if bad:
            errors.append(f"{path}: keys must be strings, got {describe(bad[0])}")
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
        errors.append(f"{path}: expected a list of polygons, got {describe(value)}")
        return value
    for i, poly in enumerate(value):
        if not (isinstance(poly, list) and len(poly) >= 3 and all(map(point_ok, poly))):
            errors.append(f"{path}[{i}]: expected a polygon [[x, y], [x, y], [x, y], ...] "
                          f"(at least 3 points), got {describe(poly)}")
            return value
    return [[[float(c) for c in pt] for pt in poly] for poly in value]


def build(cls: type, data: Any, prefix: str, errors: list[str]) -> Any:
    """Build dataclass ``cls`` from mapping ``data``, appending problems to ``errors``."""
    where = prefix or "the top level"
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        errors.append(f"{where}: expected a mapping of keys, got {describe(data)}")
        return cls()
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            hint = did_you_mean(key, fields) or f" (known keys: {', '.join(fields)})"
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
            kwargs[name] = build(tp, value, path, errors)
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
                      f"{describe(value)}")
        return value
    for i, iv in enumerate(value):
        if not ok(iv):
            errors.append(f"{path}[{i}]: expected [on_s, off_s] with 0 <= on_s < off_s, "
                          f"got {describe(iv)}")
            return value
    return [[float(c) for c in iv] for iv in value]
