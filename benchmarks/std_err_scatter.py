"""Whether the diagnosis's standard errors are the size of what really varies
(descriptive; it decides nothing).

    .venv/bin/python benchmarks/std_err_scatter.py [FINDINGS.json ...] [--json out/std_err_scatter.json]

The flights of one day fly the same room, anchors and tag, so each untouched
flight's own lever arm and anchor delays scatter from flight to flight by about
what one flight's error lets them: if the reported standard errors are right, the
scatter between a day's flights is about their size or larger (the flights also
differ: obstacles, mode, path), never many times it. It reads the untouched flights
(`<flight>|control`) of `benchmarks/concealed.py`'s findings (default: the fourteen
flights' and the held-out eight's), takes each flight's estimate wherever the report
lists it (a finding, not explained, or an unnamed estimate), and prints per day and
quantity the scatter (standard deviation over the flights), the median reported
standard error and their ratio.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = [ROOT / "out" / "concealed.findings.json", ROOT / "out" / "held-out.findings.json"]
ANCHORS = range(8)


def estimates(listed: dict) -> dict[str, tuple[float, float]]:
    """(value, standard error) of the lever arm's components and each anchor's delay."""
    out = {}
    for fit in listed["findings"] + listed["unnamed"]:
        if fit["effect"] == "lever_arm" and fit.get("std_err"):
            for axis, value, error in zip("xyz", fit["params"]["offset_m"], fit["std_err"]["offset_m"]):
                out[f"lever_arm {axis}"] = (value, error)
        elif fit["effect"] == "anchor_delay" and fit.get("std_err"):
            out[f"delay {fit['params']['anchor']}"] = (fit["params"]["meters"], fit["std_err"]["meters"])
    return out


def by_day(paths: list[Path]) -> dict[str, dict[str, list[tuple[float, float]]]]:
    days: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for path in paths:
        for key, value in json.loads(path.read_text()).items():
            flight, label = key.split("|")
            if label != "control" or flight == "sim":
                continue
            for quantity, pair in estimates(value[0]).items():
                days[flight.split("-")[0]][quantity].append(pair)
    return days


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("findings", nargs="*", type=Path, default=DEFAULT)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "std_err_scatter.json")
    args = parser.parse_args()
    rows = {}
    for day, quantities in sorted(by_day(args.findings).items()):
        for quantity, pairs in sorted(quantities.items()):
            if len(pairs) < 3:
                continue
            values, errors = np.array(pairs).T
            scatter, error = float(np.std(values, ddof=1)), float(np.median(errors))
            rows[f"{day} {quantity}"] = {"flights": len(pairs), "scatter": round(scatter, 4),
                                         "median_std_err": round(error, 4), "ratio": round(scatter / error, 2)}
            print(f"{day} {quantity:12s} flights {len(pairs):2d}  scatter {scatter:.3f}  "
                  f"median std_err {error:.3f}  ratio {scatter / error:.1f}")
    ratios = [r["ratio"] for r in rows.values()]
    print(f"ratio over {len(ratios)} day × quantity: median {np.median(ratios):.1f}, "
          f"range {min(ratios):.1f}–{max(ratios):.1f}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
