"""``ogiflow export``: per-frame gas-velocity summaries and wind out of an MCAP log.

Writes, for ``--to csv``, two files ``<OUT>_summary.csv`` (one row per processed stereo
pair: time, mean 3D gas velocity in the left camera frame, speed, directional angles,
gas pixels, c_USF, validity and flags) and ``<OUT>_wind.csv`` (one row per wind sample in
the sensor's axes, and the wind in the camera frame at each processed pair), or for
``--to npz`` one ``<OUT>.npz`` with the same columns as arrays. Rows whose ``valid`` is
false must not be used as measurements; ``flags`` says why. A recording cut by a crash is
exported up to the cut (and the command says so).
"""

from __future__ import annotations

import argparse
import csv
import sys
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


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("export", help="export per-frame summaries and wind to CSV or NPZ",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="recording to read")
    p.add_argument("--to", choices=("csv", "npz"), required=True, help="output format")
    p.add_argument("--out", type=Path, default=None,
                   help="output path prefix (default: FILE without .mcap)")
    p.set_defaults(func=run)


def _vec(v: Any) -> list[float | None]:
    return [None, None, None] if v is None else [float(x) for x in v]


def summary_row(m: dict[str, Any]) -> dict[str, Any]:
    v = _vec(m.get("mean_velocity_m_s"))
    a = _vec(m.get("angles_deg"))
    return {
        "t_wall_ns": m["t_wall_ns"], "t_mono_ns": m["t_mono_ns"], "pair_index": m["pair_index"],
        "valid": bool(m["valid"]), "vx_m_s": v[0], "vy_m_s": v[1], "vz_m_s": v[2],
        "speed_m_s": m.get("speed_m_s"), "angle_x_deg": a[0], "angle_y_deg": a[1],
        "angle_z_deg": a[2], "gas_pixels": m.get("gas_pixels"), "c_usf": m.get("c_usf"),
        "latency_ms": m.get("latency_ms"), "skipped_pairs": m.get("skipped_pairs"),
        "flags": ";".join(m.get("flags") or []),
    }


def wind_row(topic: str, m: dict[str, Any]) -> dict[str, Any]:
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


def run(args: argparse.Namespace) -> int:
    from appliance.progress import ProgressBar
    from appliance.recording.reader import iter_json

    if not args.file.is_file():
        raise ValueError(f"{args.file}: no such file")
    out = args.out if args.out is not None else args.file.with_suffix("")
    reader, messages = iter_json(args.file, ("/sceneflow/summary", "/wind/raw", "/wind/camera"))
    progress = ProgressBar("export")
    summaries: list[dict[str, Any]] = []
    winds: list[dict[str, Any]] = []
    for n, (topic, m) in enumerate(messages):
        if topic == "/sceneflow/summary":
            summaries.append(summary_row(m))
        else:
            winds.append(wind_row(topic, m))
        if n % 500 == 0:
            progress(reader.bytes_read, reader.size)
    progress(reader.size, reader.size)
    if args.to == "csv":
        paths = [Path(f"{out}_summary.csv"), Path(f"{out}_wind.csv")]
        for path, rows, cols in ((paths[0], summaries, SUMMARY_COLUMNS),
                                 (paths[1], winds, WIND_COLUMNS)):
            with open(path, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=cols)
                w.writeheader()
                w.writerows(rows)
    else:
        paths = [Path(f"{out}.npz")]
        arrays: dict[str, np.ndarray] = {}
        for prefix, rows, cols in (("summary", summaries, SUMMARY_COLUMNS),
                                   ("wind", winds, WIND_COLUMNS)):
            for c in cols:
                values = [r[c] for r in rows]
                if c in ("flags", "source", "status"):
                    arrays[f"{prefix}_{c}"] = np.array(["" if v is None else str(v)
                                                        for v in values])
                else:
                    arrays[f"{prefix}_{c}"] = np.array(
                        [np.nan if v is None else v for v in values], dtype=np.float64)
        np.savez_compressed(paths[0], **arrays)
    valid = sum(1 for r in summaries if r["valid"])
    print(f"exported {len(summaries)} summaries ({valid} valid) and {len(winds)} wind rows "
          f"to {', '.join(map(str, paths))}")
    if reader.truncated:
        print(f"warning: {args.file} ends early (cut by a crash?): exported everything up to "
              f"the cut; `ogiflow recover {args.file}` repairs the file", file=sys.stderr)
    return 0
