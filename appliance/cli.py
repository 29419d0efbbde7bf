"""The ``ogiflow`` command line: one console script, subcommands in ``appliance.commands``.

Exit codes (shared by every subcommand):

- 0: success
- 1: the job ran but failed (a device error, a failed check, an evaluation that could
  not run; for ``run``, any fault after the configuration was accepted)
- 2: bad usage or bad input (unknown option, wrong config key, unreadable or malformed
  input file of a one-shot command); the message names the problem
- 130: interrupted by SIGINT before finishing
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from appliance import __version__
from appliance.exitcodes import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from appliance.memory import keep_freed_memory

#: Modules that each register one subcommand (or one member of a group such as ``eval``).
COMMAND_MODULES: tuple[str, ...] = (
    "appliance.commands.eval_flow",
    "appliance.commands.recover",
    "appliance.commands.calibrate",
    "appliance.commands.calibrate_gascell",
    "appliance.commands.eval_footage",
    "appliance.commands.eval_detection",
    "appliance.commands.simulate",
    "appliance.commands.eval_stereo",
    "appliance.commands.wind_decode",
    "appliance.commands.run",
    "appliance.commands.export",
    "appliance.commands.bench",
    "appliance.commands.eval_sceneflow",
    "appliance.commands.eval_emission",
    "appliance.commands.eval_robustness",
    "appliance.commands.replay",
    "appliance.commands.reprocess",
)

__all__ = ["EXIT_FAILURE", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE", "CommandError", "main"]


class CommandError(Exception):
    """A failure a command reports to the user as one clear line (exit code 1)."""


def command_group(
    root: argparse._SubParsersAction, name: str, help_text: str
) -> argparse._SubParsersAction:
    """Return the subparsers of group ``name`` (``eval``, ``calibrate``, ...), creating it once.

    Several command modules add members to the same group without knowing about each other.
    """
    groups: dict[str, argparse._SubParsersAction] = root.__dict__.setdefault("_ogiflow_groups", {})
    if name not in groups:
        parser = root.add_parser(name, help=help_text, description=help_text)
        groups[name] = parser.add_subparsers(dest=f"{name}_command", metavar="COMMAND")
        groups[name].required = True
    return groups[name]


def write_json(path: Path, obj: object) -> None:
    """Write a command's ``--json`` result (indented, parent folders made); a failure is a
    :class:`CommandError` naming the file."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(obj, indent=2) + "\n")
    except OSError as exc:
        raise CommandError(f"cannot write {path}: {exc}") from exc


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="ogiflow",
        description=(
            "Stereo optical-gas-imaging appliance: acquisition, 3D gas velocity (scene flow), "
            "recording, live view, calibration and evaluation."
        ),
    )
    parser.add_argument("--version", action="version", version=f"ogiflow {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="show full tracebacks instead of one-line errors"
    )
    root = parser.add_subparsers(dest="command", metavar="COMMAND")
    root.required = True
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(root)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``ogiflow`` console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command != "run":
        # Numerical commands run faster with freed memory kept. The daemon's main process
        # does no numerics (its workers set this themselves) but has many threads and
        # bursty buffers: kept freed memory there only makes its RSS ratchet upwards.
        keep_freed_memory()
    try:
        return int(args.func(args) or EXIT_OK)
    except KeyboardInterrupt:
        print("ogiflow: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except CommandError as exc:
        if args.debug:
            raise
        print(f"ogiflow {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except (ValueError, OSError) as exc:
        # Bad input of a one-shot command or a configuration error (``run`` turns its
        # runtime faults into CommandError itself): one clear line, exit 2.
        if args.debug:
            raise
        print(f"ogiflow {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    raise SystemExit(main())
