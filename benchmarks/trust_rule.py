"""The correction-trust rule of session 69 (benchmarks/bias_validation.py's docstring),
judged on the kept link rows and the trust rows of the same models:

    .venv/bin/python benchmarks/bias_validation.py --forms trust \
        --splits within-0426 day-0422 day-0426 day-0425 mode-tdoa3 mode-tdoa2 \
        --json docs/notebook/trust.bias-validation.json        # 11 min on two cores
    .venv/bin/python benchmarks/trust_rule.py                  # the verdict, seconds
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
KEPT = ROOT / "docs" / "notebook" / "bias-validation.json"
TRUST = ROOT / "docs" / "notebook" / "trust.bias-validation.json"
ACCURACY_SPLITS = ("day-0426", "day-0425", "mode-tdoa3", "mode-tdoa2")
NEW_DAYS = ("day-0426", "day-0425", "day-0422")
TOLERANCE_M = 0.005


def per_seed(rows: list[dict], form: str, split: str) -> dict[int, tuple[float, int]]:
    """Each seed's mean 3D RMSE and flights made worse (a split's folds pooled by flight)."""
    out = {}
    for seed in sorted({r["seed"] for r in rows if r["form"] == form and r["split"] == split}):
        flights = [f for r in rows if r["form"] == form and r["split"] == split and r["seed"] == seed
                   for f in r["flights"]]
        out[seed] = (float(np.mean([f["rmse_3d"] for f in flights])),
                     int(sum(f["rmse_3d"] > f["rmse_3d_without"] for f in flights)))
    return out


def mean_over_seeds(rows: list[dict], form: str, split: str) -> tuple[float, float]:
    seeds = per_seed(rows, form, split).values()
    return float(np.mean([m for m, _ in seeds])), float(np.mean([w for _, w in seeds]))


def verdict(rows: list[dict]) -> dict:
    figures = {form: {split: mean_over_seeds(rows, form, split) for split in (*ACCURACY_SPLITS, "day-0422", "within-0426")}
               for form in ("link", "trust")}
    link, trust = figures["link"], figures["trust"]
    within_worse = max(w for _, w in per_seed(rows, "trust", "within-0426").values())
    a = trust["within-0426"][0] <= link["within-0426"][0] + TOLERANCE_M and within_worse == 0
    b = (trust["day-0422"][1] < link["day-0422"][1] and trust["day-0422"][0] < link["day-0422"][0]
         and sum(trust[s][1] for s in NEW_DAYS) < sum(link[s][1] for s in NEW_DAYS))
    accuracy = {form: float(np.mean([figures[form][s][0] for s in ACCURACY_SPLITS])) for form in figures}
    c = accuracy["trust"] <= accuracy["link"] + TOLERANCE_M
    return {"figures": figures, "accuracy": accuracy, "a": a, "b": b, "c": c, "kept": a and b and c}


def main() -> None:
    rows = [r for r in json.loads(KEPT.read_text())["rows"] if r["form"] == "link" and "flights" in r]
    rows += json.loads(TRUST.read_text())["rows"]
    result = verdict(rows)
    for split in result["figures"]["link"]:
        (lm, lw), (tm, tw) = result["figures"]["link"][split], result["figures"]["trust"][split]
        print(f"{split:12s} link {lm:.4f} m, {lw:.2f} worse | trust {tm:.4f} m, {tw:.2f} worse")
    print(json.dumps({k: v for k, v in result.items() if k != "figures"}))


if __name__ == "__main__":
    main()
