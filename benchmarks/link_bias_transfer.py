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

Leave-one-anchor-out (the question: can the physical model, which has no anchor identity,
correct an anchor no training flight measured, where the networks abstain?): for each
anchor k and split seeds 0-2, fitted on bias_validation's training and validation
flights of that seed with every measurement involving k removed, tested on the
measurements involving k of that seed's test flights; k's unknown delay is the others'
mean (zero: delays are centred). Rule, fixed before the first run: the model corrects
an unseen anchor only if "link + delays" narrows its spread for at least 6 of the 8
anchors on every seed and widens none by more than 0.01 m; otherwise the estimator
keeps abstaining there.

Leave-sector-out (session 58; descriptive, it decides nothing): bias_validation's
quarters of the circle and seeds, for comparison with the link network's there; and per
anchor, what the model fitted to every flight leaves in each quarter.
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

from bias_validation import bearing_sector, test_flights  # noqa: E402
from bias_validation_results import SECTORS  # noqa: E402

from rig.bias.train import split_flights  # noqa: E402

from rig.bias.calibrate import FlightRows, calibrate, delay_columns, fit_coefficients, load_flights  # noqa: E402
from rig.data import paths  # noqa: E402

SPLITS = ("day-0426", "day-0425", "mode-tdoa3", "mode-tdoa2")
ANCHOR_SEEDS = (0, 1, 2)


def spread(test: list[FlightRows], coeffs: np.ndarray, delays: dict[str, float]) -> dict:
    error = np.concatenate([r.error for r in test])
    link = np.concatenate([r.basis @ coeffs for r in test])
    delay = np.concatenate([np.array([delays.get(str(int(b)), 0.0) - delays.get(str(int(a)), 0.0)
                                      for a, b in zip(r.id_a, r.id_b)]) for r in test])
    return {"before": float(np.std(error)), "delays": float(np.std(error - delay)), "link": float(np.std(error - link)),
            "link_and_delays": float(np.std(error - link - delay)), "n": int(len(error))}


def fitted_model(train: list[FlightRows]) -> tuple[np.ndarray, dict[str, float], bool]:
    """The shared coefficients, the training flights' mean delays by anchor, and
    whether every coefficient is within its bound."""
    fitted = calibrate(train, bootstrap=0)
    coeffs = np.array([t["value_m"] for t in fitted["terms"].values()])
    delays = {str(e["params"]["anchor"]): e["params"]["meters"] for e in fitted["effects"][1:]}
    return coeffs, delays, fitted["within_bounds"]


def run_split(name: str, flights: list[FlightRows]) -> dict:
    names = [r.name for r in flights]
    test = set(test_flights(name, names))
    train = [r for r in flights if r.name not in test
             and not (name == "day-0425" and r.name.startswith("0425"))]
    coeffs, delays, within = fitted_model(train)
    return {"split": name, "train": [r.name for r in train], "test": sorted(test), "coeffs_m": coeffs.tolist(),
            "within_bounds": within,
            "tdoa_std_m": spread([r for r in flights if r.name in test], coeffs, delays)}


def without_anchor(rows: FlightRows, anchor: int, keep: bool = False) -> FlightRows:
    """The rows of `rows` that do not involve `anchor` (with `keep`, only those that do)."""
    involved = (rows.id_a == anchor) | (rows.id_b == anchor)
    return rows.select(involved if keep else ~involved)


def run_anchor(anchor: int, seed: int, flights: list[FlightRows]) -> dict:
    split = split_flights([r.name for r in flights], seed)
    train = [without_anchor(r, anchor) for r in flights if r.name not in split.test]
    coeffs, delays, _ = fitted_model(train)
    test = [without_anchor(r, anchor, keep=True) for r in flights if r.name in split.test]
    return {"split": "anchors", "anchor": anchor, "seed": seed, "test": split.test, "coeffs_m": coeffs.tolist(),
            "tdoa_std_m": spread(test, coeffs, delays)}


def run_sector(sector: int, seed: int, flights: list[FlightRows]) -> dict:
    """bias_validation's leave-sector-out for the physical model: fitted on the training
    and validation flights of `seed` outside the quarter, tested inside it (quarters by
    the tag's true position here, the estimator's there)."""
    split = split_flights([r.name for r in flights], seed)
    train = [r.select(bearing_sector(r.position) != sector) for r in flights if r.name not in split.test]
    coeffs, delays, _ = fitted_model(train)
    test = [r.select(bearing_sector(r.position) == sector) for r in flights if r.name in split.test]
    return {"split": "sector", "sector": sector, "seed": seed, "test": split.test, "coeffs_m": coeffs.tolist(),
            "tdoa_std_m": spread(test, coeffs, delays)}


