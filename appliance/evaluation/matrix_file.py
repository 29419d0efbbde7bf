"""Robustness matrices from a file (YAML or JSON): scenes x conditions, and a hold-out part.

The file's layout (every key but ``scenes`` and ``conditions`` optional)::

    name: wide                 # default: the file's stem
    n_frames: 14               # frames per scene (>= 3)
    voxel_m: 0.05              # fluid voxel size, m
    scenes:                    # one fluid simulation each
      - {seed: 23, wind_m_s: [-1.5, 0.0, 0.0], release_rate_g_s: 2.0, distance_m: 4.5,
         depth_m: 1.44}
    conditions:                # camera effects; a key left out keeps Condition's default
      - {name: ideal}
      - {name: all realistic, noise_netd_k: 0.03, jitter_px: 0.3, gain_mismatch: 0.04,
         moving_object: true}
    holdout:                   # a fixed part nobody tunes on: its own scenes, and the
      scenes: [...]            # main part's conditions unless it lists its own

Scene keys are the fields of :class:`appliance.evaluation.robustness.Scene`, condition keys
those of :class:`~appliance.evaluation.robustness.Condition`. Any other key, a wrong type or
an out-of-range value raises :class:`MatrixFileError` (a ValueError: exit 2 in the CLI)
naming the file, the entry and the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
from pathlib import Path
from typing import Any

import yaml

from appliance.evaluation.robustness import Condition, Matrix, Scene

PARTS = ("dev", "holdout")
_TOP_KEYS = ("name", "n_frames", "voxel_m", "scenes", "conditions", "holdout")
_HOLDOUT_KEYS = ("scenes", "conditions")
#: Allowed ranges of numeric scene and condition keys (inclusive).
_RANGES: dict[str, tuple[float, float]] = {
    "release_rate_g_s": (0.01, 100.0), "distance_m": (1.0, 100.0), "depth_m": (1.44, 12.0),
    "noise_netd_k": (0.0, 1.0), "jitter_px": (0.0, 5.0), "gain_mismatch": (0.0, 1.0),
    "lens_k1": (-1.0, 1.0), "object_z_m": (1.0, 100.0), "t_gas_k": (100.0, 1000.0),
    "n_frames": (3, 1000),
    "voxel_m": (0.005, 0.2),
}


class MatrixFileError(ValueError):
    """The matrix file is invalid; the message names the file, entry and key."""


def is_matrix_file(text: str) -> bool:
    """Whether ``--matrix`` names a file (by its suffix or because it exists)."""
    return text.endswith((".yaml", ".yml", ".json")) or Path(text).is_file()


def _hint(key: str, choices: tuple[str, ...]) -> str:
    near = difflib.get_close_matches(key, choices, n=1)
    return f" (did you mean {near[0]!r}?)" if near else ""


def _check_keys(where: str, data: Any, allowed: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise MatrixFileError(f"{where}: expected a mapping, got {type(data).__name__}")
    for key in data:
        if key not in allowed:
            raise MatrixFileError(f"{where}: unknown key {key!r}{_hint(str(key), allowed)}; "
                                  f"allowed: {', '.join(allowed)}")
    return data


def _value(where: str, key: str, value: Any, default: Any) -> Any:
    """``value`` converted to the type of the field's ``default`` and range-checked."""
    kind = type(default)
    if key == "wind_m_s":
        if (not isinstance(value, list | tuple) or len(value) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           for v in value)):
            raise MatrixFileError(f"{where}: wind_m_s must be three numbers [X, Y, Z] in m/s, "
                                  f"got {value!r}")
        return tuple(float(v) for v in value)
    if kind is bool or key in ("moving_object", "calibrated", "realistic"):
        if not isinstance(value, bool):
            raise MatrixFileError(f"{where}: {key} must be true or false, got {value!r}")
        return value
    if kind is str or key in ("name", "background"):
        if not isinstance(value, str) or not value:
            raise MatrixFileError(f"{where}: {key} must be a non-empty string, got {value!r}")
        if key == "background" and value not in ("uniform", "plant", "sky"):
            raise MatrixFileError(f"{where}: background must be uniform, plant or sky, "
                                  f"got {value!r}")
        return value
    if value is None and default is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MatrixFileError(f"{where}: {key} must be a number, got {value!r}")
    if key in ("seed", "n_frames"):
        if int(value) != value:
            raise MatrixFileError(f"{where}: {key} must be an integer, got {value!r}")
        value = int(value)
    lo, hi = _RANGES.get(key, (-1e9, 1e9))
    if not lo <= value <= hi:
        raise MatrixFileError(f"{where}: {key} must be within {lo:g}..{hi:g}, got {value!r}")
    return value if key in ("seed", "n_frames") else float(value)


