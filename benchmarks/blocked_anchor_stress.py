"""Does the blocked-anchor weighting hold when an obstacle blocks harder than the shared
flights' wooden shelf? Obstacles injected into real TDOA3 flights of a clear room
(session 84):

    .venv/bin/python benchmarks/blocked_anchor_stress.py            # ~1 min; out/blocked_anchor_stress.json
    .venv/bin/python benchmarks/blocked_anchor_stress.py --steady   # ~1 min; out/blocked_anchor_stress-steady.json
    .venv/bin/python benchmarks/blocked_anchor_stress.py --steady --whole   # out/blocked_anchor_stress-steady-whole.json
    .venv/bin/python benchmarks/blocked_anchor_stress.py --steady --whole --pairs   # out/blocked_anchor_stress-steady-whole-pairs.json
    .venv/bin/python benchmarks/blocked_anchor_stress.py --figure   # docs/img/blocked_anchor_stress.png from --steady --whole
    .venv/bin/python benchmarks/blocked_anchor_stress.py --real-shape   # what the shared flights' long links look like, 1 min
    .venv/bin/python benchmarks/blocked_anchor_stress.py --discounts    # which anchors the weighting discounts, seconds
    .venv/bin/python benchmarks/blocked_anchor_stress.py --axes    # where the error of a whole-flight block lies, 1 min

The question. The weighting (`anchor_bias_c`, session 83) was built and judged on the
shared flights, whose only TDOA3 obstacle is a wooden shelf (0426-traj5, traj6). Six of
the issue's eight held-out 0426 flights are TDOA3 with obstacles that include metal. Metal
reflects rather than delays: a blocked link reads the path of a reflection, longer by
decimetres to metres, and only some of the time. Whether the weighting still helps then,
and whether the correction still makes no flight worse, the shared flights cannot say.

The stress test, fixed before its first run. Into each of the eleven TDOA3 flights of
0425 (a clear room), `rig inject` adds an `nlos` effect: while the tag is in the half of
the arena nearer one anchor, that anchor's ranges read longer by an exponentially
distributed excess of mean m, on a share f of them. Anchor 0 (floor, the half y < 0)
and anchor 3 (ceiling, x > 0); m = 0.2, 0.4 and 0.8 m; f = 1 (a steady block) and
f = 0.5 (intermittent, as reflections come and go); injection seed 0. Each injected
flight is replayed with the network that held it out (`within-0425-{a,b,c}`, seeds 0–2,
saved by `bias_validation.py --save-models out/models/link-amd`) and without correction
(`--no-nn`), each with the weighting (0.15 m, shipped) and without it (0).

Reported, for each (m, f): the mean 3D RMSE over flights and anchors, and over seeds
for the network; the flights the network makes worse than `--no-nn` (mean over seeds),
with and without the weighting. It decides nothing: the scale is not tuned on synthetic
obstacles. A size at which the weighting raises the mean, with or without the network,
or makes more flights worse, is reported as a limit of the design.

Steady blocks (`--steady`, added after the first run found such a limit, before its own
run). The `nlos` effect draws each range's excess afresh, exponential: most ranges of a
blocked anchor read near their true length and a few far longer, which the robust
update alone already discounts. A block with one dominant reflection lengthens every
range by about the same path, as the wooden shelf did (session 83). `--steady` adds the
same excess m to every range of the anchor while the tag is in its half, with the same
anchors, halves, sizes, flights and networks (f does not apply). Reported the same way;
it decides nothing either.

Whole flights (`--whole`, added after the steady run and a probe of three flights, before
its own run): the anchor is blocked wherever the tag flies, as a block near the anchor
would, with everything else as above. The probe found a ceiling anchor blocked so the
weighting's worst case (0425-traj13, anchor 3 at +0.8 m: 0.414 m without the weighting,
0.690 m with it).

Two anchors at once (`--pairs`, with `--steady --whole`; added after experiments B and
C, before its own run, to learn from physics rather than from the 0426 flights where a
redescending fit might lose): the shared flights' long links are often on several
anchors in the same seconds (`--real-shape`). Blocked together throughout: floor
anchors 0 and 7, on one wall (as an obstacle along it), and ceiling anchors 1 and 3,
the two most often long. Everything else as above; it decides nothing.

Where the error lies (`--axes`, added in session 85 to test session 84's guess that a
blocked ceiling anchor is read as a height error; descriptive, deciding nothing): the
whole-flight blocks at +0.8 m (anchor 0, anchor 3, and both pairs), each flight replayed
without correction and with the seeds' networks, weighting off and on; per axis, the RMSE
and the mean error (estimate - truth), means over flights (and seeds); and, without
correction, each anchor's mean weight over the flight after its first fifth (the
tracker's start), read every 100 ms.
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
from bias_validation_results import TDOA3, WITHIN_0425_FOLDS  # noqa: E402

from rig.data import paths  # noqa: E402

FLIGHTS = tuple(f for f in TDOA3 if f.startswith("0425"))
# anchor -> the half of the arena, nearer it, where an obstacle blocks it
BLOCKED = {0: {"min": [-10.0, -10.0, -1.0], "max": [10.0, 0.0, 5.0]},
           3: {"min": [0.0, -10.0, -1.0], "max": [10.0, 10.0, 5.0]}}
MEAN_EXCESS_M = (0.2, 0.4, 0.8)
SHARES = (1.0, 0.5)
SEEDS = (0, 1, 2)
FIGURE = ROOT / "docs" / "img" / "blocked_anchor_stress.png"
PAIRS = ((0, 7), (1, 3))   # --pairs: anchors blocked together (floor, one wall; ceiling)
WEIGHTING = {"on": 0.15, "off": 0.0}


def model_path(models: Path, flight: str, seed: int) -> Path:
    fold = next(f for f, held in WITHIN_0425_FOLDS.items() if flight in held)
    return models / f"within-0425-{fold}.link.seed{seed}.json"


def steady_block(rec, anchor: int | tuple[int, ...], excess_m: float, whole: bool = False):
    """`rec` with every range of `anchor` longer by `excess_m` while the tag is in its half
    (anywhere, `whole`; several anchors, only so)."""
    from dataclasses import replace

    from rig.sim.effects.tdoa import Region

    anchors = anchor if isinstance(anchor, tuple) else (anchor,)
    if len(anchors) > 1 and not whole:
        raise ValueError("several anchors are blocked together over the whole flight only")
    truth = np.stack([np.interp(rec.tdoa.t, rec.truth.t, rec.truth.position[:, i]) for i in range(3)], axis=1)
    inside = Region.from_json(None if whole else BLOCKED[anchors[0]]).contains(truth)
    sign = sum((rec.tdoa.id_b == k).astype(float) - (rec.tdoa.id_a == k) for k in anchors)
    return replace(rec, tdoa=replace(rec.tdoa, distance_diff=rec.tdoa.distance_diff + excess_m * sign * inside))


def case_figures(job: tuple[str, int | tuple[int, ...] | None, float, float | None, str, bool]) -> dict:
    """One flight with one obstacle (none when `anchor` is None; steady when `share` is
    None, over the whole flight when `whole`): 3D RMSE without correction and with each seed's network, with and without the
    weighting."""
    from rig.data.importer import load_any
    from rig.estimator.bias_net import BiasNet
    from rig.estimator.evaluate import evaluate
    from rig.sim.simulate import inject

    flight, anchor, mean_excess, share, models, whole = job
    rec = load_any(paths.data_dir() / "flights" / flight)
    if anchor is not None and share is None:
        rec = steady_block(rec, anchor, mean_excess, whole)
    elif anchor is not None:
        rec = inject(rec, [{"effect": "nlos", "params": {"anchor": anchor, "fraction": share,
                                                          "mean_excess_m": mean_excess, "region": BLOCKED[anchor]}}])
    out = {}
    for name, scale in WEIGHTING.items():
        out[name] = {"none": evaluate(rec, use_nn=False, anchor_bias_c=scale)["rmse_3d"]}
        for seed in SEEDS:
            net = BiasNet.load(model_path(Path(models), flight, seed))
            out[name][f"seed{seed}"] = evaluate(rec, use_nn=True, model=net, anchor_bias_c=scale)["rmse_3d"]
    return out


AXES_BLOCKS = (0, 3, *PAIRS)
AXES_EXCESS_M = 0.8


def mean_anchor_weights(rec, scale: float) -> list[float]:
    """Each anchor's weight in the blocked-anchor weighting, without correction, averaged
    over the flight after its first fifth (the tracker's start)."""
    from rig.estimator.evaluate import anchor_weight_series, estimator_config

    _, weights = anchor_weight_series(rec, estimator_config(use_nn=False, anchor_bias_c=scale)[0])
    return np.mean(weights[len(weights) // 5:], axis=0)[:8].tolist()


def axes_figures(job: tuple[str, int | tuple[int, ...], str]) -> dict:
    """One flight with `anchor` blocked throughout by AXES_EXCESS_M: per-axis RMSE and mean
    error without correction and with each seed's network, weighting off and on, and the
    anchors' mean weights."""
    from rig.data.importer import load_any
    from rig.estimator.bias_net import BiasNet
    from rig.estimator.evaluate import evaluate

    flight, anchor, models = job
    rec = steady_block(load_any(paths.data_dir() / "flights" / flight), anchor, AXES_EXCESS_M, whole=True)
    out = {}
    for name, scale in WEIGHTING.items():
        runs = {"none": evaluate(rec, use_nn=False, anchor_bias_c=scale)}
        for seed in SEEDS:
            net = BiasNet.load(model_path(Path(models), flight, seed))
            runs[f"seed{seed}"] = evaluate(rec, use_nn=True, model=net, anchor_bias_c=scale)
        out[name] = {key: {"rmse_xyz": r["rmse_xyz"], "mean_xyz": r["mean_xyz"]} for key, r in runs.items()}
    out["weights"] = mean_anchor_weights(rec, WEIGHTING["on"])
    return out


def print_axes(runs: list[tuple[tuple, dict]]) -> None:
    for anchor in AXES_BLOCKS:
        rows = [r for j, r in runs if j[1] == anchor]
        for name in WEIGHTING:
            for label, keys in (("no-nn", ("none",)), ("network", tuple(f"seed{s}" for s in SEEDS))):
                rmse = np.mean([r[name][k]["rmse_xyz"] for r in rows for k in keys], axis=0)
                mean = np.mean([r[name][k]["mean_xyz"] for r in rows for k in keys], axis=0)
                print(f"anchor {str(anchor):<7} {name:<3} {label:<8} RMSE x y z "
                      f"{' '.join(f'{v:.3f}' for v in rmse)}   mean x y z {' '.join(f'{v:+.3f}' for v in mean)}")
        weights = np.mean([r["weights"] for r in rows], axis=0)
        print(f"anchor {str(anchor):<7} mean weights of anchors 0-7, no-nn: {' '.join(f'{w:.2f}' for w in weights)}")


def summary(runs: list[tuple[tuple, dict]]) -> dict:
    """Per case (m, f): means over flights and anchors (and seeds), flights made worse."""
    cases: dict[str, list[dict]] = {}
    for (flight, anchor, m, f, _, whole), figures in runs:
        kind = ("steady" + (" whole" if whole else "")) if f is None else f"f {f:.1f}"
        key = "no obstacle" if anchor is None else f"m {m:.1f} {kind}"
        cases.setdefault(key, []).append(figures)
    table = {}
    for key, rows in cases.items():
        table[key] = {}
        for name in WEIGHTING:
            net = [np.mean([r[name][f"seed{s}"] for r in rows]) for s in SEEDS]
            worse = [sum(r[name][f"seed{s}"] > r[name]["none"] for r in rows) for s in SEEDS]
            table[key][name] = {"without correction": float(np.mean([r[name]["none"] for r in rows])),
                                "network": float(np.mean(net)), "network min-max": [float(min(net)), float(max(net))],
                                "worse": float(np.mean(worse)), "cases": len(rows)}
    return table


SHAPE_FLIGHTS = ("0426-traj3", "0426-traj4", "0426-traj5", "0426-traj6", "0426-traj7", "0426-traj8",
                 "0425-traj13", "0425-traj22")
LONG_M = 0.25   # an anchor's one-second range bias above which its links count as long


def real_shape(flight: str) -> dict:
    """The range errors of an anchor's links over the seconds its bias exceeds LONG_M
    (nlos_oracle.py's one-second split of the raw TDOA error against the ground truth,
    the partner's bias removed): steady blocks read a median near the mean, exponential
    ones (the `nlos` effect) a median 0.69 of it and many ranges near zero."""
    from nlos_oracle import block_biases

    from rig.bias.dataset import airborne_tdoa, measurement_features, true_tdoa, truth_latency
    from rig.data.importer import load_any

    rec = load_any(paths.data_dir() / "flights" / flight)
    sel = airborne_tdoa(rec)
    rows = np.flatnonzero(sel)
    _, tag_pos, a_pos, b_pos = measurement_features(rec, sel, truth_latency(rec))
    id_a, id_b = rec.tdoa.id_a[rows], rec.tdoa.id_b[rows]
    residual = rec.tdoa.distance_diff[rows] - true_tdoa(tag_pos, a_pos, b_pos)
    bias_a, bias_b = block_biases(rec.tdoa.t[rows], residual, id_a, id_b)
    anchors = {}
    for k in sorted({int(i) for i in np.concatenate([id_a, id_b])}):
        as_b, as_a = (id_b == k) & (bias_b > LONG_M), (id_a == k) & (bias_a > LONG_M)
        error = np.concatenate([residual[as_b] + bias_a[as_b], bias_b[as_a] - residual[as_a]])
        if len(error) > 50:
            anchors[k] = {"ranges": len(error), "median_m": float(np.median(error)),
                          "mean_m": float(np.mean(np.clip(error, -2.0, 3.0))),
                          "under_0.1_m": float(np.mean(error < 0.1))}
    return {"flight": flight, "uwb_mode": rec.metadata.get("uwb_mode"), "anchors": anchors}


DISCOUNT_FLIGHTS = ("0425-traj13", "0425-traj17", "0425-traj22")


def discounts(flight: str) -> dict:
    """`rig evaluate`'s `anchor_discounted` with the shipped estimator and network, on the
    flight as flown and with floor anchor 0 or ceiling anchor 3 0.8 m long throughout,
    and the count of TDOA it down-weighted against those it accepted."""
    from rig.data.importer import load_any
    from rig.estimator.evaluate import anchor_discounts, estimator_config, evaluate

    flown = load_any(paths.data_dir() / "flights" / flight)
    out = {}
    for name, rec in (("as flown", flown), ("anchor 0 +0.8 m", steady_block(flown, 0, 0.8, True)),
                      ("anchor 3 +0.8 m", steady_block(flown, 3, 0.8, True))):
        counts = evaluate(rec)
        out[name] = {"anchor_discounted": anchor_discounts(rec, *estimator_config()),
                     "weighted_share": counts["tdoa_anchor_weighted"] / max(counts["tdoa_accepted"], 1)}
    return out


def write_figure(runs: list[dict], path: Path = FIGURE) -> None:
    """Each flight's 3D RMSE with the weighting against without, under a whole-flight
    block of the floor anchor (one panel) and of the ceiling anchor (the other), with the
    network (mean over seeds): above the diagonal, the weighting made it worse."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def network(run: dict, weighting: str) -> float:
        return float(np.mean([run[weighting][f"seed{s}"] for s in SEEDS]))

    blocked = [r for r in runs if r["anchor"] is not None]
    values = [network(r, w) for r in blocked for w in WEIGHTING]
    low, top = 0.9 * min(values), 1.05 * max(values)
    fig, axes = plt.subplots(1, len(BLOCKED), figsize=(8, 4.6))
    for ax, (anchor, where) in zip(axes, ((0, "floor"), (3, "ceiling"))):
        for excess in MEAN_EXCESS_M:
            marks = [r for r in blocked if r["anchor"] == anchor and r["mean_excess_m"] == excess]
            ax.scatter([network(r, "off") for r in marks], [network(r, "on") for r in marks], s=14,
                       alpha=0.8, label=f"+{excess:.1f} m")
        ax.plot([low, top], [low, top], color="grey", linewidth=0.8)
        ax.set(xlim=(low, top), ylim=(low, top), aspect="equal", title=f"anchor {anchor} ({where}) blocked",
               xlabel="without the weighting (m)")
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("with the weighting (m)")
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle("0425 TDOA3 flights with one anchor blocked throughout, with the network: 3D RMSE", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=Path, default=ROOT / "out" / "models" / "link-amd")
    ap.add_argument("--steady", action="store_true", help="every blocked range longer by m (no nlos draw)")
    ap.add_argument("--whole", action="store_true", help="with --steady: blocked over the whole flight")
    ap.add_argument("--pairs", action="store_true", help=f"with --steady --whole: block {PAIRS} together")
    ap.add_argument("--discounts", action="store_true",
                    help="print which anchors the shipped weighting discounts under a whole-flight block, and nothing else")
    ap.add_argument("--axes", action="store_true",
                    help="per-axis errors and anchor weights under whole-flight blocks at +0.8 m (out/blocked_anchor_stress-axes.json)")
    ap.add_argument("--real-shape", action="store_true",
                    help="print how the shared flights' long links are distributed, and nothing else")
    ap.add_argument("--figure", action="store_true",
                    help=f"draw {FIGURE.relative_to(ROOT)} from the --steady --whole run's JSON, and nothing else")
    ap.add_argument("--json", type=Path, help="default: out/blocked_anchor_stress[-steady[-whole[-pairs]]].json")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    if args.discounts:
        with ProcessPoolExecutor(args.workers) as pool:
            for flight, cases in zip(DISCOUNT_FLIGHTS, pool.map(discounts, DISCOUNT_FLIGHTS)):
                for name, case in cases.items():
                    shares = " ".join(f"{k}:{v:.2f}" for k, v in case["anchor_discounted"].items())
                    print(f"{flight} {name:<16} discounted share by anchor {shares}; "
                          f"weighted {case['weighted_share']:.0%} of the accepted")
        return
    if args.real_shape:
        with ProcessPoolExecutor(args.workers) as pool:
            shapes = list(pool.map(real_shape, SHAPE_FLIGHTS))
        for shape in shapes:
            cells = [f"anchor {k}: {a['ranges']} ranges, median {a['median_m']:.2f} m, mean {a['mean_m']:.2f} m, "
                     f"{a['under_0.1_m']:.0%} under 0.1 m" for k, a in shape["anchors"].items()]
            print(f"{shape['flight']} ({shape['uwb_mode']}): " + "; ".join(cells))
        return
    if args.axes:
        jobs = [(f, a, str(args.models)) for a in AXES_BLOCKS for f in FLIGHTS]
        with ProcessPoolExecutor(args.workers) as pool:
            runs = list(zip(jobs, pool.map(axes_figures, jobs)))
        out = args.json or ROOT / "out" / "blocked_anchor_stress-axes.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps([{"flight": j[0], "anchor": j[1], **r} for j, r in runs], indent=1))
        print_axes(runs)
        return
    if args.figure:
        kept = ROOT / "out" / "blocked_anchor_stress-steady-whole.json"
        if not kept.is_file():
            ap.error(f"{kept.relative_to(ROOT)} is missing: run --steady --whole first")
        write_figure(json.loads(kept.read_text())["runs"])
        return
    if args.whole and not args.steady:
        ap.error("--whole is a kind of steady block: give --steady too")
    if args.pairs and not args.whole:
        ap.error("--pairs blocks two anchors over the whole flight: give --steady --whole too")
    suffix = ("-steady" if args.steady else "") + ("-whole" if args.whole else "") + ("-pairs" if args.pairs else "")
    blocked = PAIRS if args.pairs else tuple(BLOCKED)
    args.json = args.json or ROOT / "out" / f"blocked_anchor_stress{suffix}.json"
    shares = (None,) if args.steady else SHARES
    missing = [p for f in FLIGHTS for s in SEEDS if not (p := model_path(args.models, f, s)).is_file()]
    if missing:
        ap.error(f"{len(missing)} networks are missing, e.g. {missing[0]}: bias_validation.py --forms link "
                 f"--splits within-0425 --save-models {args.models}")
    jobs = [(f, None, 0.0, 0.0, str(args.models), False) for f in FLIGHTS]
    jobs += [(f, a, m, s, str(args.models), args.whole) for f in FLIGHTS for a in blocked for m in MEAN_EXCESS_M for s in shares]
    with ProcessPoolExecutor(args.workers) as pool:
        runs = list(zip(jobs, pool.map(case_figures, jobs)))
    table = summary(runs)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"runs": [{"flight": j[0], "anchor": j[1], "mean_excess_m": j[2], "share": j[3],
                                               **r} for j, r in runs], "summary": table}, indent=1))
    print(f"{'case':<14} {'weighting':<9} {'no-nn':>7} {'network (min-max)':>24} {'worse':>6}")
    for key, row in table.items():
        for name, c in row.items():
            lo, hi = c["network min-max"]
            print(f"{key:<14} {name:<9} {c['without correction']:7.3f} {c['network']:9.3f} ({lo:.3f}-{hi:.3f})"
                  f" {c['worse']:6.2f} of {c['cases']}")


if __name__ == "__main__":
    main()
