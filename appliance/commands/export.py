"""``ogiflow export``: per-frame gas-velocity summaries and wind out of an MCAP log.

Writes, for ``--to csv``, two files ``<OUT>_summary.csv`` (one row per processed stereo
pair: time, mean 3D gas velocity in the left camera frame, speed, directional angles,
gas pixels, c_USF, validity and flags) and ``<OUT>_wind.csv`` (one row per wind sample in
the sensor's axes, and the wind in the camera frame at each processed pair), or for
``--to npz`` one ``<OUT>.npz`` with the same columns as arrays, or for ``--to parquet``
``<OUT>_summary.parquet`` and ``<OUT>_wind.parquet`` (pandas, polars and DuckDB read them
directly; times also as a UTC ``time`` column). Rows whose ``valid`` is
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

from appliance.progress import ProgressBar


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("export", help="export per-frame summaries and wind to CSV, NPZ or Parquet",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="recording to read")
    p.add_argument("--to", choices=("csv", "npz", "parquet"), required=True,
                   help="output format")
    p.add_argument("--out", type=Path, default=None,
                   help="output path prefix (default: FILE without .mcap)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.recording.reader import iter_json
    from appliance.recording.tables import (
        SUMMARY_COLUMNS,
        WIND_COLUMNS,
        summary_columns,
        summary_row,
        wind_row,
        write_parquet,
    )

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
    summary_cols = summary_columns(summaries)  # the emission columns when recorded
    if args.to == "csv":
        paths = [Path(f"{out}_summary.csv"), Path(f"{out}_wind.csv")]
        for path, rows, cols in ((paths[0], summaries, summary_cols),
                                 (paths[1], winds, WIND_COLUMNS)):
            with open(path, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
                w.writeheader()
                w.writerows(rows)
    elif args.to == "parquet":
        paths = [write_parquet(Path(f"{out}_summary.parquet"), summaries, SUMMARY_COLUMNS),
                 write_parquet(Path(f"{out}_wind.parquet"), winds, WIND_COLUMNS)]
    else:
        paths = [Path(f"{out}.npz")]
        arrays: dict[str, np.ndarray] = {}
        for prefix, rows, cols in (("summary", summaries, summary_cols),
                                   ("wind", winds, WIND_COLUMNS)):
            for c in cols:
                values = [r.get(c) for r in rows]
                if c in ("flags", "source", "status") or any(isinstance(v, str)
                                                             for v in values):
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
