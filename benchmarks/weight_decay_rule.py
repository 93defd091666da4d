"""The rule that decides the link form's weight decay (session 71), fixed before its
first run: the link form trained with an L2 penalty of 1e-3 (`weight-decay`, 100 times
the recipe's 1e-5) against the kept link rows (docs/notebook/bias-validation.json, the
same seeds, splits and MKL branch; session 70 reran them to the last digit). Seconds,
once the run is done:

    .venv/bin/python benchmarks/bias_validation.py --forms weight-decay \\
        --splits day-0426 day-0425 mode-tdoa3 mode-tdoa2 within-0426 day-0422 --json out/weight-decay.json   # 11 min
    .venv/bin/python benchmarks/weight_decay_rule.py [--json out/weight-decay.json]

Each flight's figure is the shipped estimator's (the share of the correction the flight
supports, `rmse_3d`). Accuracy is the mean over the four day and mode splits of the mean
3D RMSE over seeds; flights worse is the sum over those splits of the mean over seeds of
the flights the correction makes worse than none. The weight decay is kept only if
(1) neither figure is higher than the link rows', and
(2) accuracy is lower by at least 0.005 m, or flights worse by at least 1.0, and
(3) within-0426 its mean is at most 0.002 m higher, with no flight worse on any seed.
day-0422 is reported and decides nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from trust_rule import ACCURACY_SPLITS, KEPT, ESTIMATORS, mean_over_seeds, per_seed

ROOT = Path(__file__).resolve().parent.parent
SPLITS = (*ACCURACY_SPLITS, "within-0426", "day-0422")
GAIN_M, FEWER_WORSE, WITHIN_TOLERANCE_M = 0.005, 1.0, 0.002


def figures(rows: list[dict]) -> dict[str, tuple[float, float]]:
    return {split: mean_over_seeds(rows, split, ESTIMATORS["trust"]) for split in SPLITS}


def verdict(link: list[dict], decayed: list[dict]) -> dict:
    fig = {"link": figures(link), "weight-decay": figures(decayed)}
    accuracy = {name: sum(f[s][0] for s in ACCURACY_SPLITS) / len(ACCURACY_SPLITS) for name, f in fig.items()}
    worse = {name: sum(f[s][1] for s in ACCURACY_SPLITS) for name, f in fig.items()}
    one = accuracy["weight-decay"] <= accuracy["link"] and worse["weight-decay"] <= worse["link"]
    two = accuracy["weight-decay"] <= accuracy["link"] - GAIN_M or worse["weight-decay"] <= worse["link"] - FEWER_WORSE
    within_worse = max(w for _, w in per_seed(decayed, "within-0426", ESTIMATORS["trust"]).values())
    three = (fig["weight-decay"]["within-0426"][0] <= fig["link"]["within-0426"][0] + WITHIN_TOLERANCE_M
             and within_worse == 0)
    return {"figures": fig, "accuracy_m": accuracy, "worse_flights": worse, "1": one, "2": two, "3": three,
            "kept": one and two and three}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "weight-decay.json")
    args = parser.parse_args()
    with_flights = [r for r in json.loads(KEPT.read_text())["rows"] if "flights" in r]
    link = [r for r in with_flights if r["form"] == "link"]
    decayed = [r for r in json.loads(args.json.read_text())["rows"] if r["form"] == "weight-decay" and "flights" in r]
    result = verdict(link, decayed)
    for split in SPLITS:
        (lm, lw), (dm, dw) = result["figures"]["link"][split], result["figures"]["weight-decay"][split]
        print(f"{split:12s} link {lm:.4f} m, {lw:.2f} worse | weight decay 1e-3 {dm:.4f} m, {dw:.2f} worse")
    print(json.dumps({k: v for k, v in result.items() if k != "figures"}))


if __name__ == "__main__":
    main()
