"""An estimator parameter's value chosen by transfer, on the very networks of the kept
link rows: each day, mode and within-0426 split's network (`bias_validation.py
--save-models out/models/link`, which session 70 reran to the kept rows' last digit)
replayed on its own test flights at each value, with its correction and without.
Seconds to minutes, once the networks are saved:

    .venv/bin/python benchmarks/bias_validation.py --forms link \
        --splits day-0426 day-0425 mode-tdoa3 mode-tdoa2 within-0426 day-0422 \
        --json out/link-models.json --save-models out/models/link                    # 11 min, once
    .venv/bin/python benchmarks/param_transfer.py --param tdoa_std --values 0.3 0.55      # session 71
    .venv/bin/python benchmarks/param_transfer.py --param accel_noise --values 0.25 1.0   # session 71
    .venv/bin/python benchmarks/param_transfer.py --param gm_meas_c2 --values 4 16        # session 71
    .venv/bin/python benchmarks/param_transfer.py --param trust_prior_n --values 500 8000 # session 71
    .venv/bin/python benchmarks/param_transfer.py --param gyro_noise --values 0.05 0.2    # session 72
    .venv/bin/python benchmarks/param_transfer.py --param gm_state_c2 --values 1 4        # session 72
    .venv/bin/python benchmarks/param_transfer.py --param irls_iterations --values 1 3    # session 72
    .venv/bin/python benchmarks/param_transfer.py --param gate_m --values 1.0 2.5         # session 72
    .venv/bin/python benchmarks/param_transfer.py --param anchor_bias_c --values 0 0.25 \
        --models out/models/link-amd --held-out-at 0                                    # session 83, 20 s
    # session 84: each of the eight above again (and trust_prior_n -1, the whole correction) with
    # the weighting on, --models out/models/link-amd --json out/transfer84-PARAM.json: every one stays

The rule, fixed before the first run (session 71, for `tdoa_std`, and the same for every
parameter since). Each flight's figure is the shipped estimator's (the share of the
correction the flight supports), with its correction and without (`--no-nn`) at the same
value. Accuracy is the mean over the four day and mode splits of the mean 3D RMSE over
seeds; flights worse is the sum over those splits of the mean over seeds of the flights
the correction makes worse than none. A value replaces the shipped one only if
(1) its accuracy is lower by at least 0.003 m;
(2) its flights worse are no more;
(3) within-0426 its mean is no higher, with no flight worse on any seed;
(4) on day-0422 its mean is at most 0.002 m higher and its flights worse no more.
If several pass, the one with the lowest accuracy. The networks were each chosen among
their restarts at the shipped values, which favours them: a value that passes does so
against that.

It also prints the issue's 0426 check estimated per UWB mode at each value, from
within-0426, day-0426 and, when its networks are saved too (`--splits setup-0426`),
setup-0426; and, when saved, within-0425's figures. Those weigh nothing in the rule.
"""

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
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402
from bias_validation_results import HELD_OUT_0426_BY_MODE, TDOA3  # noqa: E402
from trust_rule import ACCURACY_SPLITS, KEPT  # noqa: E402

from rig.data import paths  # noqa: E402
from rig.estimator.native import default_params  # noqa: E402

SPLITS = (*ACCURACY_SPLITS, "within-0426", "day-0422")
# replayed too when their networks are saved, shown and weighing nothing in the rule:
# setup-0426 (both flights of each obstacle setup held out) for the per-mode estimate of the
# 0426 check, within-0425 (new flights of the other trained day) for its figures
ESTIMATE_ONLY = ("setup-0426", "within-0425")
GAIN_M, DAY_0422_TOLERANCE_M = 0.003, 0.002


def model_file(models: Path, row: dict) -> Path:
    fold = f"-{row['fold']}" if "fold" in row else ""
    return models / f"{row['split']}{fold}.link.seed{row['seed']}.json"


def flight_figures(job: tuple[str, str | None, str, tuple[float, ...]]) -> dict:
    """One flight's 3D RMSE at each value of `param`, with the network at `model` (its
    correction as the shipped estimator applies it) or without correction (`model` None)."""
    from rig.data.importer import load_any
    from rig.estimator.bias_net import BiasNet
    from rig.estimator.evaluate import evaluate

    flight, model, param, values = job
    rec = load_any(paths.data_dir() / "flights" / flight)
    net = BiasNet.load(Path(model)) if model else None
    return {str(v): evaluate(rec, use_nn=net is not None, model=net, **{param: setting(param, v)})["rmse_3d"]
            for v in values}


