"""What of the TDOA bias transfers from one flight to another, and from one day to
another (docs/notebook/bias.md, "What transfers"). For each 0426 flight, the robust
estimator's 3D RMSE and the TDOA error spread without and with:

1. a lookup table, the mean error of each anchor pair in each 0.2 m cube of tag
   position, subtracted from the flight's measurements (cubes found from the ground
   truth): a bound for any correction that is a function of the geometry with this
   layout, no features, no network. Built on the 0425 flights (across days, as
   ablation (d)) and on the other 0426 flights (within the day);
2. the network trained on every other shared flight (the shipped model's training
   set minus this flight), inside the estimator: what the shipped network does on a
   flight it has not seen, taken in a setup it has; with features from the
   estimator's own pose (as shipped) and from the ground truth.

    .venv/bin/python benchmarks/bias_transfer.py [--flights 0426-traj1 ...] [--json out/bias_transfer.json]

Uses the dataset caches of bias_ablation.py (built if missing). About eighteen minutes (each left-out network is trained from three
initialisations, chosen by replaying its validation flights)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bias_ablation import CACHES, TEST_DAY  # noqa: E402  - the ablations' dataset caches and test day

from rig.bias.config import TrainConfig  # noqa: E402
from rig.bias.dataset import Samples, known_pairs, truth_latency  # noqa: E402
from rig.bias.train import fit, load_or_build_dataset, split_flights  # noqa: E402
from rig.data import paths
from rig.data.importer import load_any  # noqa: E402
from rig.data.survey import parse_survey  # noqa: E402
from rig.estimator import metrics  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402

CELL_M = 0.2
MIN_CELL_SAMPLES = 5
TRAIN_DAY = "0425"


def tag_positions(samples: Samples) -> np.ndarray:
    """Features 0-2 are anchor A minus the tag (world): the tag is anchor A, as the
    flight's survey has it, minus them."""
    a_pos = np.zeros((len(samples), 3))
    flight = samples.flight.astype(str)
    for name in np.unique(flight):
        rows = flight == name
        anchors = {a.id: a.position for a in parse_survey(paths.survey_for(paths.data_dir() / "flights" / name))}
        a_pos[rows] = [anchors[int(k)] for k in samples.id_a[rows]]
    return a_pos - samples.features[:, 0:3]


def cell_keys(tag: np.ndarray, id_a: np.ndarray, id_b: np.ndarray) -> np.ndarray:
    """One key per anchor pair and cube of tag position."""
    cell = np.floor(tag / CELL_M).astype(np.int64) + 1000
    return ((cell[:, 0] * 4096 + cell[:, 1]) * 4096 + cell[:, 2]) * 4096 + id_a.astype(np.int64) * 64 + id_b


