"""``ogiflow eval robustness``: scene-flow accuracy under field disturbances.

A thin argparse layer over :mod:`appliance.evaluation.robustness`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from appliance import cli


def register(root: argparse._SubParsersAction) -> None:
    """Add ``eval robustness`` to the ``eval`` group."""
    group = cli.command_group(root, "eval", "evaluate the processing against reference data")
    p = group.add_parser(
        "robustness",
        help="3D velocity accuracy of the chain under noise, jitter, radiometric mismatch, "
             "moving objects, low contrast and sky backgrounds",
        description=(
            "Simulate the matrix's field scenes once each (cached), render every condition "
            "of the matrix (camera effects after the fluid step) and run the scene-flow "
            "chain on every triple. Prints per condition RMVE and AEMV (mean +- std over "
            "all triples of all scenes, and the worst scene's mean), 3D AEE, SA, the "
            "fraction of segmented pixels that are not gas and the chain's flags; then "
            "the realistic conditions that miss the acceptance targets (exit 0 either "
            "way: this is a measurement)."
        ),
        epilog="example: ogiflow eval robustness --json robustness.json",
    )
    p.add_argument("--matrix", default="default",
                   help="named matrix: default (24 conditions x 4 scenes x 14 frames, "
                        "about 10-20 min on 2 cores), quick (3 conditions, 1 scene) or "
                        "holdout (the 11 realistic conditions on 8 scenes of 4 other "
                        "seeds); or a matrix file (.yaml/.yml/.json: scenes x conditions, "
                        "an optional holdout section; see benchmarks/matrices/wide.yaml)")
    p.add_argument("--part", choices=("dev", "holdout"), default="dev",
                   help="with a matrix file: its development scenes (default) or its "
                        "hold-out section")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="run the chain exactly as `ogiflow run --config FILE` does: the "
                        "file's processing.parameters over the scene's gas depth band "
                        "(d0, SGM range). Without it: the band and the field solver options "
                        "(disparity_options n_warps 3, n_inner 4, n_inner_finest 6, n_sor 15)")
    p.add_argument("--workers", type=int, choices=(1, 2), default=None,
                   help="take the triples as this many of the daemon's workers do: 1 (one "
                        "chain state, every triple) or 2 (two states alternating, each "
                        "warm-started two frames back). Default: the --config file's "
                        "processing.workers, else 1")
    p.add_argument("--condition", action="append", metavar="NAME",
                   help="evaluate only this condition of the matrix (repeatable)")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the results as JSON")
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="where simulated gas frames are cached (default "
                        "~/.cache/ogiflow/robustness)")
    p.add_argument("--no-cache", action="store_true", help="simulate without caching")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate the matrix; print the table and the acceptance check, write JSON."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation import robustness as rb
    from appliance.evaluation.matrix_file import is_matrix_file, load_matrix
    from appliance.evaluation.sceneflow import configured_workers
    from appliance.evaluation.sceneflow_setup import load_processing
    from appliance.runtime.simsite import cache_root

    if is_matrix_file(args.matrix):
        matrix = load_matrix(Path(args.matrix), args.part)
    elif args.matrix not in rb.MATRICES:
        raise ValueError(f"unknown --matrix {args.matrix!r}; choose from "
                         f"{', '.join(rb.MATRICES)} or give a .yaml/.json matrix file")
    elif args.part != "dev":
        raise ValueError("--part applies to a matrix file; the named matrices are "
                         "default, quick and holdout")
    else:
        matrix = rb.MATRICES[args.matrix]
    hook = None
    workers = 1 if args.workers is None else args.workers
    if args.config is not None:
        processing = load_processing(args.config)
        if args.workers is None:
            workers = configured_workers(processing.workers, str(args.config))

        def hook(params: Any) -> Any:
            # the daemon's parameters: the scene's band under the file's parameters
            return processing.chain_parameters({"d0": params.d0, "sgm_num_disparities":
                                                params.sgm_num_disparities})
    cache = None if args.no_cache else (args.cache_dir or cache_root(None) / "robustness")

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results = rb.run_matrix(matrix, cache, conditions=args.condition, params_hook=hook,
                           log=log, workers=workers)
    chain = (f"chain as `ogiflow run --config {args.config}`" if args.config is not None
             else "chain: the gas depth band and the field solver options")
    chain += (", one worker (every triple warm from the one before)" if workers == 1 else
              ", two workers (every other triple each, warm from two frames back)")
    print(f"Scene-flow robustness, matrix {matrix.name!r}: {len(matrix.scenes)} scene(s) x "
          f"{matrix.n_frames} frames; pooled over every triple; {chain}")
    print(rb.format_table(results))
    misses = rb.acceptance(results)
    if misses:
        print("acceptance (realistic conditions): missed")
        for m in misses:
            print(f"  {m}")
    else:
        print("acceptance (realistic conditions): met")
    if args.json is not None:
        try:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(rb.public(results), indent=1) + "\n")
        except OSError as exc:
            raise cli.CommandError(f"cannot write {args.json}: {exc}") from exc
    return cli.EXIT_OK