def _build(cls: type, where: str, data: Any, required: tuple[str, ...]) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    data = _check_keys(where, data, tuple(fields))
    for key in required:
        if key not in data:
            raise MatrixFileError(f"{where}: missing key {key!r}")
    kwargs = {}
    for key, value in data.items():
        f = fields[key]
        default = f.default if f.default is not dataclasses.MISSING else (
            (0.0, 0.0, 0.0) if key == "wind_m_s" else 0 if key == "seed" else "")
        kwargs[key] = _value(where, key, value, default)
    return cls(**kwargs)


def _entries(where: str, data: Any) -> list[Any]:
    if not isinstance(data, list) or not data:
        raise MatrixFileError(f"{where}: expected a non-empty list")
    return data


def _scenes(where: str, data: Any) -> tuple[Scene, ...]:
    scenes = tuple(_build(Scene, f"{where}[{i}]", s, ("seed", "wind_m_s"))
                   for i, s in enumerate(_entries(where, data)))
    _check_unique(f"{where}: the same scene twice", [s.name for s in scenes])
    return scenes


def _conditions(where: str, data: Any) -> tuple[Condition, ...]:
    conds = tuple(_build(Condition, f"{where}[{i}]", c, ("name",))
                  for i, c in enumerate(_entries(where, data)))
    _check_unique(f"{where}: condition names must be unique", [c.name for c in conds])
    return conds


def _check_unique(message: str, names: list[str]) -> None:
    """MatrixFileError ``message: <the repeated names>`` if a name appears twice."""
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise MatrixFileError(f"{message}: {', '.join(dup)}")


def read_document(path: Path) -> Any:
    """The file's content (JSON for ``.json``, YAML otherwise); MatrixFileError if it
    cannot be read or parsed."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise MatrixFileError(f"cannot read matrix file {path}: {exc}") from None
    try:
        return json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise MatrixFileError(f"{path}: not valid {'JSON' if path.suffix == '.json' else 'YAML'}"
                              f": {exc}") from None


def load_matrix(path: Path, part: str = "dev") -> Matrix:
    """The ``part`` (``dev``: the main scenes; ``holdout``: the hold-out section) of a
    matrix file as a :class:`Matrix`. Both parts are validated whichever is asked for.

    Raises
    ------
    MatrixFileError
        Unreadable file, invalid content, or no hold-out section when ``part`` asks for it.
    """
    if part not in PARTS:
        raise MatrixFileError(f"unknown part {part!r}; choose from {', '.join(PARTS)}")
    where = str(path)
    doc = _check_keys(where, read_document(path), _TOP_KEYS)
    for key in ("scenes", "conditions"):
        if key not in doc:
            raise MatrixFileError(f"{where}: missing key {key!r}")
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise MatrixFileError(f"{where}: name must be a non-empty string, got {name!r}")
    n_frames = _value(where, "n_frames", doc.get("n_frames", 14), 14)
    voxel = _value(where, "voxel_m", doc.get("voxel_m", 0.05), 0.05)
    conditions = _conditions(f"{where}: conditions", doc["conditions"])
    dev = Matrix(name=name, scenes=_scenes(f"{where}: scenes", doc["scenes"]),
                 conditions=conditions, n_frames=n_frames, voxel_m=voxel)
    hold = None
    if "holdout" in doc:
        h = _check_keys(f"{where}: holdout", doc["holdout"], _HOLDOUT_KEYS)
        if "scenes" not in h:
            raise MatrixFileError(f"{where}: holdout: missing key 'scenes'")
        scenes = _scenes(f"{where}: holdout.scenes", h["scenes"])
        shared = sorted({s.name for s in scenes} & {s.name for s in dev.scenes})
        if shared:
            raise MatrixFileError(f"{where}: holdout.scenes repeats development scenes: "
                                  f"{', '.join(shared)}")
        conds = (_conditions(f"{where}: holdout.conditions", h["conditions"])
                 if "conditions" in h else conditions)
        hold = Matrix(name=f"{name} holdout", scenes=scenes, conditions=conds,
                      n_frames=n_frames, voxel_m=voxel)
    if part == "holdout":
        if hold is None:
            raise MatrixFileError(f"{where}: no holdout section")
        return hold
    return dev
