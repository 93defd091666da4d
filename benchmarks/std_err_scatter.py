"""Whether the diagnosis's standard errors are the size of what really varies
(descriptive; it decides nothing).

    .venv/bin/python benchmarks/std_err_scatter.py [FINDINGS.json ...] [--json out/std_err_scatter.json]
    .venv/bin/python benchmarks/std_err_scatter.py NEW.findings.json --before OLD.findings.json

The flights of one day fly the same room, anchors and tag, so each untouched
flight's own lever arm and anchor delays scatter from flight to flight by about
what one flight's error lets them: if the reported standard errors are right, the
scatter between a day's flights is about their size or larger (the flights also
differ: obstacles, mode, path), never many times it. It reads the untouched flights
(`<flight>|control`) of `benchmarks/concealed.py`'s findings (default: the fourteen
flights' and the held-out eight's), takes each flight's estimate wherever the report
lists it (a finding, not explained, or an unnamed estimate), and prints per day and
quantity the scatter (standard deviation over the flights), the median reported
standard error and their ratio. It also counts, per effect, the untouched flights'
fits beyond their physical bound and how many of those lie beyond it by more than
two standard errors. With `--before` (findings of the same cases made by other code),
it also prints how the untouched flights' TDOA standard errors changed.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data.files import write_json  # noqa: E402
from rig.diagnosis.wording import beyond_bound_by  # noqa: E402
DEFAULT = [ROOT / "out" / "concealed.findings.json", ROOT / "out" / "held-out.findings.json"]
TDOA_EFFECTS = {"time_offset", "clock_drift", "anchor_delay", "lever_arm", "anchor_position", "antenna_pattern",
                "link_bias"}


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


def _controls(path: Path) -> dict[str, dict]:
    return {key: value[0] for key, value in json.loads(path.read_text()).items()
            if key.endswith("|control") and not key.startswith("sim|")}


def _errors(listed: dict) -> dict[tuple, np.ndarray]:
    """Every TDOA fit's standard errors, keyed by effect and anchors."""
    return {(fit["effect"], tuple(fit.get("anchors") or [])): np.ravel(next(iter(fit["std_err"].values())))
            for fit in listed["findings"] + listed["unnamed"]
            if fit.get("std_err") and fit["effect"] in TDOA_EFFECTS}


def std_err_change(after: list[Path], before: list[Path]) -> dict[str, list[float]]:
    """Per TDOA effect, each component's standard error after over before, on the
    untouched flights both sets hold."""
    old = {k: v for path in before for k, v in _controls(path).items()}
    ratios: dict[str, list[float]] = defaultdict(list)
    for path in after:
        for key, listed in _controls(path).items():
            if key not in old:
                continue
            then = _errors(old[key])
            for fit, errors in _errors(listed).items():
                if fit in then and len(then[fit]) == len(errors):
                    ratios[fit[0]] += (errors / np.maximum(then[fit], 1e-12)).tolist()
    return ratios


def print_change(ratios: dict[str, list[float]]) -> dict:
    every = np.concatenate([np.array(v) for v in ratios.values()])
    out = {}
    for name, values in [("every TDOA effect", every), *sorted(ratios.items())]:
        p5, p25, p50, p75, p95 = np.percentile(values, [5, 25, 50, 75, 95])
        out[name] = {"components": len(values), "median": round(p50, 2), "middle_half": [round(p25, 2), round(p75, 2)],
                     "p5_p95": [round(p5, 2), round(p95, 2)]}
        print(f"std_err after / before, {name:18s} {len(values):5d} components: median {p50:.1f}, "
              f"middle half {p25:.1f}–{p75:.1f}, 5–95 % {p5:.1f}–{p95:.1f}")
    return out


def beyond_counts(paths: list[Path]) -> dict[str, dict[str, int]]:
    """Per effect: the untouched flights' fits beyond bound, and of them those beyond
    by more than two standard errors."""
    counts: dict[str, dict[str, int]] = defaultdict(lambda: {"beyond": 0, "by_two_std_errs": 0})
    for path in paths:
        for listed in _controls(path).values():
            for fit in listed["findings"]:
                beyond = fit.get("beyond_physical_bound") and beyond_bound_by(fit["effect"], fit["params"],
                                                                             fit.get("std_err"))
                if beyond:
                    counts[fit["effect"]]["beyond"] += 1
                    counts[fit["effect"]]["by_two_std_errs"] += int(beyond[2] > 2.0)
    for effect, n in sorted(counts.items()):
        print(f"beyond bound, {effect:16s} {n['beyond']:4d} fits, by more than two standard errors {n['by_two_std_errs']:4d}")
    return dict(counts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("findings", nargs="*", type=Path, default=DEFAULT)
    parser.add_argument("--before", nargs="+", type=Path, help="findings of the same cases made by other code")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "std_err_scatter.json")
    args = parser.parse_args()
    rows = {}
    if args.before:
        rows["std_err_change"] = print_change(std_err_change(args.findings, args.before))
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
    ratios = [r["ratio"] for key, r in rows.items() if key != "std_err_change"]
    rows["beyond_bound"] = beyond_counts(args.findings)
    print(f"ratio over {len(ratios)} day × quantity: median {np.median(ratios):.1f}, "
          f"range {min(ratios):.1f}–{max(ratios):.1f}")
    write_json(args.json, rows)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
