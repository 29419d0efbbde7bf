"""``ogiflow run``: the appliance itself (also what the systemd service starts).

With no arguments it runs the built-in default configuration: two simulated OGI cameras
showing a synthetic gas plume (rendered once and cached) and a simulated Gill anemometer
on a pseudo terminal whose wind drives that plume; it records to ./recordings and serves
the live view on http://127.0.0.1:9090.

Exit codes: 0 normal end (duration elapsed, SIGTERM or SIGINT; every file finalised);
1 a failure while running (systemd restarts the service); 2 a configuration error, found
before any device opens (the message names the key; restarting cannot fix it).
"""

from __future__ import annotations

import argparse
import logging
import sys

from appliance.cli import CommandError
from appliance.config import ConfigError, add_config_arguments, config_from_args


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("run", help="run the appliance (acquire, process, record, serve)",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_arguments(p)
    p.add_argument("--duration", metavar="S", type=float, default=None,
                   help="stop after S seconds (default: run until SIGTERM/SIGINT)")
    p.add_argument("--prepare", action="store_true",
                   help="render the simulated scene (the configured one, not the quick "
                        "preview; cached) and compile the solvers on its first triple, then "
                        "exit: what a first start would otherwise do while acquiring. Opens "
                        "no device; tools/install.sh runs it")
    p.add_argument("--log-level", default="INFO",
                   choices=("DEBUG", "INFO", "WARNING", "ERROR"),
                   help="verbosity of the log on stderr (journald under systemd)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from appliance.live.view import LiveViewError
    from appliance.runtime.daemon import Appliance
    from appliance.runtime.warmup import warm_up
    from drivers.anemometer.base import AnemometerConfigError

    logging.basicConfig(level=getattr(logging, args.log_level), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be positive, got {args.duration}")
    cfg = config_from_args(args)  # ConfigError (exit 2) before anything opens
    appliance = Appliance(cfg, duration_s=args.duration, announce=True)
    try:
        if args.prepare:
            print(f"ogiflow: ready: {warm_up(appliance)}")
            return 0
        return appliance.run()
    except (ConfigError, AnemometerConfigError):
        raise  # a wrong option value found when the back end is built: exit 2
    except (LiveViewError, OSError, ValueError, RuntimeError) as exc:
        # A full /dev/shm, a vanished device node, a busy port: transient faults of a
        # running appliance, exit 1 so that systemd restarts it.
        raise CommandError(f"{type(exc).__name__}: {exc}") from exc
