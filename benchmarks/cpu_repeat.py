"""How far the validation's estimates move with the CPU the networks were trained on.

Training repeats to the last digit on its CPU only (rig.bias.train.cpu_identity; session
77): on another CPU the same command trains other networks. So the kept rows
(docs/notebook/bias-validation.json, mostly the Intel Xeon of sessions 62-76) cannot be
repeated on another machine, and a figure made there differs by what the CPU changes.
This compares the shipped recipe's rows of the estimate and chooser splits, trained on
another CPU, with the kept ones: per split, the mean over seeds of the mean 3D RMSE and
of the flights made worse, each CPU's spread over seeds, and the two estimates of the
issue's 0426 check. It decides nothing. Seconds, from rows trained so (12 min on two
cores for the six splits; within-0425's rows are in the kept JSON):

    .venv/bin/python benchmarks/bias_validation.py --forms link \\
        --splits day-0426 day-0425 day-0422 mode-tdoa3 mode-tdoa2 within-0426 --json out/link-cpu.json
    .venv/bin/python benchmarks/cpu_repeat.py --json out/link-cpu.json

The rows trained on the AMD EPYC of sessions 77-78 are kept beside the page
(docs/notebook/bias-validation-amd.json, the default).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from bias_validation_results import (EARLIER_CPU, HELD_OUT_0426_BY_MODE, HELD_OUT_0426_WITHOUT_M, RESULTS, TDOA3,
                                     row_cpu, shipped_recipe)
from trust_rule import ESTIMATORS, per_seed

ROOT = Path(__file__).resolve().parent.parent
OTHER_CPU_ROWS = ROOT / "docs" / "notebook" / "bias-validation-amd.json"
SPLITS = ("within-0425", "within-0426", "day-0426", "day-0425", "day-0422", "mode-tdoa3", "mode-tdoa2")


def split_figures(rows: list[dict], split: str) -> dict | None:
    """The split's mean over seeds (3D RMSE, flights worse) and its range over seeds."""
    seeds = per_seed(rows, split, ESTIMATORS["trust"])
    if not seeds:
        return None
    means = [m for m, _ in seeds.values()]
    return {"mean_m": float(np.mean(means)), "min_m": float(min(means)), "max_m": float(max(means)),
            "worse": float(np.mean([w for _, w in seeds.values()])), "seeds": len(seeds)}


def estimates_0426(rows: list[dict]) -> dict | None:
    """The within-0426 gain applied to the held-out flights' figure without correction,
    pooled and per UWB mode (as docs/bias.md's table makes them)."""
    flights = [f for r in rows if r["split"] == "within-0426" for f in r["flights"]]
    if not flights:
        return None

    def gain(runs: list[dict]) -> float:
        return 1 - np.mean([f["rmse_3d"] for f in runs]) / np.mean([f["rmse_3d_without"] for f in runs])

    by_mode = {mode: [f for f in flights if (f["flight"] in TDOA3) == (mode == "TDOA3")] for mode in HELD_OUT_0426_BY_MODE}
    per_mode = None
    if all(by_mode.values()):            # a mode without a flight has no gain to apply
        per_mode = float(sum(n * without * (1 - gain(by_mode[mode])) for mode, (n, without) in HELD_OUT_0426_BY_MODE.items())
                         / sum(n for n, _ in HELD_OUT_0426_BY_MODE.values()))
    return {"pooled_m": float(HELD_OUT_0426_WITHOUT_M * (1 - gain(flights))), "per_mode_m": per_mode}


def by_cpu(rows: list[dict], form: str) -> dict[str, list[dict]]:
    """The form's flight rows, grouped by the CPU they were trained on."""
    out: dict[str, list[dict]] = {}
    for row in rows:
        if row["form"] == form and "flights" in row:
            out.setdefault(row_cpu(row), []).append(row)
    return out


def compare(kept: list[dict], other: list[dict], form: str | None = None) -> dict:
    """Each CPU's figures of every split either holds, for the shipped recipe's rows: a
    split is taken from the other CPU's rows where they hold it, and from the kept rows
    of that CPU too (within-0425 was kept on the AMD EPYC). The kept rows' CPU comes
    first; a difference is the other CPU's mean less its. `form`: default the shipped
    recipe's."""
    form = form or shipped_recipe(kept)
    rows: dict[str, list[dict]] = {}
    for cpu, part in [*by_cpu(kept, form).items(), *by_cpu(other, form).items()]:
        rows.setdefault(cpu, []).extend(part)
    ordered = sorted(rows.items(), key=lambda item: (item[0] != EARLIER_CPU, item[0]))    # the kept rows' CPU first
    return {"form": form,
            "splits": {cpu: {split: fig for split in SPLITS if (fig := split_figures(part, split))} for cpu, part in ordered},
            "estimates_0426": {cpu: estimates_0426(part) for cpu, part in ordered}}


def table(result: dict) -> list[str]:
    cpus = list(result["splits"])
    lines = ["| split | " + " | ".join(f"{cpu}: mean (min–max over seeds), flights worse" for cpu in cpus)
             + " | difference |", "|---|" + "---|" * (len(cpus) + 1)]
    for split in SPLITS:
        figs = [result["splits"][cpu].get(split) for cpu in cpus]
        cells = [f"{f['mean_m']:.4f} m ({f['min_m']:.4f}–{f['max_m']:.4f}), {f['worse']:.1f}" if f else "—" for f in figs]
        held = [f for f in figs if f]
        diff = f"{held[-1]['mean_m'] - held[0]['mean_m']:+.4f} m" if len(held) == 2 else "—"
        lines.append(f"| {split} | " + " | ".join(cells) + f" | {diff} |")
    for cpu, est in result["estimates_0426"].items():
        if est:
            per_mode = "no flight of one mode" if est["per_mode_m"] is None else f"{est['per_mode_m']:.3f} m"
            lines.append(f"\n0426 check from {cpu}'s within-0426 rows: {est['pooled_m']:.3f} m pooled, "
                         f"{per_mode} per mode")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=OTHER_CPU_ROWS, help="rows trained on another CPU")
    parser.add_argument("--out", type=Path, help="write the comparison as JSON here")
    args = parser.parse_args()
    kept = json.loads(RESULTS.read_text())["rows"]
    other = json.loads(args.json.read_text())["rows"]
    result = compare(kept, other)
    if len(result["splits"]) < 2:
        parser.error(f"{args.json}'s rows and the kept rows are of one CPU ({', '.join(result['splits'])}): "
                     "nothing to compare")
    print("\n".join(table(result)))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
