"""The rule that keeps the correction trust (session 69), judged on the link form's rows
of the kept validation results, whose flights carry both estimators' figures: the
share of the correction the flight supports (`rmse_3d`) and the whole correction
(`rmse_3d_full_trust`, the estimator before session 69). Seconds:

    .venv/bin/python benchmarks/trust_rule.py

The rule, fixed before its first run on any split (after a mechanism check on six
shared flights with the shipped model and the shipped model negated), with a prior of
2000 pseudo-measurements (EST_TRUST_PRIOR_N): the trust is kept if
(a) within-0426 its mean is at most 0.005 m above the whole correction's, with no flight
    worse than without correction on any seed;
(b) on day-0422 it makes fewer flights worse and has a lower mean, and over day-0426 +
    day-0425 + day-0422 it makes fewer flights worse;
(c) its accuracy (the mean over the four day and mode splits) is within 0.005 m of the
    whole correction's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
KEPT = ROOT / "docs" / "notebook" / "bias-validation.json"
ACCURACY_SPLITS = ("day-0426", "day-0425", "mode-tdoa3", "mode-tdoa2")
NEW_DAYS = ("day-0426", "day-0425", "day-0422")
TOLERANCE_M = 0.005


ESTIMATORS = {"full": "rmse_3d_full_trust", "trust": "rmse_3d"}     # estimator -> each flight's figure


def per_seed(rows: list[dict], split: str, key: str) -> dict[int, tuple[float, int]]:
    """Each seed's mean 3D RMSE and flights made worse (a split's folds pooled by flight),
    by the flights' figure `key`."""
    out = {}
    for seed in sorted({r["seed"] for r in rows if r["split"] == split}):
        flights = [f for r in rows if r["split"] == split and r["seed"] == seed for f in r["flights"]]
        out[seed] = (float(np.mean([f[key] for f in flights])),
                     int(sum(f[key] > f["rmse_3d_without"] for f in flights)))
    return out


def mean_over_seeds(rows: list[dict], split: str, key: str) -> tuple[float, float]:
    seeds = per_seed(rows, split, key).values()
    return float(np.mean([m for m, _ in seeds])), float(np.mean([w for _, w in seeds]))


def verdict(rows: list[dict]) -> dict:
    """The rule on the link form's `rows`."""
    figures = {name: {split: mean_over_seeds(rows, split, key) for split in (*ACCURACY_SPLITS, "day-0422", "within-0426")}
               for name, key in ESTIMATORS.items()}
    link, trust = figures["full"], figures["trust"]
    within_worse = max(w for _, w in per_seed(rows, "within-0426", ESTIMATORS["trust"]).values())
    a = trust["within-0426"][0] <= link["within-0426"][0] + TOLERANCE_M and within_worse == 0
    b = (trust["day-0422"][1] < link["day-0422"][1] and trust["day-0422"][0] < link["day-0422"][0]
         and sum(trust[s][1] for s in NEW_DAYS) < sum(link[s][1] for s in NEW_DAYS))
    accuracy = {name: float(np.mean([figures[name][s][0] for s in ACCURACY_SPLITS])) for name in figures}
    c = accuracy["trust"] <= accuracy["full"] + TOLERANCE_M
    return {"figures": figures, "accuracy": accuracy, "a": a, "b": b, "c": c, "kept": a and b and c}


def main() -> None:
    rows = [r for r in json.loads(KEPT.read_text())["rows"] if r["form"] == "link" and "flights" in r]
    result = verdict(rows)
    for split in result["figures"]["full"]:
        (lm, lw), (tm, tw) = result["figures"]["full"][split], result["figures"]["trust"][split]
        print(f"{split:12s} whole correction {lm:.4f} m, {lw:.2f} worse | trusted share {tm:.4f} m, {tw:.2f} worse")
    print(json.dumps({k: v for k, v in result.items() if k != "figures"}))


if __name__ == "__main__":
    main()
