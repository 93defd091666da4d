"""What down-weighting the anchors whose links are biased at the moment could recover at
most: an oracle that knows, from the ground truth, each anchor's range bias over each
second of flight, on the 0426 flights with their within-0426 networks (session 83).

    .venv/bin/python benchmarks/nlos_oracle.py       # ~5 min; out/nlos_oracle.json

The question. 0426-traj6 (TDOA3, a wooden shelf) gains 11 % from its network, its TDOA2
twin traj4 32 %; the issue's six held-out TDOA3 flights with obstacles gained 17 %. An
obstacle lengthens every link to the anchor it blocks, and in TDOA3 that anchor is paired
with all the others: a per-anchor weighting would be a state of a few floats per anchor.
Before a causal detector is built, this oracle bounds what any detector could do.

The oracle, fixed before its first run. For each one-second block of flight the residual
of every TDOA measurement (measured − true, less the network's prediction; the raw error
without a network) is split by least squares into one range bias per anchor (their sum
zero over the anchors heard in the block; measurements with |residual| ≥ 1 m left out of
the fit, as the training labels leave them). Then, in the recording the estimator replays:
- `drop τ`: every measurement of the block that involves an anchor with |bias| > τ is
  removed (τ = 0.15 m decides; 0.10 and 0.25 m are shown for their sensitivity only);
- `subtract`: every measurement is corrected by its two anchors' biases (B − A), the
  ceiling of any per-anchor correction.
The estimator runs as shipped then (the share of the correction each flight supports, and
no blocked-anchor weighting, which this oracle led to: `UNWEIGHTED`), with the
network that held the flight out (`within-0426-a|b.link.seed{0,1,2}`, saved by
`bias_validation.py --save-models`), and without correction.

The rule, fixed before its first run: a causal per-anchor down-weighting is worth building
only if `drop 0.15` with the network lowers 0426-traj6's 3D RMSE (mean over seeds) by at
least 0.02 m and the mean over the eight flights by at least 0.01 m. Otherwise it is not
pursued.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402
from bias_validation_results import WITHIN_0426_FOLDS  # noqa: E402

from rig.data import paths  # noqa: E402

BLOCK_S = 1.0
DECIDING_TAU_M = 0.15
TAUS_M = (0.10, 0.15, 0.25)
SEEDS = (0, 1, 2)
OUTLIER_M = 1.0
TARGET_FLIGHT, TARGET_GAIN_M, MEAN_GAIN_M = "0426-traj6", 0.02, 0.01
# the estimator as shipped when the oracle ran: without the blocked-anchor weighting it led to
UNWEIGHTED = {"anchor_bias_c": 0.0}


def anchor_biases(residual: np.ndarray, id_a: np.ndarray, id_b: np.ndarray) -> dict[int, float]:
    """Least-squares range bias per anchor (sum zero) of residual ≈ bias[B] − bias[A]."""
    fit = np.abs(residual) < OUTLIER_M
    ids = np.unique(np.concatenate([id_a[fit], id_b[fit]]))
    if len(ids) < 2:
        return {}
    col = {int(k): j for j, k in enumerate(ids)}
    rows = np.flatnonzero(fit)
    design = np.zeros((len(rows), len(ids)))
    design[np.arange(len(rows)), [col[int(k)] for k in id_b[rows]]] += 1.0
    design[np.arange(len(rows)), [col[int(k)] for k in id_a[rows]]] -= 1.0
    bias = np.linalg.lstsq(design, residual[rows], rcond=None)[0]
    return {k: float(bias[j] - bias.mean()) for k, j in col.items()}


def block_biases(t: np.ndarray, residual: np.ndarray, id_a: np.ndarray, id_b: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Each measurement's anchor A and anchor B bias, from its one-second block's split."""
    block = np.floor((t - t[0]) / BLOCK_S).astype(int)
    bias_a, bias_b = np.zeros(len(t)), np.zeros(len(t))
    for k in np.unique(block):
        rows = block == k
        split = anchor_biases(residual[rows], id_a[rows], id_b[rows])
        bias_a[rows] = [split.get(int(i), 0.0) for i in id_a[rows]]
        bias_b[rows] = [split.get(int(i), 0.0) for i in id_b[rows]]
    return bias_a, bias_b


