"""Per-frame summaries and wind of an appliance log as table rows, and as Parquet.

``ogiflow export`` writes these rows as CSV, NPZ or Parquet; ``ogiflow reprocess`` writes
one Parquet table over all its inputs. Parquet goes through pyarrow (already installed
with rerun-sdk), and pandas (``pd.read_parquet``), polars (``pl.read_parquet``) and DuckDB
(``SELECT * FROM 'file.parquet'``) read the file as it is. Times are kept as integer ns and
also given as a UTC timestamp column ``time``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

SUMMARY_COLUMNS = (
    "t_wall_ns", "t_mono_ns", "pair_index", "valid", "vx_m_s", "vy_m_s", "vz_m_s", "speed_m_s",
    "angle_x_deg", "angle_y_deg", "angle_z_deg", "gas_pixels", "c_usf", "latency_ms",
    "skipped_pairs", "flags",
)
WIND_COLUMNS = ("t_wall_ns", "t_mono_ns", "source", "pair_index", "valid", "x_m_s", "y_m_s",
                "z_m_s", "speed_m_s", "status")
#: Summary keys passed through as they are when a recording has them (emission rates).
PASS_THROUGH_PREFIX = "emission"

_INT = ("t_wall_ns", "t_mono_ns", "pair_index", "gas_pixels", "skipped_pairs")
_BOOL = ("valid",)
_STR = ("flags", "source", "status", "appliance_id", "input", "parameters")


def _vec(v: Any) -> list[float | None]:
    return [None, None, None] if v is None else [float(x) for x in v]


def summary_row(m: Mapping[str, Any]) -> dict[str, Any]:
    """One ``/sceneflow/summary`` message as a row of :data:`SUMMARY_COLUMNS` (+ emission)."""
    v = _vec(m.get("mean_velocity_m_s"))
    a = _vec(m.get("angles_deg"))
    row = {
        "t_wall_ns": m["t_wall_ns"], "t_mono_ns": m["t_mono_ns"], "pair_index": m["pair_index"],
        "valid": bool(m["valid"]), "vx_m_s": v[0], "vy_m_s": v[1], "vz_m_s": v[2],
        "speed_m_s": m.get("speed_m_s"), "angle_x_deg": a[0], "angle_y_deg": a[1],
        "angle_z_deg": a[2], "gas_pixels": m.get("gas_pixels"), "c_usf": m.get("c_usf"),
        "latency_ms": m.get("latency_ms"), "skipped_pairs": m.get("skipped_pairs"),
        "flags": ";".join(m.get("flags") or []),
    }
    for key, value in m.items():
        if key.startswith(PASS_THROUGH_PREFIX):
            # lists of words (the rate's flags) as one string, like ``flags``
            row[key] = ";".join(value) if isinstance(value, list) else value
    return row


def summary_columns(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """:data:`SUMMARY_COLUMNS` and the pass-through (emission) keys any row has, in order."""
    cols = list(SUMMARY_COLUMNS)
    for r in rows:
        cols.extend(k for k in r if k not in cols)
    return cols


def wind_row(topic: str, m: Mapping[str, Any]) -> dict[str, Any]:
    """A ``/wind/raw`` or ``/wind/camera`` message as a row of :data:`WIND_COLUMNS`."""
    if topic == "/wind/raw":
        v = [m.get("u"), m.get("v"), m.get("w")]
        speed = float(np.linalg.norm(v)) if None not in v else None
        return {"t_wall_ns": m["t_wall_ns"], "t_mono_ns": m["t_mono_ns"], "source": "sensor",
                "pair_index": None, "valid": bool(m.get("valid")), "x_m_s": v[0],
                "y_m_s": v[1], "z_m_s": v[2], "speed_m_s": speed, "status": m.get("status")}
    v = _vec(m.get("velocity_m_s"))
    return {"t_wall_ns": m["t_wall_ns"], "t_mono_ns": m["t_mono_ns"], "source": "camera_frame",
            "pair_index": m.get("pair_index"), "valid": True, "x_m_s": v[0], "y_m_s": v[1],
            "z_m_s": v[2], "speed_m_s": m.get("speed_m_s"), "status": None}


def to_arrow(rows: Sequence[Mapping[str, Any]], columns: Iterable[str]) -> Any:
    """A ``pyarrow.Table`` of ``rows``: ``columns`` first, then any other keys rows have.

    Integer, boolean and text columns get their types; everything else is float64 (None
    -> null). A ``t_wall_ns`` column also gives a ``time`` column (timestamp ns, UTC).
    """
    # pyarrow only for the tables of export and reprocess (not the daemon).
    import pyarrow as pa

    names = list(columns)
    for r in rows:
        names.extend(k for k in r if k not in names)
    arrays: dict[str, Any] = {}
    for name in names:
        values = [r.get(name) for r in rows]
        if name in _INT:
            arrays[name] = pa.array(values, type=pa.int64())
        elif name in _BOOL:
            arrays[name] = pa.array(values, type=pa.bool_())
        elif name in _STR or any(isinstance(v, str) for v in values):
            arrays[name] = pa.array([None if v is None else str(v) for v in values],
                                    type=pa.string())
        else:
            arrays[name] = pa.array([None if v is None else float(v) for v in values],
                                    type=pa.float64())
        if name == "t_wall_ns":
            arrays["time"] = arrays[name].cast(pa.timestamp("ns", tz="UTC"))
    return pa.table(arrays)


def write_parquet(path: Path, rows: Sequence[Mapping[str, Any]], columns: Iterable[str]) -> Path:
    """Write ``rows`` (see :func:`to_arrow`) as one Parquet file (zstd), atomically."""
    # pyarrow only for the tables of export and reprocess (not the daemon).
    import pyarrow.parquet as pq

    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(f".{path.name}.part")
    pq.write_table(to_arrow(rows, columns), part, compression="zstd")
    part.replace(path)
    return path
