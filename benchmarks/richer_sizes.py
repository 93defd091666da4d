"""How large the diagnosis's richer TDOA terms come out on the shared flights, where
the anchors stand where they were surveyed: the size of each named displacement, how
much each displacement and pattern changes its anchor's ranges over the flight
(findings and not explained), how many displacement, pattern and link-bias estimates
lie beyond their physical bounds, and how many entries under *Not explained* have an
estimate within their bounds (left out of the re-simulating model for its joint fit's
sake), with the TDOA mismatch the model leaves (median over the flights of the
channel's `fit_after`). Reads the reports `benchmarks/diagnosis.py` wrote; seconds.

    .venv/bin/python benchmarks/diagnosis.py --reuse        # the 35 reports (5 min when not there yet)
    .venv/bin/python benchmarks/richer_sizes.py [--reports out/diagnosis] [--json out/richer_sizes.json]

Session 80 judged two changes with it (docs/notebook/diagnosis-experiments.md)."""

from __future__ import annotations

import sys
from collections import Counter

import numpy as np

import diagnosis_reports

sys.path.insert(0, str(diagnosis_reports.ROOT))

from rig.sim import effects as fx  # noqa: E402
RICHER = ("anchor_position", "antenna_pattern", "link_bias")
PER_ANCHOR = ("anchor_position", "antenna_pattern")          # those whose reports say how they change the ranges


def flight_figures(report: dict) -> dict:
    """One report's displacement sizes (m), how much each displacement and pattern
    changes its anchor's ranges (m, `where.spread_m`, in reports that give it), and its
    richer estimates beyond bound, by effect."""
    named = [f for f in report["findings"] + report["not_explained"] if f["effect"] in RICHER]
    sizes = [float(np.linalg.norm(f["params"]["offset_m"])) for f in named if f["effect"] == "anchor_position"]
    spreads = {e: [float(f["where"]["spread_m"][str(f["params"]["anchor"])]) for f in named
                   if f["effect"] == e and "spread_m" in f.get("where", {})] for e in PER_ANCHOR}
    beyond = {e: sum(1 for f in named if f["effect"] == e and f.get("beyond_physical_bound")) for e in RICHER}
    named_by_effect = {e: sum(1 for f in named if f["effect"] == e) for e in RICHER}
    within = Counter(f["effect"] for f in report["not_explained"]
                     if not fx.make_effect(f["effect"], f["params"]).beyond_bound())
    return {"displacement_sizes_m": sizes, "range_spreads_m": spreads, "named": named_by_effect, "beyond_bound": beyond,
            "not_explained_within_bound": dict(within), "tdoa_fit_after_m": report["channels"]["tdoa"]["fit_after"]}


def summary(flights: dict[str, dict]) -> dict:
    sizes = np.array([s for f in flights.values() for s in f["displacement_sizes_m"]])
    out = {"flights": len(flights), "displacements": int(len(sizes)),
           "named": {e: sum(f["named"][e] for f in flights.values()) for e in RICHER},
           "beyond_bound": {e: sum(f["beyond_bound"][e] for f in flights.values()) for e in RICHER}}
    out["beyond_bound_total"] = sum(out["beyond_bound"].values())
    out["not_explained_within_bound"] = dict(sum((Counter(f["not_explained_within_bound"])
                                                  for f in flights.values()), Counter()))
    out["tdoa_fit_after_median_m"] = float(np.median([f["tdoa_fit_after_m"] for f in flights.values()]))
    if len(sizes):
        out["displacement_median_m"] = float(np.median(sizes))
        out["displacement_p10_p90_m"] = [float(v) for v in np.percentile(sizes, [10, 90])]
    for effect in PER_ANCHOR:
        spreads = [s for f in flights.values() for s in f.get("range_spreads_m", {}).get(effect, [])]
        if spreads:
            out.setdefault("range_spread_median_m", {})[effect] = float(np.median(spreads))
            out.setdefault("range_spread_p10_p90_m", {})[effect] = [float(v) for v in np.percentile(spreads, [10, 90])]
    return out


def main() -> None:
    args = diagnosis_reports.command_line(__doc__, "richer_sizes.json")
    flights = diagnosis_reports.per_flight(args, flight_figures)
    total = summary(flights)
    print(f"{total['flights']} flights, {total['displacements']} displacements named", end="")
    if total["displacements"]:
        low, high = total["displacement_p10_p90_m"]
        print(f": median size {total['displacement_median_m']:.2f} m (10-90 %: {low:.2f}-{high:.2f} m)", end="")
    print()
    for effect, median in total.get("range_spread_median_m", {}).items():
        low, high = total["range_spread_p10_p90_m"][effect]
        print(f"  the {effect} fits change their anchors' ranges by: median {median:.3f} m "
              f"(standard deviation over the flight; 10-90 %: {low:.3f}-{high:.3f} m)")
    for effect in RICHER:
        print(f"  {effect:16s} {total['beyond_bound'][effect]:4d} of {total['named'][effect]:4d} beyond bound")
    print(f"  {'all':16s} {total['beyond_bound_total']:4d} of {sum(total['named'].values()):4d} beyond bound")
    within = total["not_explained_within_bound"]
    print(f"under Not explained with an estimate within bound: {sum(within.values())} "
          f"({', '.join(f'{e} {n}' for e, n in sorted(within.items())) or 'none'})")
    print(f"TDOA mismatch the model leaves: median {total['tdoa_fit_after_median_m']:.4f} m")
    diagnosis_reports.write(args, total, flights)


if __name__ == "__main__":
    main()
