"""``ogiflow recover FILE``: rewrite an MCAP file cut by a crash into a valid indexed one."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "rewrite an MCAP file cut by a crash or power loss into a valid, indexed file"

DESCRIPTION = """\
Rewrite an MCAP recording cut by a crash (kill -9, power loss) into a valid, indexed file.
Every chunk that reached the disk completely is kept (its CRC is checked), with the metadata
(config, calibration, software version); the chunk that was still being written is lost.
The input is never modified. Default output: NAME.mcap for NAME.mcap.active (the appliance's
name for the file it was writing), otherwise NAME.recovered.mcap.

Exit codes: 0 recovered, 2 not an MCAP file / output exists / unreadable."""


def register(root: argparse._SubParsersAction) -> None:
    """Add the ``recover`` subcommand."""
    p = root.add_parser("recover", help=HELP, description=DESCRIPTION,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=Path, metavar="FILE", help="the cut MCAP file")
    p.add_argument("--out", type=Path, metavar="FILE", default=None,
                   help="output file (default: see above)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Recover ``args.file``; print what was kept."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.recording.recovery import recover

    if not args.file.is_file():
        raise ValueError(f"no such file: {args.file}")
    report = recover(args.file, args.out, overwrite=args.force)
    print(report.summary())
    return 0
