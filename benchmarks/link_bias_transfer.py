"""Does the physical link-bias model (`rig calibrate`) transfer to days and modes it was
not fitted on? Label level: the TDOA error's spread on the test flights.

    .venv/bin/python benchmarks/link_bias_transfer.py [--json out/link_bias_transfer.json]

The protocol is bias_validation.py's flight splits (day-0426, day-0425, mode-tdoa3,
mode-tdoa2), fixed there before any result; the samples are the same (in flight,
|error| <= 1 m, ground truth shifted by each flight's latency), so the spreads compare
with that page's "TDOA std before -> after" of the networks. Fitted on the training
flights (no bootstrap: the fit is deterministic), applied to the test flights as a
simulator or an estimator would have it:
- delays: the training flights' mean anchor delays alone (the reference);
- link: the shared coefficients alone (a new flight's delays are unknown);
- link + delays: with the training flights' mean anchor delays as well.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bias_validation import test_flights  # noqa: E402

from rig.bias.calibrate import FlightRows, calibrate, load_flights  # noqa: E402
from rig.data import paths  # noqa: E402

SPLITS = ("day-0426", "day-0425", "mode-tdoa3", "mode-tdoa2")


def spread(test: list[FlightRows], coeffs: np.ndarray, delays: dict[str, float]) -> dict:
    error = np.concatenate([r.error for r in test])
    link = np.concatenate([r.basis @ coeffs for r in test])
    delay = np.concatenate([np.array([delays.get(str(int(b)), 0.0) - delays.get(str(int(a)), 0.0)
                                      for a, b in zip(r.id_a, r.id_b)]) for r in test])
    return {"before": float(np.std(error)), "delays": float(np.std(error - delay)), "link": float(np.std(error - link)),
            "link_and_delays": float(np.std(error - link - delay)), "n": int(len(error))}


def run_split(name: str, flights: list[FlightRows]) -> dict:
    names = [r.name for r in flights]
    test = set(test_flights(name, names))
    train = [r for r in flights if r.name not in test
             and not (name == "day-0425" and r.name.startswith("0425"))]
    fitted = calibrate(train, bootstrap=0)
    coeffs = np.array([t["value_m"] for t in fitted["terms"].values()])
    delays = {str(e["params"]["anchor"]): e["params"]["meters"] for e in fitted["effects"][1:]}
    return {"split": name, "train": [r.name for r in train], "test": sorted(test), "coeffs_m": coeffs.tolist(),
            "within_bounds": fitted["within_bounds"],
            "tdoa_std_m": spread([r for r in flights if r.name in test], coeffs, delays)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "link_bias_transfer.json")
    args = parser.parse_args()
    flights = load_flights(paths.flights())
    results = [run_split(name, flights) for name in SPLITS]
    print("| split | fitted coefficients (m) | TDOA std before | training delays | link | link + training delays |")
    print("|---|---|---|---|---|---|")
    for r in results:
        s = r["tdoa_std_m"]
        print(f"| {r['split']} | {np.round(r['coeffs_m'], 3).tolist()} | {s['before']:.3f} | {s['delays']:.3f} | "
              f"{s['link']:.3f} | {s['link_and_delays']:.3f} |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