def setting(param: str, value: float) -> float | int:
    """`value` as the C field takes it: a count (irls_iterations) is an integer."""
    if isinstance(getattr(default_params(), param), int):
        if not float(value).is_integer():
            raise ValueError(f"{param} is a count, not {value}")
        return int(value)
    return value


def replay_rows(rows: list[dict], models: Path, param: str, values: tuple[float, ...]) -> list[dict]:
    """Every row's test flights at every value: `flights` as the kept rows hold them,
    each with `by_level` and `without_by_level`."""
    flights = sorted({f["flight"] for r in rows for f in r["flights"]})
    jobs = [(f, None) for f in flights] + [(f["flight"], str(model_file(models, r))) for r in rows for f in r["flights"]]
    jobs = [(*job, param, values) for job in jobs]
    with ProcessPoolExecutor(max_workers=2) as pool:
        results = dict(zip(jobs, pool.map(flight_figures, jobs, chunksize=4)))
    return [{**r, "flights": [{**f, "by_level": results[(f["flight"], str(model_file(models, r)), param, values)],
                               "without_by_level": results[(f["flight"], None, param, values)]}
                              for f in r["flights"]]}
            for r in rows]


def split_figures(rows: list[dict], split: str, level: float) -> tuple[float, float, int]:
    """Mean over seeds of the mean 3D RMSE and of the flights made worse, and the most
    flights made worse on one seed (folds pooled)."""
    means, worse = [], []
    for seed in sorted({r["seed"] for r in rows if r["split"] == split}):
        flights = [f for r in rows if r["split"] == split and r["seed"] == seed for f in r["flights"]]
        means.append(np.mean([f["by_level"][str(level)] for f in flights]))
        worse.append(sum(f["by_level"][str(level)] > f["without_by_level"][str(level)] for f in flights))
    return float(np.mean(means)), float(np.mean(worse)), int(max(worse))


def verdict(rows: list[dict], values: tuple[float, ...], shipped: float) -> dict:
    fig = {str(v): {split: split_figures(rows, split, v) for split in SPLITS} for v in values}
    accuracy = {s: float(np.mean([f[split][0] for split in ACCURACY_SPLITS])) for s, f in fig.items()}
    worse = {s: float(sum(f[split][1] for split in ACCURACY_SPLITS)) for s, f in fig.items()}
    ship, base = str(shipped), fig[str(shipped)]
    passing = {}
    for s in fig:
        if s == ship:
            continue
        f = fig[s]
        passing[s] = {"1": accuracy[s] <= accuracy[ship] - GAIN_M, "2": worse[s] <= worse[ship],
                      "3": f["within-0426"][0] <= base["within-0426"][0] and f["within-0426"][2] == 0,
                      "4": (f["day-0422"][0] <= base["day-0422"][0] + DAY_0422_TOLERANCE_M
                            and f["day-0422"][1] <= base["day-0422"][1])}
    kept = [s for s, c in passing.items() if all(c.values())]
    return {"figures": fig, "accuracy_m": accuracy, "worse_flights": worse, "conditions": passing,
            "value": float(min(kept, key=accuracy.get)) if kept else shipped}


