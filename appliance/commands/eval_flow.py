"""``ogiflow eval flow``: optical-flow accuracy and speed on Middlebury-layout data.

The argparse layer and the printed tables; the evaluation is
:func:`appliance.evaluation.flow.evaluate_flow` (its docstring says what is measured).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from appliance.cli import command_group


def register(root: argparse._SubParsersAction) -> None:
    group = command_group(root, "eval", "evaluate the methods against reference data")
    p = group.add_parser(
        "flow",
        help="optical-flow AEE and runtime on Middlebury-layout sequences",
        description=(
            "Every subfolder of --dataset holding frame10.png, frame11.png and flow10.flo "
            "is one sequence. Our Brox flow (paper Eq. 5) and, in the same run, OpenCV "
            "Farneback and DIS (medium) are scored by the average endpoint error over "
            "pixels with known ground truth and timed (median of --repeats runs after one "
            "warm-up), all on one thread."
        ),
    )
    p.add_argument("--dataset", required=True, type=Path,
                   help="folder whose subfolders hold frame10.png, frame11.png, flow10.flo")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<sequence>": {"<method>": {"aee": px, "ms": ms}}} here')
    p.add_argument("--alpha", type=float, default=0.05, help="smoothness weight (paper: 0.05)")
    p.add_argument("--beta", type=float, default=0.1,
                   help="gradient-constancy weight (paper: 0.1)")
    p.add_argument("--grid", action="store_true",
                   help="also run the alpha x beta grid of the paper's Table 1 (Brox only)")
    p.add_argument("--repeats", type=int, default=3,
                   help="timed runs per method and sequence after one warm-up (default 3)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation.flow import (
        evaluate_flow,
        flow_methods,
        format_grid,
        format_table,
    )

    def show(seq: str, name: str, scores: dict[str, float]) -> None:
        print(f"  {seq:12s} {name:28s} AEE {scores['aee']:.3f} px  {scores['ms']:8.1f} ms",
              flush=True)

    results = evaluate_flow(args.dataset, flow_methods(args.alpha, args.beta, args.grid),
                            args.repeats, on_result=show)
    print()
    print(format_table(results))
    if args.grid:
        print()
        print(format_grid(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
        print(f"\nwrote {args.json}")
    return 0
