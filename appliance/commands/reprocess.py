"""``ogiflow reprocess``: many recordings, all cores or a Ray cluster, resumable.

Each INPUT (MCAP files, folders searched recursively, or globs; ``.mcap.active`` files left
by a crash are included and processed up to their cut) is cut into time segments of
``--segment-s`` seconds; every segment runs as one Ray task with the same chain as
``ogiflow replay`` and starts cold, so the results equal ``ogiflow replay --fast
--segment-s S`` on the same file. Per input and parameter combination one result MCAP
(``OUT/<appliance>/<name>[__<params>].mcap``, the content ``ogiflow replay`` writes), and over
everything one table ``OUT/summaries.parquet`` of per-frame summaries (appliance id, input,
swept parameters, time, velocity, angles, gas pixels, c_USF, flags).

``--param KEY=V1,V2`` sweeps: one output per combination of all listed values.
``OUT/manifest.jsonl`` records finished segments: after Ctrl-C or a lost node the same
command does only what is missing. Needs Ray (``pip install 'ogiflow[cluster]'``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from appliance.cli import EXIT_FAILURE, EXIT_INTERRUPTED
from appliance.progress import ProgressBar


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("reprocess", help="reprocess many recordings on all cores or a Ray "
                        "cluster (resumable), with a Parquet table of all summaries",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="MCAP file, folder (searched recursively) or glob")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="Ray cluster: 'auto' (on a cluster node) or ray://HOST:10001 "
                        "(default: a local Ray on all cores of this machine)")
    p.add_argument("--num-cpus", type=int, default=None, metavar="N",
                   help="cores of the local Ray (default: all); ignored with --address")
    p.add_argument("--param", metavar="KEY=V1,V2,...", action="append", default=[],
                   help="override a chain parameter; a comma list sweeps it (repeatable)")
    p.add_argument("--segment-s", type=float, default=60.0, metavar="S",
                   help="segment length in seconds of recording (default 60)")
    p.add_argument("--calibration", type=Path, default=None,
                   help="stereo calibration file to use instead of the recorded geometry")
    p.add_argument("--fields-every", type=int, default=1, metavar="N",
                   help="record the full fields of every N-th triple (default 1: all)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.reprocess.jobs import expand_inputs, make_jobs, parameter_grid
    from appliance.reprocess.runner import Runner, import_ray, print_summary

    import_ray()  # before any work: a clear message when the extra is missing
    if not args.segment_s > 0:
        raise ValueError(f"--segment-s must be > 0, got {args.segment_s}")
    if args.fields_every < 1:
        raise ValueError(f"--fields-every must be >= 1, got {args.fields_every}")
    if args.calibration is not None and not args.calibration.is_file():
        raise ValueError(f"{args.calibration}: no such file")
    inputs = expand_inputs(args.inputs, exclude=args.out)
    grid = parameter_grid(args.param)
    _check_parameters(grid)
    jobs = make_jobs(inputs, grid, segment_s=args.segment_s, fields_every=args.fields_every,
                     calibration=args.calibration.resolve() if args.calibration else None)
    swept = [k for k in grid[0] if len({repr(c[k]) for c in grid}) > 1]
    runner = Runner(jobs, args.out.resolve(), address=args.address,
                    num_cpus=None if args.address else (args.num_cpus or os.cpu_count()),
                    progress=ProgressBar("reprocess", unit="triples", rate=True))
    summary = runner.run()
    table = runner.write_table(swept)
    print_summary(summary, table)
    if summary.interrupted:
        print("interrupted: finished segments are kept; run the same command again to do "
              "the rest")
        return EXIT_INTERRUPTED
    return EXIT_FAILURE if summary.failed_segments or summary.bad_inputs else 0


def _check_parameters(grid: list[dict]) -> None:
    """Unknown or invalid parameter values fail now, not in every task."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.chain import ChainParameters

    for combo in grid:
        ChainParameters.from_mapping(combo)
