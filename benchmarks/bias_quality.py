"""What else moves the 0426 target of the bias network (docs/notebook/bias.md): the estimator's
TDOA noise with corrected measurements, and dropping the measurements that a second
network rates worst. Uses ablation (d)'s network, trained without the 0426 flights
(run benchmarks/bias_ablation.py first).

    .venv/bin/python benchmarks/bias_quality.py [--json out/bias_quality.json]

The quality network has the bias network's shape (14 features, 3 x 30 ReLU) and one
output, the log-variance of the corrected measurement's error (Gaussian likelihood),
trained on the 0425 and 0422 flights. Not part of the estimator: an estimate of what
weighting measurements by their predicted quality could gain. About a minute."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bias_ablation import CACHES, OUT, TEST_DAY  # noqa: E402  - ablation (d): its network, test day, dataset

from rig.bias.dataset import known_pairs, measurement_features, truth_latency  # noqa: E402
from rig.bias.train import import_torch, load_or_build_dataset  # noqa: E402
from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.estimator.bias_net import BiasNet  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402

MODEL = OUT / "d14" / "bias_net.json"
TDOA_STDS = (0.25, 0.3, 0.5)
DROPPED = (0.1, 0.2, 0.3)


def quality_network(features: np.ndarray, residual: np.ndarray, seed: int = 0, epochs: int = 6):
    """log-variance of the residual as a function of the features (seeded, CPU)."""
    torch = import_torch()
    torch.manual_seed(seed)
    mean, scale = features.mean(0), features.std(0) + 1e-6
    x = torch.tensor(((features - mean) / scale).astype(np.float32))
    r = torch.tensor(residual.astype(np.float32))
    layers = [torch.nn.Linear(14, 30), torch.nn.ReLU(), torch.nn.Linear(30, 30), torch.nn.ReLU(),
              torch.nn.Linear(30, 30), torch.nn.ReLU(), torch.nn.Linear(30, 1)]
    model = torch.nn.Sequential(*layers)
    optimizer = torch.optim.Adam(model.parameters(), 1e-3)
    for _ in range(epochs):
        order = torch.randperm(len(x))
        for i in range(0, len(x), 512):
            batch = order[i:i + 512]
            log_var = model(x[batch])[:, 0]
            loss = (0.5 * log_var + 0.5 * r[batch] ** 2 / torch.exp(log_var)).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

    def predict(f: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return np.exp(0.5 * model(torch.tensor(((f - mean) / scale).astype(np.float32))).numpy()[:, 0])
    return predict


def flight_job(name: str, quality) -> dict:
    rec = load_any(paths.data_dir() / "flights" / name)
    out = {"without": evaluate(rec, use_nn=False)["rmse_3d"], "with": evaluate(rec, model_path=MODEL)["rmse_3d"]}
    for std in TDOA_STDS:
        out[f"tdoa_std {std}"] = evaluate(rec, model_path=MODEL, tdoa_std=std)["rmse_3d"]
    rows = np.flatnonzero(known_pairs(rec))
    features = measurement_features(rec, rows, truth_latency(rec))[0]
    sigma = quality(features)
    for share in DROPPED:
        keep = np.ones(len(rec.tdoa.t), bool)
        keep[rows[sigma > np.quantile(sigma, 1.0 - share)]] = False
        dropped = dataclasses.replace(rec, tdoa=rec.tdoa.select(keep))
        out[f"dropped {share:.0%}"] = evaluate(dropped, model_path=MODEL)["rmse_3d"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "bias_quality.json")
    args = parser.parse_args()
    samples, _ = load_or_build_dataset(paths.flights(), CACHES["estimate"])
    residual = samples.label - BiasNet.load(MODEL).predict(samples.features, samples.id_a, samples.id_b)
    train = ~np.char.startswith(samples.flight.astype(str), TEST_DAY)
    quality = quality_network(samples.features[train], residual[train])
    sigma = quality(samples.features[~train])
    correlation = float(np.corrcoef(np.abs(residual[~train]), sigma)[0, 1])
    print(f"quality network on the {TEST_DAY} flights: correlation with |error| {correlation:.2f}")
    flights = sorted(p.name for p in (paths.data_dir() / "flights").iterdir() if p.name.startswith(TEST_DAY))
    rows = [flight_job(name, quality) for name in flights]
    keys = list(rows[0])
    print("| flight | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for name, row in zip(flights, rows):
        print(f"| {name} | " + " | ".join(f"{row[k]:.3f}" for k in keys) + " |")
    means = {k: float(np.mean([row[k] for row in rows])) for k in keys}
    print("| **mean** | " + " | ".join(f"{means[k]:.3f}" for k in keys) + " |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"correlation": correlation, "flights": dict(zip(flights, rows)),
                                     "mean": means}, indent=1))


if __name__ == "__main__":
    main()
