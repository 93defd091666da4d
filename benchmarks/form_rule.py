"""The rule that decides whether the link form trained otherwise replaces the recipe
(sessions 71 on; the weight decay's rule, made for any form), fixed before each run: the
form's rows of an experiment's JSON against the kept link rows
(docs/notebook/bias-validation.json, the same seeds, splits and MKL branch; session 70
reran them to the last digit). Seconds, once the run is done:

    .venv/bin/python benchmarks/bias_validation.py --forms FORM \\
        --splits day-0426 day-0425 mode-tdoa3 mode-tdoa2 within-0426 day-0422 --json out/FORM.json   # 12 min
    .venv/bin/python benchmarks/form_rule.py --form FORM [--json out/FORM.json] [--link-json JSON]

Each flight's figure is the shipped estimator's (the share of the correction the flight
supports, `rmse_3d`). Accuracy is the mean over the four day and mode splits of the mean
3D RMSE over seeds; flights worse is the sum over those splits of the mean over seeds of
the flights the correction makes worse than none. The form is kept only if
(1) neither figure is higher than the link rows', and
(2) accuracy is lower by at least 0.005 m, or flights worse by at least 1.0, and
(3) within-0426 its mean is at most 0.002 m higher, with no flight worse on any seed.
day-0422 is reported and decides nothing. With --link-json, the link rows are that
file's (a replication on fresh seeds trains both forms into one JSON).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from trust_rule import ACCURACY_SPLITS, ESTIMATORS, KEPT, mean_over_seeds, per_seed

ROOT = Path(__file__).resolve().parent.parent
SPLITS = (*ACCURACY_SPLITS, "within-0426", "day-0422")
GAIN_M, FEWER_WORSE, WITHIN_TOLERANCE_M = 0.005, 1.0, 0.002


def figures(rows: list[dict]) -> dict[str, tuple[float, float]]:
    return {split: mean_over_seeds(rows, split, ESTIMATORS["trust"]) for split in SPLITS}


def verdict(link: list[dict], form: list[dict]) -> dict:
    fig = {"link": figures(link), "form": figures(form)}
    accuracy = {name: sum(f[s][0] for s in ACCURACY_SPLITS) / len(ACCURACY_SPLITS) for name, f in fig.items()}
    worse = {name: sum(f[s][1] for s in ACCURACY_SPLITS) for name, f in fig.items()}
    one = accuracy["form"] <= accuracy["link"] and worse["form"] <= worse["link"]
    two = accuracy["form"] <= accuracy["link"] - GAIN_M or worse["form"] <= worse["link"] - FEWER_WORSE
    within_worse = max(w for _, w in per_seed(form, "within-0426", ESTIMATORS["trust"]).values())
    three = fig["form"]["within-0426"][0] <= fig["link"]["within-0426"][0] + WITHIN_TOLERANCE_M and within_worse == 0
    return {"figures": fig, "accuracy_m": accuracy, "worse_flights": worse, "1": one, "2": two, "3": three,
            "kept": one and two and three}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--form", required=True, help="the experiment's form, as bias_validation.py --forms names it")
    parser.add_argument("--json", type=Path, help="the experiment's rows (default: out/FORM.json)")
    parser.add_argument("--link-json", type=Path, default=KEPT, help="the link rows compared with (default: the kept ones)")
    args = parser.parse_args()
    path = args.json or ROOT / "out" / f"{args.form}.json"
    link = [r for r in json.loads(args.link_json.read_text())["rows"] if r["form"] == "link" and "flights" in r]
    if not link:
        parser.error(f"{args.link_json} holds no rows of the link form")
    form = [r for r in json.loads(path.read_text())["rows"] if r["form"] == args.form and "flights" in r]
    if not form:
        parser.error(f"{path} holds no rows of the form {args.form!r}")
    result = verdict(link, form)
    for split in SPLITS:
        (lm, lw), (fm, fw) = result["figures"]["link"][split], result["figures"]["form"][split]
        print(f"{split:12s} link {lm:.4f} m, {lw:.2f} worse | {args.form} {fm:.4f} m, {fw:.2f} worse")
    print(json.dumps({"form": args.form, **{k: v for k, v in result.items() if k != "figures"}}))


if __name__ == "__main__":
    main()
