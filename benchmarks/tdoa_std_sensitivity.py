"""How the estimator's accuracy on each shared flight moves with its one TDOA noise
level (`tdoa_std`, 0.4 m shipped), with and without the shipped correction, and what a
per-flight choice of it could gain at most. Measured only, nothing decided (the shipped
model trained on most of these flights, so the corrected figures are in-sample):

    .venv/bin/python benchmarks/tdoa_std_sensitivity.py [--json out/tdoa-std.json]     # seconds

Prints each flight's UWB mode, TDOA rate, obstacles and 3D RMSE at each level; then,
per group of flights, the mean at each level and the mean of each flight's best level
(an oracle: the most a per-flight noise level, however estimated, could gain here)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402

LEVELS_M = (0.3, 0.4, 0.55)
SHIPPED_M = 0.4
# The data README's table: which flights flew with obstacles, which in TDOA3 mode.
OBSTACLES = {f"0426-traj{k}" for k in range(3, 9)}
TDOA3 = {f"0425-traj{k}" for k in range(13, 24)} | {"0426-traj5", "0426-traj6"}


def flight_row(name: str) -> dict:
    rec = load_any(paths.data_dir() / "flights" / name)
    t = rec.tdoa.t
    row = {"flight": name, "mode": "TDOA3" if name in TDOA3 else "TDOA2", "obstacles": name in OBSTACLES,
           "tdoa_hz": float(len(t) / (t[-1] - t[0]))}
    for use_nn, key in ((False, "without"), (True, "corrected")):
        row[key] = {str(s): evaluate(rec, use_nn=use_nn, tdoa_std=s)["rmse_3d"] for s in LEVELS_M}
    return row


def group_summary(rows: list[dict]) -> dict:
    out = {"flights": len(rows)}
    for key in ("without", "corrected"):
        table = np.array([[r[key][str(s)] for s in LEVELS_M] for r in rows])
        out[key] = {"mean_by_level": dict(zip(map(str, LEVELS_M), table.mean(0).round(4).tolist())),
                    "mean_best_per_flight": round(float(table.min(1).mean()), 4)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, help="write the rows and the summaries here")
    args = ap.parse_args()
    names = [p.name for p in paths.flights()]
    with ProcessPoolExecutor(max_workers=2) as pool:
        rows = list(pool.map(flight_row, names))
    print("flight mode obstacles tdoa_hz | without " + " ".join(map(str, LEVELS_M))
          + " | corrected " + " ".join(map(str, LEVELS_M)))
    for r in rows:
        print(r["flight"], r["mode"], "yes" if r["obstacles"] else "no", f"{r['tdoa_hz']:.0f}", "|",
              *(f"{r['without'][str(s)]:.3f}" for s in LEVELS_M), "|", *(f"{r['corrected'][str(s)]:.3f}" for s in LEVELS_M))
    groups = {"all": rows, "TDOA3": [r for r in rows if r["mode"] == "TDOA3"],
              "TDOA2 clear": [r for r in rows if r["mode"] == "TDOA2" and not r["obstacles"]],
              "obstacles": [r for r in rows if r["obstacles"]]}
    summaries = {name: group_summary(g) for name, g in groups.items()}
    for name, s in summaries.items():
        for key in ("without", "corrected"):
            levels = ", ".join(f"{lv} m: {v:.4f}" for lv, v in s[key]["mean_by_level"].items())
            print(f"{name} ({s['flights']} flights), {key}: {levels}; each flight's best level: "
                  f"{s[key]['mean_best_per_flight']:.4f} m")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"levels_m": LEVELS_M, "shipped_m": SHIPPED_M, "rows": rows,
                                         "summaries": summaries}, indent=1))


if __name__ == "__main__":
    main()
