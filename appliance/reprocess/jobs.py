"""What a reprocessing run has to do: inputs, parameter combinations, jobs and their keys.

A *job* is one input recording processed with one parameter combination; it yields one
output MCAP file. Jobs are named by a key that hashes everything their result depends on
(the input's path and size, the overrides, the segmenting, the fields interval, the
calibration file), so a re-run finds the work of an earlier run and a changed input or
parameter is never confused with it.
"""

from __future__ import annotations

import glob
import hashlib
import itertools
import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from appliance.paths import walk
from appliance.reprocess.source import parse_override

#: Recordings the appliance writes (closed) or left open when killed (``.active``).
RECORDING_SUFFIXES = (".mcap", ".mcap.active")


def expand_inputs(inputs: Iterable[str], exclude: Path | None = None) -> list[Path]:
    """MCAP files named by ``inputs``: files, folders (searched recursively) or globs.

    Files under ``exclude`` (the output folder) are left out; the result is sorted and
    without duplicates. ValueError names an input that matches nothing.
    """
    found: set[Path] = set()
    skip = exclude.resolve() if exclude is not None else None
    for text in inputs:
        named = [Path(p) for p in glob.glob(text, recursive=True)] if glob.has_magic(text) \
            else [Path(text)]
        matches = []
        for path in named:
            if path.is_dir():
                matches += [p for p in walk(path) if p.name.endswith(RECORDING_SUFFIXES)]
            else:
                matches.append(path)
        matches = [p.resolve() for p in matches if p.is_file()]
        matches = [p for p in matches if skip is None or not p.is_relative_to(skip)]
        if not matches:
            raise ValueError(f"{text}: no MCAP recording there")
        found.update(matches)
    return sorted(found)


def split_values(raw: str) -> list[str]:
    """Split a ``--param`` value list at top-level commas (not inside [], {} or quotes)."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(raw):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(raw[start:i])
            start = i + 1
    parts.append(raw[start:])
    return [p.strip() for p in parts]


def parameter_grid(params: Sequence[str]) -> list[dict[str, Any]]:
    """Every combination of ``KEY=V1,V2,...`` overrides (values in YAML syntax).

    ``["alpha=0.05,0.1", "nu=0.5"]`` -> ``[{alpha: 0.05, nu: 0.5}, {alpha: 0.1, nu: 0.5}]``;
    no ``--param`` gives one empty combination (the recorded parameters).
    """
    axes: dict[str, list[Any]] = {}
    for text in params:
        key, raw = parse_override(text)
        if key in axes:
            raise ValueError(f"--param {key} given twice; list its values once: {key}=V1,V2")
        axes[key] = [yaml.safe_load(v) for v in split_values(raw)]
    keys = list(axes)
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*axes.values())]


def combo_label(combo: dict[str, Any], swept: Sequence[str]) -> str:
    """File-name part of a combination: the swept keys, e.g. ``alpha=0.1,nu=0.5``."""
    text = ",".join(f"{k}={combo[k]}" for k in swept)
    return re.sub(r"[^A-Za-z0-9_.,=+-]", "_", text)


@dataclass(frozen=True)
class Job:
    """One input with one parameter combination -> one output file."""

    input: Path
    size: int
    overrides: dict[str, Any]
    label: str
    segment_s: float
    fields_every: int
    calibration: Path | None

    @property
    def key(self) -> str:
        text = json.dumps([str(self.input), self.size, self.overrides, self.segment_s,
                           self.fields_every, str(self.calibration)], sort_keys=True,
                          default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    def output(self, out_dir: Path, appliance_id: str) -> Path:
        """``OUT/<appliance id>/<input stem>[__<label>].mcap``."""
        stem = self.input.name.removesuffix(".active").removesuffix(".mcap")
        name = f"{stem}__{self.label}.mcap" if self.label else f"{stem}.mcap"
        return out_dir / re.sub(r"[^A-Za-z0-9_.-]", "_", appliance_id) / name


def make_jobs(inputs: Sequence[Path], grid: Sequence[dict[str, Any]], *, segment_s: float,
              fields_every: int, calibration: Path | None) -> list[Job]:
    """Jobs for every input and combination (inputs outer, combinations inner)."""
    swept = [k for k in (grid[0] if grid else {}) if len({repr(c[k]) for c in grid}) > 1]
    return [Job(p, p.stat().st_size, dict(c), combo_label(c, swept), segment_s, fields_every,
                calibration) for p in inputs for c in grid]
