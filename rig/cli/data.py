"""`rig import`: a Crazyflie uSD event log and its survey into an MCAP recording."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.cli.common import EXIT_OK, progress


def cmd_import(args: argparse.Namespace) -> int:
    from rig.data.importer import day_survey, import_log
    from rig.data.recording import write_recording

    survey = args.survey if args.survey is not None else day_survey(args.log)
    rec = import_log(args.log, survey, salvage=args.salvage, uwb_mode=args.uwb_mode)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=progress(desc="writing"))
    print(f"{args.output}: {len(rec.accel)} accel, {len(rec.gyro)} gyro, {len(rec.tdoa)} TDOA, "
          f"{len(rec.truth)} ground-truth samples, {len(rec.anchors)} anchors, mode {rec.metadata['uwb_mode']}")
    if "salvage" in rec.metadata:
        print(f"warning: salvaged a damaged log: {rec.metadata['salvage']}", file=sys.stderr)
    return EXIT_OK


def register(sub) -> None:
    p = sub.add_parser("import", help="convert a Crazyflie uSD event log + anchor survey to MCAP",
                       description="Decode a Crazyflie uSD event log (version 2), verify magic, version and "
                                   "CRC-32, attach the surveyed anchors and write an MCAP recording in SI units.")
    p.add_argument("log", type=Path, help="uSD event log file")
    p.add_argument("--survey", type=Path,
                   help="anchor survey (default: anchor_MMDD.txt of the log's day, beside its flights or in the shared data)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    p.add_argument("--salvage", action="store_true",
                   help="import the valid prefix of a truncated or corrupted log (with a warning)")
    p.add_argument("--uwb-mode", choices=("TDOA2", "TDOA3"), help="override the inferred UWB mode")
    p.set_defaults(func=cmd_import)
