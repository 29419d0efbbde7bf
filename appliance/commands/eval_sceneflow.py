"""``ogiflow eval sceneflow``: 3D gas velocity accuracy on synthetic sequences (paper Table 3).

A thin argparse layer over :mod:`appliance.evaluation.sceneflow` (the evaluation) and
:mod:`appliance.evaluation.sceneflow_figures` (the PNG figures).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

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
            "The geometry (s, b, principal point), the frame interval and the gas depth band "
            "(hence d0 and the SGM range) come from each sequence's meta.json unless a flag "
            "gives them; the printout says where every value came from. --chain paper "
            "(default) runs the paper's ideal conditions; --chain appliance the site's chain."
        ),
        epilog="examples: ogiflow simulate --out synthetic && ogiflow eval sceneflow "
               "--json table3.json --figures figures/;  ogiflow simulate --preset field "
               "--jitter 0.3 --out seqs && ogiflow eval sceneflow --data seqs/field "
               "--chain appliance --config /etc/ogiflow/site.yaml",
    )
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help=f"folder holding sequence directories (default {DEFAULT_DATA}), or one "
                        "sequence directory")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<sequence>": {"<method>": {"rmve": .., ...}}} to this file')
    p.add_argument("--figures", type=Path, metavar="DIR",
                   help="write PNG figures: mean velocity per frame (computed vs reference) "
                        "and the velocity fields of one frame, per sequence")
    p.add_argument("--chain", choices=("paper", "appliance"), default="paper",
                   help="paper (default, for comparison with the paper's Table 3): the "
                        "paper's ideal conditions, no registration, the ideal cameras of "
                        "meta.json; appliance: exactly what `ogiflow run` runs on a site "
                        "(registration, depth gate, the parameters of --config over the "
                        "sequence's gas depth band, the sequence's calibration.yaml)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="with --chain appliance: the configuration file whose "
                        "processing.parameters the chain runs (default: the built-in "
                        "configuration, config/default.yaml)")
    geo = p.add_argument_group(
        "geometry and timing (default: each sequence's meta.json; a flag overrides it)")
    geo.add_argument("--focal-length", type=float, metavar="PX",
                     help="camera constant s in px")
    geo.add_argument("--baseline", type=float, metavar="M", help="stereo baseline b in m")
    geo.add_argument("--principal-point", type=float, nargs=2, metavar=("CX", "CY"),
                     help="principal point in px")
    geo.add_argument("--depth-band", type=float, nargs=2, metavar=("ZNEAR", "ZFAR"),
                     help="depth band of the gas in m (default: the simulated volume's); "
                          "gives d0 = floor(s b / ZFAR) and an SGM range of at least 64 px "
                          "reaching s b / ZNEAR")
    geo.add_argument("--frame-interval", type=float, metavar="S",
                     help="time between frames in s (re-stamps the frames)")
    geo.add_argument("--disparity-init", choices=("sgm", "d0"), default=None,
                     help="initial disparity of the joint solver: an SGM estimate (the "
                          "chain's default) or the constant minimum disparity d0 (with the "
                          "solver's default iterations, a start ~17 px short leaves a d' "
                          "bias of ~0.09 px, i.e. V_Z errors of ~2 m/s at 1 ms frames; see "
                          "docs/accuracy.md)")
    geo.add_argument("--d0", type=float, default=None,
                     help="minimum disparity in px for the farthest expected gas, s*b/Z_far "
                          "(default: from the gas depth band): start of the SGM search "
                          "range, fill value of its holes")
    geo.add_argument("--sgm-range", type=int, default=None,
                     help="width N of the SGM search range [d0, d0 + N) in px, multiple of "
                          "16, for the chain's initialisation and the baselines (default: "
                          "from the gas depth band, at least 64)")
    p.add_argument("--workers", type=int, choices=(1, 2), default=None,
                   help="take the triples as this many of the daemon's workers do: 1 (every "
                        "triple warm from the one before) or 2 (every other triple each, "
                        "warm from two frames back). Default: with --chain appliance the "
                        "configuration's processing.workers, else 1")
    p.add_argument("--frames", type=int, metavar="N",
                   help="evaluate only the first N triples of each sequence")
    p.set_defaults(func=run)

def _overrides(args: argparse.Namespace) -> Any:
    from appliance.evaluation.sceneflow_setup import Overrides

    if args.sgm_range is not None and (args.sgm_range < 16 or args.sgm_range % 16):
        raise ValueError(f"--sgm-range must be a positive multiple of 16, got {args.sgm_range}")
    if args.d0 is not None and not args.d0 >= 0:
        raise ValueError(f"--d0 must be >= 0 px, got {args.d0}")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    for name in ("focal_length", "baseline", "frame_interval"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise ValueError(f"--{name.replace('_', '-')} must be > 0, got {value}")
    return Overrides(
        focal_length_px=args.focal_length, baseline_m=args.baseline,
        principal_point=None if args.principal_point is None else tuple(args.principal_point),
        depth_band_m=None if args.depth_band is None else tuple(args.depth_band),
        frame_interval_s=args.frame_interval, d0=args.d0, sgm_range=args.sgm_range,
        disparity_init=args.disparity_init, workers=args.workers)


def run(args: argparse.Namespace) -> int:
    """Evaluate every sequence in --data; print the table, write JSON and figures."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation import sceneflow as ev
    from appliance.evaluation.sceneflow_figures import write_figures
    from appliance.evaluation.sceneflow_setup import evaluate_sequence, sequence_setup
    from processing.synthetic import read_sequence_meta
    from processing.synthetic.storage import SequenceFormatError

    overrides = _overrides(args)
    seqs = ev.find_sequences(args.data)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results: dict[str, ev.Metrics] = {}
    setups: dict[str, str] = {}
    for seq in seqs:
        try:
            meta = read_sequence_meta(seq)
            setup = sequence_setup(meta, seq, chain=args.chain, overrides=overrides,
                                   config=args.config)
        except SequenceFormatError as exc:
            raise cli.CommandError(f"cannot read sequence {seq}: {exc}") from exc
        log(f"evaluating {seq.name} ({args.chain} chain) ...")
        try:
            summary, fig = evaluate_sequence(seq, setup, meta, max_triples=args.frames,
                                             log=log)
        except SequenceFormatError as exc:
            raise cli.CommandError(f"cannot read sequence {seq}: {exc}") from exc
        results[seq.name] = summary
        setups[seq.name] = "\n".join([f"{seq.name}:", setup.describe(),
                                      *(f"  note: {n}" for n in setup.notes)])
        summary["setup"] = {k: {"value": v, "source": setup.sources[k]}
                            for k, v in setup.values.items()}
        if args.figures is not None:
            try:
                paths = write_figures(args.figures, seq.name, summary, fig)
            except OSError as exc:
                raise cli.CommandError(str(exc)) from exc
            for path in paths:
                log(f"  wrote {path}")
    title = ("the paper's conditions (Table 3)" if args.chain == "paper"
             else "the appliance's chain")
    print(f"Scene flow on synthetic data, {title}; means over triples. Settings per sequence "
          f"(source in brackets):")
    for text in setups.values():
        print(text)
    print(ev.format_table(results))
    for name, res in results.items():
        undef = {m: res[m]["undefined"] for m in ev.METHODS if res[m]["undefined"]}
        if undef:
            print(f"{name}: frames with undefined metrics (left out of the means): {undef}")
    if args.json is not None:
        cli.write_json(args.json, ev.public(results))
    return cli.EXIT_OK