class LookupTable:
    """The mean error of each cell of the training samples."""

    def __init__(self, keys: np.ndarray, label: np.ndarray):
        self.cells, index = np.unique(keys, return_inverse=True)
        self.counts = np.bincount(index)
        self.mean = np.bincount(index, label) / self.counts

    def predict(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cells' means, and which keys have a cell with enough samples."""
        at = np.clip(np.searchsorted(self.cells, keys), 0, len(self.cells) - 1)
        hit = (self.cells[at] == keys) & (self.counts[at] >= MIN_CELL_SAMPLES)
        return np.where(hit, self.mean[at], 0.0), hit


def lookup_spread(keys: np.ndarray, label: np.ndarray, train: np.ndarray, test: np.ndarray) -> dict:
    """Error spread on `test` before and after subtracting the table of `train`
    (test samples in cells without enough training samples are not counted)."""
    predicted, hit = LookupTable(keys[train], label[train]).predict(keys[test])
    before = label[test][hit]
    return {"coverage": float(hit.mean()), "before": float(before.std()),
            "after": float((before - predicted[hit]).std())}


class Flight:
    """One test flight, loaded once: the recording, its TDOA rows with known anchors,
    their lookup-table cells (at the ground truth's tag position) and the robust
    estimator's 3D RMSE without correction."""

    def __init__(self, name: str):
        self.name = name
        self.rec = load_any(paths.data_dir() / "flights" / name)
        self.rows = np.flatnonzero(known_pairs(self.rec))
        tag = metrics.interpolate_positions(self.rec.truth, self.rec.tdoa.t[self.rows] + truth_latency(self.rec))
        self.keys = cell_keys(tag, self.rec.tdoa.id_a[self.rows], self.rec.tdoa.id_b[self.rows])
        self.without = evaluate(self.rec, use_nn=False)["rmse_3d"]

    def corrected_by(self, table: LookupTable) -> dict:
        """The RMSE without and with the TDOA corrected beforehand by `table` (cells found
        from the ground truth: optimistic, the estimator only knows its own position)."""
        corrected = self.rec.tdoa.distance_diff.copy()
        corrected[self.rows] -= table.predict(self.keys)[0]
        rec = dataclasses.replace(self.rec, tdoa=dataclasses.replace(self.rec.tdoa, distance_diff=corrected))
        return {"without": self.without, "with": evaluate(rec, use_nn=False)["rmse_3d"]}


class Tables:
    """Per flight of the test day: the table across days (built on the training day) and
    the table within the day (built on the test day's other flights)."""

    def __init__(self, samples: Samples):
        self.flight = samples.flight.astype(str)
        self.keys = cell_keys(tag_positions(samples), samples.id_a, samples.id_b)
        self.label = samples.label

    def on(self, day: str) -> np.ndarray:
        return np.char.startswith(self.flight, day)

    def across_days(self) -> np.ndarray:
        return self.on(TRAIN_DAY)

    def within_day(self, name: str) -> np.ndarray:
        return self.on(TEST_DAY) & (self.flight != name)

    def row(self, flight: Flight) -> dict:
        """TDOA error spread and end-to-end RMSE of `flight` with either table."""
        out = {}
        for kind, train in (("across days", self.across_days()), ("within day", self.within_day(flight.name))):
            out[kind] = lookup_spread(self.keys, self.label, train, self.flight == flight.name)
            out[kind].update(flight.corrected_by(LookupTable(self.keys[train], self.label[train])))
        return out


def left_out(flight: Flight, samples: Samples, features_from: str) -> dict:
    """The network trained on every flight of `samples` but `flight`, inside the
    estimator on `flight`."""
    split = split_flights(sorted(set(samples.flight.astype(str))), 0, [flight.name])
    net, report = fit(samples, split, TrainConfig(seed=0))
    model = ROOT / "out" / "transfer" / features_from / f"{flight.name}.json"
    model.parent.mkdir(parents=True, exist_ok=True)
    net.save(model)
    return {"before": report["test"]["before"]["std"], "after": report["test"]["after"]["std"],
            "without": flight.without, "with": evaluate(flight.rec, model_path=model)["rmse_3d"]}


def flight_job(name: str) -> tuple[str, dict]:
    datasets = {features_from: load_or_build_dataset(paths.flights(), cache, features_from=features_from)[0]
                for features_from, cache in CACHES.items()}
    flight = Flight(name)
    row = Tables(datasets["truth"]).row(flight)
    row["network, left out"] = left_out(flight, datasets["estimate"], "estimate")
    row["network, left out, features from the ground truth"] = left_out(flight, datasets["truth"], "truth")
    print(f"  {name}: " + "; ".join(f"{kind} {r['without']:.3f} -> {r['with']:.3f} m" for kind, r in row.items()),
          flush=True)
    return name, row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", help=f"flights of {TEST_DAY} to test (default: all)")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "bias_transfer.json")
    args = parser.parse_args()
    for features_from, cache in CACHES.items():      # built once, before the workers
        load_or_build_dataset(paths.flights(), cache, features_from=features_from)
    flights = args.flights or sorted(p.name for p in paths.flights() if p.name.startswith(TEST_DAY))
    print("robust estimator's 3D RMSE without -> with each correction:")
    with Pool(2) as pool:
        rows = dict(pool.map(flight_job, flights))
    kinds = list(next(iter(rows.values())))
    mean = {kind: {k: float(np.mean([rows[f][kind][k] for f in flights])) for k in ("before", "after", "without", "with")}
            for kind in kinds}
    print("| correction | TDOA error std before -> after (m) | 3D RMSE without -> with (m) |")
    print("|---|---|---|")
    for kind, m in mean.items():
        print(f"| {kind} | {m['before']:.3f} -> {m['after']:.3f} | {m['without']:.3f} -> {m['with']:.3f} "
              f"({1 - m['with'] / m['without']:.0%} lower) |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": rows, "mean": mean}, indent=1))


if __name__ == "__main__":
    main()
