"""How well a diagnosis's anchor delays agree with the most direct measure of an anchor's
constant, on every shared flight: the robust mean of how long its ranges read before
anything is modelled (`mismatch.tdoa_per_anchor_m`). Reads the reports
`benchmarks/diagnosis.py` wrote; seconds.

    .venv/bin/python benchmarks/diagnosis.py --reuse        # the 35 reports (5 min when not there yet)
    .venv/bin/python benchmarks/delay_share.py [--reports out/diagnosis] [--json out/delay_share.json]

Every vector is taken about its median (TDOA sees delays only relative to each other).
Session 79 measured with it that delays fitted together with a lever arm beyond its
bound carried that lever arm's cross-talk (median RMS 0.166 m against the direct
measure, at 5dce922, where the reports gave each delay's `lever_arm_share_m`), and
0.042 m once the simplest effects are estimated without it."""

from __future__ import annotations

import numpy as np

import diagnosis_reports


def delay_rows(report: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """A report's whole-flight delays (findings and not explained) and the direct
    measure of the same anchors; None with fewer than two."""
    direct = report["mismatch"].get("tdoa_per_anchor_m", {})
    delays = [f for f in report["findings"] + report["not_explained"]
              if f["effect"] == "anchor_delay" and "during" not in f["params"] and str(f["params"]["anchor"]) in direct]
    if len(delays) < 2:
        return None
    return (np.array([f["params"]["meters"] for f in delays]),
            np.array([direct[str(f["params"]["anchor"])] for f in delays]))


def about_median(v: np.ndarray) -> np.ndarray:
    return v - np.median(v)


def flight_figures(report: dict) -> dict | None:
    rows = delay_rows(report)
    if rows is None:
        return None
    reported, direct = (about_median(v) for v in rows)
    return {"anchors": len(reported), "largest_m": float(np.abs(reported).max()),
            "rms_vs_direct_m": float(np.sqrt(np.mean((reported - direct) ** 2)))}


def main() -> None:
    args = diagnosis_reports.command_line(__doc__, "delay_share.json")
    flights = diagnosis_reports.per_flight(args, flight_figures, "report with anchor delays")
    for name, f in flights.items():
        print(f"{name:12s} largest delay {f['largest_m']:.2f} m; RMS against the direct measure "
              f"{f['rms_vs_direct_m']:.3f} m over {f['anchors']} anchors")
    summary = {k: float(np.median([f[k] for f in flights.values()])) for k in ("largest_m", "rms_vs_direct_m")}
    summary["flights"] = len(flights)
    print(f"median over the {len(flights)} flights: largest delay {summary['largest_m']:.3f} m, "
          f"RMS against the direct measure {summary['rms_vs_direct_m']:.3f} m")
    diagnosis_reports.write(args, summary, flights)


if __name__ == "__main__":
    main()
