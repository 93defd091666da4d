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
import tempfile
from pathlib import Path

from rig.cli import bias, data, diagnosis, estimator, hil, sim
from rig.cli.common import CRASH_LOG, EXIT_BAD_INPUT, EXIT_BOARD, EXIT_INTERNAL, CliError
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
    from rig.hil.interrupt import stop_on_signals

    stop_on_signals()
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from rig.hil.links.base import LinkError

    try:
        return args.func(args)
    except CliError as exc:
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return exc.status
    except LinkError as exc:
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BOARD
    except USER_ERRORS as exc:
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"rig {args.command}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + signum             # the shell's convention: 130 for SIGINT, 143 for SIGTERM
    except Exception as exc:           # a bug of the rig's: the traceback to a file, one line here
        where = crash_log(args, exc)
        print(f"rig {args.command}: internal error: {type(exc).__name__}: {exc} (traceback in {where})",
              file=sys.stderr)
        return EXIT_INTERNAL


def crash_log(args: argparse.Namespace, exc: Exception) -> Path:
    """The traceback of an internal error, in the command's output directory if it has
    one (else the working directory), beside what the command wrote."""
    import traceback

    directory = getattr(args, "out", None)
    directory = Path(directory) if isinstance(directory, Path) and directory.suffix == "" else Path.cwd()
    path = directory / CRASH_LOG
    try:
        directory.mkdir(parents=True, exist_ok=True)
        path.write_text("".join(traceback.format_exception(exc)))
    except OSError:
        path = Path(tempfile.gettempdir()) / CRASH_LOG
        path.write_text("".join(traceback.format_exception(exc)))
    return path
