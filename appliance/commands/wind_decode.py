"""``ogiflow wind decode``: decode a captured anemometer byte stream and count what it holds."""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

from appliance import cli
from drivers.anemometer.registry import PROTOCOLS, make_decoder

COUNT_LABELS = (
    ("valid", "valid samples"),
    ("messages", "messages decoded (valid or flagged)"),
    ("checksum_failures", "checksum failures"),
    ("malformed", "malformed messages"),
    ("status_errors", "status errors (sensor-flagged)"),
    ("resyncs", "resyncs"),
    ("counter_gaps", "counter gaps"),
    ("missed_records", "records missed in counter gaps"),
    ("skipped_bytes", "bytes skipped between messages"),
)

#: Columns of the CSV and keys of each JSON sample (host_ns is meaningless offline).
COLUMNS = (
    "index",
    "counter",
    "u",
    "v",
    "w",
    "speed_of_sound",
    "sonic_temperature",
    "status_code",
    "status_text",
    "valid",
)


def register(root: argparse._SubParsersAction) -> None:
    group = cli.command_group(root, "wind", "anemometer tools: decode captured serial streams")
    p = group.add_parser(
        "decode",
        help="decode a captured anemometer byte stream",
        description=(
            "Decode a file holding an anemometer's serial bytes (bytes between messages, such "
            "as a logger's time prefix, are skipped) and print counts: valid samples, "
            "checksum failures, malformed messages, sensor status errors, resyncs and device "
            "counter gaps. Samples (u, v, w in m/s in the sensor's own axes, speed of sound, "
            "sonic temperature, status) can be written as CSV or JSON. Exit code 1 when the "
            "file holds no decodable message (wrong --protocol?)."
        ),
    )
    p.add_argument(
        "--protocol", required=True, choices=sorted(PROTOCOLS), help="the sensor's output protocol"
    )
    p.add_argument("file", type=Path, metavar="FILE", help="captured byte stream")
    p.add_argument(
        "--json",
        type=Path,
        metavar="OUT",
        help='write {"counts": {...}, "samples": [...]} to OUT (NaN as null)',
    )
    p.add_argument("--csv", type=Path, metavar="OUT", help="write the samples as CSV to OUT")
    p.set_defaults(func=run)


def _clean(value: object) -> object:
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def decode_file(protocol: str, path: Path) -> tuple[dict[str, int], list[dict[str, object]]]:
    """Decode ``path`` with ``protocol``; return (counts, samples as dicts of COLUMNS)."""
    decoder = make_decoder(protocol)
    samples = []
    with path.open("rb") as fh:
        while chunk := fh.read(1 << 16):
            samples.extend(decoder.feed(chunk, 0))
    samples.extend(decoder.flush())
    rows = []
    for i, s in enumerate(samples):
        d = s.as_dict()
        d.pop("host_ns")
        rows.append({"index": i, **{k: _clean(v) for k, v in d.items()}})
    return decoder.counts.as_dict(), rows


def run(args: argparse.Namespace) -> int:
    if not args.file.is_file():
        raise ValueError(f"no such file: {args.file}")
    counts, rows = decode_file(args.protocol, args.file)
    print(f"{args.file}: protocol {args.protocol}")
    for key, label in COUNT_LABELS:
        print(f"  {label:<40} {counts[key]:>9}")
    if args.json:
        # One sample per line: valid JSON that still diffs well as a golden file.
        body = ",\n".join(json.dumps(r, separators=(",", ":")) for r in rows)
        args.json.write_text(
            f'{{"protocol": {json.dumps(args.protocol)}, "counts": {json.dumps(counts)}, '
            f'"samples": [\n{body}\n]}}\n'
        )
        print(f"wrote {len(rows)} samples to {args.json}")
    if args.csv:
        with args.csv.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=COLUMNS)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: "" if row[k] is None else row[k] for k in COLUMNS})
        print(f"wrote {len(rows)} samples to {args.csv}")
    if counts["messages"] == 0 and args.file.stat().st_size > 0:
        raise cli.CommandError(
            f"no {args.protocol} message found in {args.file} (wrong --protocol?)"
        )
    return cli.EXIT_OK
