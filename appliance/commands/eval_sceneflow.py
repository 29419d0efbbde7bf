"""``ogiflow eval sceneflow``: 3D gas velocity accuracy on synthetic sequences (paper Table 3).

A thin argparse layer over :mod:`appliance.evaluation.sceneflow` (the evaluation) and
:mod:`appliance.evaluation.sceneflow_figures` (the PNG figures).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from appliance import cli

#: Default folder of the sequences: where docs/accuracy.md's ``ogiflow simulate --out synthetic``
#: writes them (relative to the working directory). Generated data, so not under ``data/``,
#: which holds real reference recordings with provenance.
DEFAULT_DATA = Path("synthetic")

def register(root: argparse._SubParsersAction) -> None:
    """Add ``eval sceneflow`` to the ``eval`` group."""
    group = cli.command_group(root, "eval", "evaluate the processing against reference data")
    p = group.add_parser(
        "sceneflow",
        help="3D velocity accuracy of the chain and two baselines on synthetic sequences "
             "(paper Table 3)",
        description=(
            "Run the scene-flow chain (proposed method) and the SGM+Brox and SGM+Farneback "
            "baselines on every consecutive triple of every synthetic sequence in --data and "
            "compare with the ground truth: RMVE (relative error of the mean velocity's "
            "magnitude, %) and AEMV (angle of the mean velocity, deg) as mean +- std over "
            "the frames; 3D AEE (mm/s) and 3D AAE (deg, with Eq. 10's |V*.V|) over the gas "
            "region; c_USF (Eq. 8); SA (segmented / reference gas area, %); histogram "
            "correlations r_SF of V_X, V_Y, V_Z. Printed beside the paper's Table 3. "
            "Ideal conditions as in the paper: no registration, ideal rectified cameras."
        ),
        epilog="example: ogiflow simulate --out synthetic && ogiflow eval sceneflow "
               "--json table3.json --figures figures/",
    )
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help=f"folder holding sequence directories (default {DEFAULT_DATA}), or one "
                        "sequence directory")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<sequence>": {"<method>": {"rmve": .., ...}}} to this file')
    p.add_argument("--figures", type=Path, metavar="DIR",
                   help="write PNG figures: mean velocity per frame (computed vs reference) "
                        "and the velocity fields of one frame, per sequence")
    p.add_argument("--disparity-init", choices=("sgm", "d0"), default="sgm",
                   help="initial disparity of the joint solver: an SGM estimate (default) or "
                        "the constant minimum disparity --d0 (with the solver's default "
                        "iterations, a start ~17 px short leaves a d' bias of ~0.09 px, "
                        "i.e. V_Z errors of ~2 m/s at 1 ms frames; see docs/accuracy.md)")
    p.add_argument("--d0", type=float, default=60.0,
                   help="minimum disparity in px for the farthest expected gas, s*b/Z_max "
                        "(default 60 = 780 px * 0.2 m / 2.6 m): start of the SGM search "
                        "range, fill value of its holes")
    p.add_argument("--sgm-range", type=int, default=64,
                   help="width N of the SGM search range [d0, d0 + N) in px, multiple of 16, "
                        "for the chain's initialisation and the baselines (default 64: gas "
                        "between s*b/(d0 + 64) = 1.26 m and 2.6 m)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="evaluate only the first N triples of each sequence")
    p.set_defaults(func=run)

def run(args: argparse.Namespace) -> int:
    """Evaluate every sequence in --data; print the table, write JSON and figures."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation import sceneflow as ev
    from appliance.evaluation.sceneflow_figures import write_figures
    from processing.synthetic.storage import SequenceFormatError

    if args.sgm_range < 16 or args.sgm_range % 16:
        raise ValueError(f"--sgm-range must be a positive multiple of 16, got {args.sgm_range}")
    if not args.d0 >= 0:
        raise ValueError(f"--d0 must be >= 0 px, got {args.d0}")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    seqs = ev.find_sequences(args.data)
    params = ev.chain_parameters(args.disparity_init, args.d0, args.sgm_range)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results: dict[str, ev.Metrics] = {}
    for seq in seqs:
        log(f"evaluating {seq.name} ...")
        try:
            summary, fig = ev.evaluate_sequence(seq, params, max_triples=args.frames, log=log)
        except SequenceFormatError as exc:
            raise cli.CommandError(f"cannot read sequence {seq}: {exc}") from exc
        results[seq.name] = summary
        if args.figures is not None:
            try:
                paths = write_figures(args.figures, seq.name, summary, fig)
            except OSError as exc:
                raise cli.CommandError(str(exc)) from exc
            for path in paths:
                log(f"  wrote {path}")
    lo = math.floor(args.d0)
    init = (f"SGM over [{lo}, {lo + args.sgm_range}) px, holes {args.d0:g} px"
            if args.disparity_init == "sgm" else f"d0 = {args.d0:g} px")
    print(f"Scene flow on synthetic data (paper Table 3); disparity init: {init}; "
          f"means over triples")
    print(ev.format_table(results))
    for name, res in results.items():
        undef = {m: res[m]["undefined"] for m in ev.METHODS if res[m]["undefined"]}
        if undef:
            print(f"{name}: frames with undefined metrics (left out of the means): {undef}")
    if args.json is not None:
        cli.write_json(args.json, ev.public(results))
    return cli.EXIT_OK