def variants(rec, rows: np.ndarray, bias_a: np.ndarray, bias_b: np.ndarray) -> dict:
    """The recording as each oracle variant replays it."""
    out = {"as is": rec}
    for tau in TAUS_M:
        keep = np.ones(len(rec.tdoa), bool)
        keep[rows[(np.abs(bias_a) > tau) | (np.abs(bias_b) > tau)]] = False
        out[f"drop {tau:.2f}"] = replace(rec, tdoa=rec.tdoa.select(keep))
    diff = rec.tdoa.distance_diff.copy()
    diff[rows] -= bias_b - bias_a
    out["subtract"] = replace(rec, tdoa=replace(rec.tdoa, distance_diff=diff))
    return out


def model_path(models: Path, flight: str, seed: int) -> Path:
    fold = next(f for f, held in WITHIN_0426_FOLDS.items() if flight in held)
    return models / f"within-0426-{fold}.link.seed{seed}.json"


def flight_figures(job: tuple[str, str | None]) -> dict:
    """One flight's 3D RMSE in each variant, with the network at `model` or without one."""
    from rig.bias.dataset import airborne_tdoa, measurement_features, true_tdoa, truth_latency
    from rig.data.importer import load_any
    from rig.estimator.bias_net import BiasNet
    from rig.estimator.evaluate import evaluate

    flight, model = job
    rec = load_any(paths.data_dir() / "flights" / flight)
    net = BiasNet.load(Path(model)) if model else None
    sel = airborne_tdoa(rec)
    rows = np.flatnonzero(sel)
    feats, tag_pos, a_pos, b_pos = measurement_features(rec, sel, truth_latency(rec))
    id_a, id_b = rec.tdoa.id_a[rows], rec.tdoa.id_b[rows]
    residual = rec.tdoa.distance_diff[rows] - true_tdoa(tag_pos, a_pos, b_pos)
    if net is not None:
        residual = residual - net.predict(feats, id_a, id_b)
    bias_a, bias_b = block_biases(rec.tdoa.t[rows], residual, id_a, id_b)
    figures = {name: evaluate(r, use_nn=net is not None, model=net, **UNWEIGHTED)["rmse_3d"]
               for name, r in variants(rec, rows, bias_a, bias_b).items()}
    figures["share dropped"] = {f"{tau:.2f}": float(np.mean((np.abs(bias_a) > tau) | (np.abs(bias_b) > tau)))
                                for tau in TAUS_M}
    return figures


def summarise(results: dict) -> dict:
    """Mean over seeds of each flight's figure per variant, and the rule's verdict."""
    names = [k for k in next(iter(results.values()))["none"] if k != "share dropped"]
    table = {}
    for flight, runs in results.items():
        nets = [runs[f"seed{s}"] for s in SEEDS]
        table[flight] = {"none": {n: runs["none"][n] for n in names},
                         "network": {n: float(np.mean([r[n] for r in nets])) for n in names},
                         "network min-max": {n: [min(r[n] for r in nets), max(r[n] for r in nets)] for n in names}}
    deciding = f"drop {DECIDING_TAU_M:.2f}"
    target = table[TARGET_FLIGHT]["network"]
    mean = {n: float(np.mean([table[f]["network"][n] for f in table])) for n in names}
    verdict = (target["as is"] - target[deciding] >= TARGET_GAIN_M) and (mean["as is"] - mean[deciding] >= MEAN_GAIN_M)
    return {"flights": table, "mean with network": mean,
            "mean without": {n: float(np.mean([table[f]["none"][n] for f in table])) for n in names},
            "build a detector": bool(verdict)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=Path, default=ROOT / "out" / "models" / "link-amd")
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "nlos_oracle.json")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    flights = [f for held in WITHIN_0426_FOLDS.values() for f in held]
    jobs = {(f, "none"): (f, None) for f in flights}
    jobs.update({(f, f"seed{s}"): (f, str(model_path(args.models, f, s))) for f in flights for s in SEEDS})
    with ProcessPoolExecutor(args.workers) as pool:
        done = dict(zip(jobs, pool.map(flight_figures, jobs.values())))
    results = {f: {run: done[(f, run)] for (g, run) in jobs if g == f} for f in sorted(flights)}
    summary = summarise(results)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": results, "summary": summary}, indent=1))
    names = list(summary["mean with network"])
    print(f"{'flight':<12} " + " ".join(f"{n:>10}" for n in names))
    for flight, row in summary["flights"].items():
        for kind in ("none", "network"):
            print(f"{flight:<12} " + " ".join(f"{row[kind][n]:10.3f}" for n in names) + f"  {kind}")
    for kind in ("mean without", "mean with network"):
        print(f"{kind:<12} " + " ".join(f"{summary[kind][n]:10.3f}" for n in names))
    print("build a detector:", summary["build a detector"])


if __name__ == "__main__":
    main()