def place_means(flights: list[FlightRows]) -> dict[str, list[float]]:
    """Per anchor, the mean of what the link model and each flight's delays, fitted to
    every flight, leave of its ranges (TDOA residual signed + as link B, − as link A),
    in each quarter of the circle: a bias of the anchor seen from one place."""
    anchors = sorted({int(k) for r in flights for k in np.concatenate([r.id_a, r.id_b])})
    coeffs, delays = fit_coefficients(flights, anchors)
    sums, counts = np.zeros((len(anchors), SECTORS)), np.zeros((len(anchors), SECTORS))
    for rows, d in zip(flights, delays):
        left = rows.error - delay_columns(rows, anchors) @ d - rows.basis @ coeffs
        quarter = bearing_sector(rows.position)
        for i, k in enumerate(anchors):
            for sign, ids in ((1.0, rows.id_b), (-1.0, rows.id_a)):
                np.add.at(sums[i], quarter[ids == k], sign * left[ids == k])
                np.add.at(counts[i], quarter[ids == k], 1.0)
    return {str(k): (sums[i] / np.maximum(counts[i], 1.0)).round(4).tolist() for i, k in enumerate(anchors)}


def anchor_verdict(rows: list[dict]) -> dict:
    """The rule of the module docstring, per seed and overall."""
    by_seed = {}
    for seed in sorted({r["seed"] for r in rows}):
        s = [r["tdoa_std_m"] for r in rows if r["seed"] == seed]
        change = np.array([x["link_and_delays"] - x["before"] for x in s])
        by_seed[str(seed)] = {"narrowed": int(np.sum(change < 0)), "anchors": len(s),
                              "widest_widening_m": float(max(change.max(), 0.0))}
    passes = all(v["narrowed"] >= 6 and v["widest_widening_m"] <= 0.01 for v in by_seed.values())
    return {"by_seed": by_seed, "corrects_unseen_anchors": passes}


def print_table(heads: list[str], labels: list[list], rows: list[dict]) -> None:
    """A markdown table: each row's labels, then its spreads before and after each correction."""
    heads = heads + ["training delays", "link", "link + training delays"]
    print("| " + " | ".join(heads) + " |")
    print("|" + "---|" * len(heads))
    for label, r in zip(labels, rows):
        s = r["tdoa_std_m"]
        spreads = [f"{s[k]:.3f}" for k in ("before", "delays", "link", "link_and_delays")]
        print("| " + " | ".join(map(str, label + spreads)) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "link_bias_transfer.json")
    args = parser.parse_args()
    flights = load_flights(paths.flights())
    results = [run_split(name, flights) for name in SPLITS]
    print_table(["split", "fitted coefficients (m)", "TDOA std before"],
                [[r["split"], np.round(r["coeffs_m"], 3).tolist()] for r in results], results)
    anchors = [run_anchor(k, seed, flights) for seed in ANCHOR_SEEDS for k in range(8)]
    print()
    print_table(["anchor", "seed", "TDOA std on its pairs: before"], [[r["anchor"], r["seed"]] for r in anchors],
                anchors)
    verdict = anchor_verdict(anchors)
    counts = ", ".join(f"seed {seed}: {v['narrowed']} of {v['anchors']}" for seed, v in verdict["by_seed"].items())
    print(f"\nunseen anchors narrowed by link + training delays: {counts}; "
          f"corrects unseen anchors: {verdict['corrects_unseen_anchors']}")
    sectors = [run_sector(k, seed, flights) for seed in ANCHOR_SEEDS for k in range(SECTORS)]
    print()
    print_table(["quarter", "seed", "TDOA std in the quarter: before"], [[r["sector"], r["seed"]] for r in sectors],
                sectors)
    places = place_means(flights)
    print("\nper anchor, what the link model and each flight's delays leave, by quarter (m):")
    for k, means in places.items():
        print(f"  anchor {k}: " + ", ".join(f"{m:+.3f}" for m in means))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"splits": results, "anchors": anchors, "anchor_verdict": verdict,
                                     "sectors": sectors, "place_means_m": places}, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
