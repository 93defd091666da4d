"""Bias-network ablations on the shared flights; regenerates docs/notebook/bias.md.

    .venv/bin/python benchmarks/bias_ablation.py [--json out/bias_ablation.json]

(a) the 14 features, (b) without the anchors' orientation (10 features), each on
the default seeded 70/15/15 flight split; (c) leave-anchors-out: no measurement
involving anchors {k} in training, tested on the test flights' measurements that
involve them, with 14 and 10 features; (d) trained on 0425 + 0422, tested on
0426, and once more with features from the ground truth instead of the estimator's
own pose: TDOA error statistics and histograms, and the robust estimator's 3D RMSE
on every 0426 flight with and without the correction; (d) again with seeds 1, 2, 3
for the seed-to-seed spread. Takes about twenty minutes."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.bias.config import TrainConfig  # noqa: E402
from rig.bias.dataset import Samples  # noqa: E402
from rig.bias.train import run_training  # noqa: E402
from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.estimator.bias_net import BiasNet  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402

OUT = ROOT / "out" / "ablation"
CACHES = {"estimate": ROOT / "out" / "cache" / "all.npz", "truth": ROOT / "out" / "cache" / "all_truth.npz"}
LEAVE_OUT = [[0], [3], [1, 6]]
OTHER_SEEDS = (1, 2, 3)
TEST_DAY = "0426"


def train(name: str, features: str, features_from: str = "estimate", seed: int = 0, **kwargs) -> dict:
    out = OUT / name / "bias_net.json"
    prov = run_training(paths.flights(), out, config=TrainConfig.with_features(features, seed=seed),
                        dataset_cache=CACHES[features_from], features_from=features_from, **kwargs)
    prov["path"] = str(out)
    print(f"{name}: test std {prov['test']['before']['std']:.3f} -> {prov['test']['after']['std']:.3f} m", flush=True)
    return prov


def end_to_end(model: Path) -> list[dict]:
    rows = []
    for flight in [f for f in paths.flights() if f.name.startswith(TEST_DAY)]:
        rec = load_any(flight)
        without = evaluate(rec, use_nn=False)
        with_nn = evaluate(rec, model_path=model)
        rows.append({"flight": flight.name, "without": without["rmse_3d"], "with": with_nn["rmse_3d"],
                     "diverged": without["diverged"] or with_nn["diverged"]})
        print(f"  {flight.name}: {without['rmse_3d']:.3f} -> {with_nn['rmse_3d']:.3f} m", flush=True)
    return rows


def mean_rmse(rows: list[dict], column: str = "with") -> float:
    return float(np.mean([r[column] for r in rows]))


def histogram(samples: Samples, models: dict[str, Path], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    bins = np.linspace(-1, 1, 101)
    ax.hist(samples.label, bins, density=True, color="0.6", label=f"before (σ {samples.label.std():.3f} m)")
    for (name, path), colour in zip(models.items(), ("tab:red", "teal")):
        residual = samples.label - BiasNet.load(path).predict(samples.features, samples.id_a, samples.id_b)
        ax.hist(residual, bins, density=True, histtype="step", lw=1.8, color=colour,
                label=f"{name} (σ {residual.std():.3f} m)")
    ax.set_xlabel("TDOA error (m)")
    ax.set_ylabel("density")
    ax.set_title(f"{TEST_DAY} flights, network trained on the other days")
    ax.legend()
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def stats_cells(stats: dict) -> str:
    b, a = stats["before"], stats["after"]
    return f"{b['mean']:+.3f} / {b['std']:.3f} | {a['mean']:+.3f} / {a['std']:.3f} | {b['n']}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "bias_ablation.json")
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "notebook" / "bias.md")
    args = parser.parse_args()
    runs = {"(a) 14 features": train("a14", "14"), "(b) 10 features": train("b10", "10")}
    for anchors in LEAVE_OUT:
        key = ",".join(map(str, anchors))
        for features in ("14", "10"):
            runs[f"(c) without anchors {key}, {features} features"] = train(
                f"c{key.replace(',', '_')}-{features}", features, exclude_anchors=anchors)
    held_out = {"14": f"(d) {TEST_DAY} held out, 14 features", "10": f"(d) {TEST_DAY} held out, 10 features",
                "14, from the ground truth": f"(d) {TEST_DAY} held out, 14 features from the ground truth"}
    runs[held_out["14"]] = train("d14", "14", test_prefixes=[TEST_DAY])
    runs[held_out["10"]] = train("d10", "10", test_prefixes=[TEST_DAY])
    runs[held_out["14, from the ground truth"]] = train("d14-truth", "14", "truth", test_prefixes=[TEST_DAY])
    e2e = {column: end_to_end(Path(runs[name]["path"])) for column, name in held_out.items()}
    means = {column: mean_rmse(rows) for column, rows in e2e.items()}
    base = mean_rmse(e2e["14"], "without")
    seeds = {0: means["14"]}
    for seed in OTHER_SEEDS:
        model = Path(train(f"d14-seed{seed}", "14", seed=seed, test_prefixes=[TEST_DAY])["path"])
        seeds[seed] = mean_rmse(end_to_end(model))
    samples = Samples.load(CACHES["estimate"])
    test = samples.select(np.char.startswith(samples.flight.astype(str), TEST_DAY))
    histogram(test, {"14 features": Path(runs[held_out["14"]]["path"]),
                     "10 features": Path(runs[held_out["10"]]["path"])},
              ROOT / "docs" / "img" / "bias_histogram.png")
    table = ["| ablation | test: mean / std before (m) | after (m) | samples |", "|---|---|---|---|"]
    table += [f"| {name} | {stats_cells(r['test'])} |" for name, r in runs.items()]
    e2e_table = ["| flight | robust EKF | " + " | ".join(f"+ network ({c})" for c in e2e) + " |",
                 "|---|---|" + "---|" * len(e2e)]
    for rows in zip(*e2e.values()):
        e2e_table.append(f"| {rows[0]['flight']} | {rows[0]['without']:.3f} | "
                         + " | ".join(f"{r['with']:.3f}" for r in rows) + " |")
    e2e_table.append(f"| **mean** | **{base:.3f}** | " + " | ".join(
        f"**{m:.3f}** ({1 - m / base:.0%} lower)" for m in means.values()) + " |")
    seed_table = ["| seed | " + " | ".join(map(str, seeds)) + " |", "|---|" + "---|" * len(seeds),
                  "| mean 3D RMSE (m) | " + " | ".join(f"{m:.3f}" for m in seeds.values()) + " |",
                  "| lower than without | " + " | ".join(f"{1 - m / base:.0%}" for m in seeds.values()) + " |"]
    text = (ROOT / "docs" / "notebook" / "bias.md.in").read_text()
    for key, lines in (("ABLATIONS", table), ("END_TO_END", e2e_table), ("SEEDS", seed_table)):
        text = text.replace("{{" + key + "}}", "\n".join(lines))
    args.doc.write_text(text)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": {k: {kk: v for kk, v in r.items() if kk != "history"}
                                              for k, r in runs.items()},
                                     "end_to_end": e2e, "mean_rmse": {"without": base, **means},
                                     "seeds_mean_rmse": seeds}, indent=2) + "\n")
    print(f"wrote {args.doc} and {args.json}")


if __name__ == "__main__":
    main()
