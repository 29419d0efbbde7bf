"""``ogiflow eval emission``: emission rate (g/s) on simulated sequences vs the true flux.

A thin argparse layer over :mod:`appliance.evaluation.emission`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from appliance import cli


def register(root: argparse._SubParsersAction) -> None:
    """Add ``eval emission`` to the ``eval`` group."""
    group = cli.command_group(root, "eval", "evaluate the processing against reference data")
    p = group.add_parser(
        "emission",
        help="emission rate (stereo and single-camera) vs the simulator's true flux",
        description=(
            "Run the chain on every consecutive triple of every sequence written by "
            "ogiflow simulate under --data (at any depth), compute the emission rate through "
            "curtains downstream of the detected source with our 3D velocity and depth "
            "(stereo) and as single-camera quantitative OGI does (image-plane flow at one "
            "typed-in distance), and compare both with the true mass flux through the same "
            "curtains, computed in the simulation volume. Prints a table (g/s, relative "
            "errors); acceptance: stereo within 20 %% everywhere, median within 10 %%."
        ),
        epilog="example: benchmarks/emission_sequences.sh emission-data && "
               "ogiflow eval emission --data emission-data --json emission.json "
               "--figures figures/",
    )
    p.add_argument("--data", type=Path, required=True,
                   help="folder holding sequence directories (searched recursively)")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<sequence>": {"true_release_g_s", "true_flux_g_s", '
                        '"stereo_g_s", "stereo_uncertainty_g_s", "single_camera_g_s", ...}}')
    p.add_argument("--figures", type=Path, metavar="DIR",
                   help="write <sequence>_rate.png: rate over time (true flux, stereo, "
                        "single camera, true release)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="evaluate only the first N triples of each sequence")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate every sequence under --data; print the table, write JSON and figures."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.evaluation import emission as ev
    from processing.synthetic.storage import SequenceFormatError

    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    seqs = ev.find_emission_sequences(args.data)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results = {}
    for seq in seqs:
        name = seq.relative_to(args.data).as_posix() if seq != args.data else seq.name
        name = name.replace("/", "_")
        log(f"evaluating {name} ...")
        try:
            results[name] = ev.evaluate_emission_sequence(seq, name=name,
                                                          max_triples=args.frames, log=log)
        except SequenceFormatError as exc:
            raise cli.CommandError(f"cannot read sequence {seq}: {exc}") from exc
        if args.figures is not None:
            try:
                log(f"  wrote {ev.write_figure(args.figures, name, results[name])}")
            except OSError as exc:
                raise cli.CommandError(str(exc)) from exc
    print("Emission rate on simulated sequences (g/s; errors relative to the true flux "
          "through the same curtains; means over triples)")
    print(ev.format_table(results))
    if args.json is not None:
        cli.write_json(args.json, ev.public(results))
    return cli.EXIT_OK
