"""The `rig` command: one entry point for every job of the test rig.

One module per command group registers its own subcommands (`data`, `sim`,
`estimator`, `bias`, `hil`, `diagnosis`); a command's body parses, calls library
functions and prints. Heavy modules (torch, scipy, matplotlib, zenoh) are imported
inside the commands that use them, so `rig --help` starts fast.

May import: every `rig` package; nothing imports it.
"""

from __future__ import annotations

import argparse
import faulthandler
import logging
import signal
import sys

from rig.cli import bias, data, diagnosis, estimator, hil, sim
from rig.cli.common import EXIT_BAD_INPUT, CliError, stop_on_signals
from rig.data import paths

GROUPS = (data, sim, estimator, bias, hil, diagnosis)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig",
        description="uwb-rig: replay UWB TDOA + IMU flights into the onboard estimator, "
                    "simulate flights, score estimates against ground truth.",
        epilog=f"Real flights are read from $UWB_RIG_DATA (default {paths.DEFAULT_DATA_DIR}).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in GROUPS:
        group.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from rig.data.errors import USER_ERRORS

    # a rig that seems stuck says where: `kill -USR1 PID` prints every thread's stack
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    stop_on_signals()
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (CliError, *USER_ERRORS) as exc:
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"rig {args.command}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + signum             # the shell's convention: 130 for SIGINT, 143 for SIGTERM