def held_out_0426(rows: list[dict], split: str, level: float, measured_at: float) -> dict:
    """The issue's 0426 check estimated per UWB mode from `split`'s 0426 flights: each
    mode's gain at `level` over the estimator without correction at `measured_at` (the
    value the held-out figures were measured with), applied to the held-out flights of
    that mode; mean over seeds, and their min and max."""
    estimates = []
    for seed in sorted({r["seed"] for r in rows if r["split"] == split}):
        flights = [f for r in rows if r["split"] == split and r["seed"] == seed for f in r["flights"]
                   if f["flight"].startswith("0426")]
        held = 0.0
        for mode, (n, without) in HELD_OUT_0426_BY_MODE.items():
            runs = [f for f in flights if (f["flight"] in TDOA3) == (mode == "TDOA3")]
            gain = 1 - np.mean([f["by_level"][str(level)] for f in runs]) / \
                np.mean([f["without_by_level"][str(measured_at)] for f in runs])
            held += n * without * (1 - gain)
        estimates.append(held / sum(n for n, _ in HELD_OUT_0426_BY_MODE.values()))
    return {"mean": float(np.mean(estimates)), "min": float(min(estimates)), "max": float(max(estimates))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--param", required=True, help="an estimator parameter (est_params_t), e.g. tdoa_std")
    parser.add_argument("--values", nargs="+", type=float, required=True, help="the values tried beside the shipped one")
    parser.add_argument("--models", type=Path, default=ROOT / "out" / "models" / "link")
    parser.add_argument("--json", type=Path, help="default: out/transfer-PARAM.json")
    parser.add_argument("--held-out-at", type=float, metavar="VALUE",
                        help="the value the issue's held-out 0426 figures were measured with, for the per-mode "
                             "estimate of that check (default: the shipped one)")
    args = parser.parse_args()
    defaults = default_params().as_dict()
    if args.param not in defaults:
        parser.error(f"--param {args.param}: not an estimator parameter ({', '.join(defaults)})")
    shipped = round(float(defaults[args.param]), 6)          # as the C default reads in decimal
    values = tuple(sorted({shipped, *args.values}))
    args.json = args.json or ROOT / "out" / f"transfer-{args.param}.json"
    kept = [r for r in json.loads(KEPT.read_text())["rows"] if r["form"] == "link" and "flights" in r]
    rows = [r for r in kept if r["split"] in SPLITS]
    missing = [str(model_file(args.models, r)) for r in rows if not model_file(args.models, r).is_file()]
    if missing:
        parser.error(f"{len(missing)} networks are missing, e.g. {missing[0]}: save them first (see above)")
    for split in ESTIMATE_ONLY:
        extra = [r for r in kept if r["split"] == split]
        if extra and all(model_file(args.models, r).is_file() for r in extra):
            rows += extra
    rows = replay_rows(rows, args.models, args.param, values)
    # the shipped value must give the kept rows' figures: the same networks, the same estimator
    drift = max(abs(f["by_level"][str(shipped)] - f["rmse_3d"]) for r in rows for f in r["flights"]
                if r["split"] in SPLITS)
    result = verdict(rows, values, shipped)
    shown = [s for s in ESTIMATE_ONLY if any(r["split"] == s for r in rows)]
    result["shown"] = {str(v): {s: split_figures(rows, s, v) for s in shown} for v in values}
    for split in (*SPLITS, *shown):
        figures = result["figures"] if split in SPLITS else result["shown"]
        cells = " | ".join(f"{v}: {f[split][0]:.4f} m, {f[split][1]:.2f} worse" for v, f in figures.items())
        print(f"{split:12s} {cells}{'' if split in SPLITS else '   (shown only)'}")
    if shown:   # at the value the kept rows were made with, 0: the very networks of the kept rows
        apart = {str(v): max(abs(f["by_level"][str(v)] - f["rmse_3d"]) for r in rows if r["split"] in shown
                             for f in r["flights"]) for v in values}
        print(f"largest difference from the kept rows of {', '.join(shown)}, at each value: {apart}")
    print(json.dumps({"param": args.param, "shipped": shipped, **{k: v for k, v in result.items() if k != "figures"}}))
    print(f"largest difference from the kept rows at the shipped {shipped:g}: {drift:.2e} m")
    measured_at = shipped if args.held_out_at is None else round(args.held_out_at, 6)
    if measured_at not in values:
        parser.error(f"--held-out-at {measured_at:g} is not among the values run ({values})")
    result["held_out_0426"] = {split: {str(v): held_out_0426(rows, split, v, measured_at) for v in values}
                               for split in ("within-0426", "day-0426", "setup-0426")
                               if any(r["split"] == split for r in rows)}
    for split, by_value in result["held_out_0426"].items():
        cells = " | ".join(f"{v}: {e['mean']:.4f} m ({e['min']:.4f}–{e['max']:.4f})" for v, e in by_value.items())
        print(f"the 0426 check per mode from {split} (without correction at {measured_at:g}): {cells}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"param": args.param, "shipped": shipped, "rows": rows, **result,
                                     "kept_rows_drift_m": drift}, indent=1))


if __name__ == "__main__":
    main()
