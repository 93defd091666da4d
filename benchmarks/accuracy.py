"""Accuracy benchmark: every shared flight through the C estimator in each configuration.

    .venv/bin/python benchmarks/accuracy.py [--out docs/notebook/accuracy.md] [--json out/accuracy.json]

Prints per-flight and per-group 3D RMSE and writes the Markdown table and a JSON file.
Configurations: plain EKF update, robust (M-estimation), robust + bias network (when a
model is available; the share of its correction the flight supports, as shipped), and
robust + the whole correction (`--full-trust`), with the share the shipped run applied
at the end (`correction_trust`) and the share of its corrections made outside where the
model was trained (`rig evaluate`'s `outside_trained_region`)."""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import import_log  # noqa: E402
from rig.estimator.bias_net import DEFAULT_NETWORK  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402

GROUPS = [("0425 TDOA2", lambda n: n.startswith("0425-traj") and int(n.split("traj")[1]) <= 12),
          ("0425 TDOA3", lambda n: n.startswith("0425-traj") and int(n.split("traj")[1]) >= 13),
          ("0422 TDOA2", lambda n: n.startswith("0422")),
          ("0426 clear", lambda n: n in ("0426-traj1", "0426-traj2")),
          ("0426 obstacles", lambda n: n.startswith("0426") and n not in ("0426-traj1", "0426-traj2"))]


def configurations() -> dict[str, dict]:
    configs = {"plain": {"robust": False, "use_nn": False}, "robust": {"robust": True, "use_nn": False}}
    if DEFAULT_NETWORK.exists():
        configs["robust+nn"] = {"robust": True, "use_nn": True}
        configs["robust+nn whole"] = {"robust": True, "use_nn": True, "full_trust": True}
    return configs


def run_flight(flight: Path) -> dict:
    rec = import_log(flight, paths.survey_for(flight))
    row = {}
    for name, cfg in configurations().items():
        r = evaluate(rec, **cfg)
        row[name] = {"rmse_3d": r["rmse_3d"], "rmse_xyz": r["rmse_xyz"], "diverged": r["diverged"]}
        if "outside_trained_region" in r:
            row["outside_trained_region"] = r["outside_trained_region"]
        if name == "robust+nn":
            row["correction_trust"] = r["correction_trust"]
    return {"flight": flight.name, **row}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "notebook" / "accuracy.md")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "accuracy.json")
    args = parser.parse_args()
    flights = paths.flights()
    with ProcessPoolExecutor(max_workers=2) as pool:
        rows = list(pool.map(run_flight, flights))
    names = list(configurations())
    region = any("outside_trained_region" in row for row in rows)
    trust = any("correction_trust" in row for row in rows)
    lines = ["| flight | " + " | ".join(names) + (" | share of the correction applied" if trust else "")
             + (" | corrected outside the model's trained region" if region else "")
             + " |", "|---|" + "---|" * (len(names) + trust + region)]
    for row in rows:
        cells = [f"{row[n]['rmse_3d']:.3f}" + (" (diverged)" if row[n]["diverged"] else "") for n in names]
        if trust:
            cells.append(f"{row['correction_trust']:.2f}" if "correction_trust" in row else "—")
        if region:
            cells.append(f"{row['outside_trained_region']:.1%}" if "outside_trained_region" in row else "—")
        lines.append(f"| {row['flight']} | " + " | ".join(cells) + " |")
    group_lines = ["| group | flights | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    summary = {}
    for group, member in GROUPS + [("all", lambda n: True)]:
        sel = [r for r in rows if member(r["flight"])]
        means = {n: float(np.mean([r[n]["rmse_3d"] for r in sel])) for n in names}
        summary[group] = {"flights": len(sel), **means,
                          "diverged": {n: sum(r[n]["diverged"] for r in sel) for n in names}}
        group_lines.append(f"| {group} | {len(sel)} | " + " | ".join(f"{means[n]:.3f}" for n in names) + " |")
    print("\n".join(group_lines))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": rows, "groups": summary}, indent=2) + "\n")
    text = (ROOT / "docs" / "notebook" / "accuracy.md.in").read_text()
    args.out.write_text(text.replace("{{GROUPS}}", "\n".join(group_lines)).replace("{{FLIGHTS}}", "\n".join(lines)))
    print(f"wrote {args.out} and {args.json}")


if __name__ == "__main__":
    main()
