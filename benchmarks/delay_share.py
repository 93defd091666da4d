"""How far a diagnosis's anchor delays move with a lever arm fitted beyond its bound, on
every shared flight: each delay as reported, and without the lever arm's share
(`lever_arm_share_m`), against the most direct measure of an anchor's constant, the
robust mean of how long its ranges read before anything is modelled
(`mismatch.tdoa_per_anchor_m`). Reads the reports `benchmarks/diagnosis.py` wrote; seconds.

    .venv/bin/python benchmarks/diagnosis.py --reuse        # the 35 reports (5 min when not there yet)
    .venv/bin/python benchmarks/delay_share.py [--reports out/diagnosis] [--json out/delay_share.json]

Every vector is taken about its median (TDOA sees delays only relative to each other)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def delay_rows(report: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Anchors, delays as reported, their lever arm's shares (0 without) and the direct
    measure, of a report's whole-flight delays (findings and not explained); None without."""
    delays = [f for f in report["findings"] + report["not_explained"]
              if f["effect"] == "anchor_delay" and "during" not in f["params"]]
    direct = report["mismatch"].get("tdoa_per_anchor_m", {})
    delays = [f for f in delays if str(f["params"]["anchor"]) in direct]
    if len(delays) < 2:
        return None
    anchors = np.array([f["params"]["anchor"] for f in delays])
    return (anchors, np.array([f["params"]["meters"] for f in delays]),
            np.array([f.get("lever_arm_share_m", 0.0) for f in delays]),
            np.array([direct[str(k)] for k in anchors]))


def about_median(v: np.ndarray) -> np.ndarray:
    return v - np.median(v)


def flight_figures(report: dict) -> dict | None:
    rows = delay_rows(report)
    if rows is None:
        return None
    _, reported, share, direct = rows
    without, direct = about_median(reported - share), about_median(direct)
    reported = about_median(reported)
    rms = lambda v: float(np.sqrt(np.mean(v ** 2)))  # noqa: E731
    return {"anchors": len(reported), "lever_arm_beyond_bound": bool(np.any(share != 0)),
            "largest_reported_m": float(np.abs(reported).max()), "largest_without_m": float(np.abs(without).max()),
            "rms_reported_vs_direct_m": rms(reported - direct), "rms_without_vs_direct_m": rms(without - direct)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reports", type=Path, default=ROOT / "out" / "diagnosis")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "delay_share.json")
    args = parser.parse_args()
    flights = {p.parent.name: flight_figures(json.loads(p.read_text()))
               for p in sorted(args.reports.glob("*/report.json"))}
    flights = {k: v for k, v in flights.items() if v is not None}
    if not flights:
        parser.error(f"no report with anchor delays under {args.reports}: run benchmarks/diagnosis.py first")
    for name, f in flights.items():
        print(f"{name:12s} largest delay {f['largest_reported_m']:.2f} m, without the lever arm's share "
              f"{f['largest_without_m']:.2f} m; RMS against the direct measure {f['rms_reported_vs_direct_m']:.3f} "
              f"-> {f['rms_without_vs_direct_m']:.3f} m{'' if f['lever_arm_beyond_bound'] else ' (lever arm within bound)'}")
    keys = ("largest_reported_m", "largest_without_m", "rms_reported_vs_direct_m", "rms_without_vs_direct_m")
    summary = {k: float(np.median([f[k] for f in flights.values()])) for k in keys}
    summary["flights"] = len(flights)
    summary["lever_arm_beyond_bound"] = sum(f["lever_arm_beyond_bound"] for f in flights.values())
    print("median over the flights: " + ", ".join(f"{k} {summary[k]:.3f}" for k in keys)
          + f"; {summary['lever_arm_beyond_bound']} of {summary['flights']} with the lever arm beyond its bound")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"summary": summary, "flights": flights}, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
