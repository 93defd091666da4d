"""The reports `benchmarks/diagnosis.py` wrote (OUT/<flight>/report.json), as the
benchmarks that read them take them: the command line, and each flight's figures."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parent.parent


def command_line(doc: str, default_json: str) -> argparse.Namespace:
    """--reports (the directory) and --json (where the figures go), described by `doc`."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--reports", type=Path, default=ROOT / "out" / "diagnosis")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / default_json)
    args = parser.parse_args()
    args.error = parser.error
    return args


def per_flight(args: argparse.Namespace, figures: Callable[[dict], dict | None], what: str = "report") -> dict:
    """`figures` of each flight's report that has any; a usage error when none has."""
    flights = {p.parent.name: figures(json.loads(p.read_text())) for p in sorted(args.reports.glob("*/report.json"))}
    flights = {name: f for name, f in flights.items() if f is not None}
    if not flights:
        args.error(f"no {what} under {args.reports}: run benchmarks/diagnosis.py first")
    return flights


def write(args: argparse.Namespace, summary: dict, flights: dict) -> None:
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"summary": summary, "flights": flights}, indent=1) + "\n")
    print(f"wrote {args.json}")
