"""How well each anchor's range bias can be tracked from the innovations, away from the
filter it would weight (session 83): the estimator's tracking
(estimator_c/src/anchor_bias.c) redone in Python on a replay without correction or
weighting, against the truth's one-second split of benchmarks/nlos_oracle.py.

    .venv/bin/python benchmarks/anchor_bias_open_loop.py 0425-traj13 ... # ~1 min

For each flight: the correlation of the tracked bias of each measurement's anchor B with
the truth's (and of what a position error cannot explain of it, `without geometry`),
their spreads, and the 3D RMSE (without correction) when the measurements of anchors
whose tracked bias exceeds τ are removed (the oracle's `drop`, but causal), and when
they are removed by what a position error cannot explain of it.
"""

from __future__ import annotations

import argparse
import logging
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402
from nlos_oracle import TAUS_M, UNWEIGHTED, block_biases  # noqa: E402

from rig.data import paths  # noqa: E402

STEP_S, WINDOW_S, PRIOR_N = 0.01, 1.0, 10.0   # as estimator.h
TDOA_STD, GM_C2, ANCHORS = 0.4, 9.0, 16       # the shipped parameters


def without_geometry(bias: np.ndarray, n: np.ndarray, tag: np.ndarray, anchors: dict) -> np.ndarray:
    """The tracked biases less their fit c + u_k . dp over the anchors heard (u_k: the
    unit vector from anchor k to the tag): what a position error dp cannot explain."""
    heard = [k for k in np.flatnonzero(n > 1.0) if k in anchors]
    out = np.zeros(ANCHORS)
    if len(heard) < 5:
        return out
    u = tag - np.array([anchors[k] for k in heard])
    design = np.c_[np.ones(len(heard)), u / np.linalg.norm(u, axis=1)[:, None]]
    out[heard] = bias[heard] - design @ np.linalg.lstsq(design, bias[heard], rcond=None)[0]
    return out


def tracked_biases(t: np.ndarray, id_a: np.ndarray, id_b: np.ndarray, innovation: np.ndarray,
                   tag: np.ndarray, anchors: dict) -> tuple[np.ndarray, ...]:
    """Anchor A's and anchor B's tracked bias before each measurement, as anchor_bias.c,
    and anchor B's and A's without the part a position error explains (`without_geometry`)."""
    bias, n = np.zeros(ANCHORS), np.zeros(ANCHORS)
    residual = np.zeros(ANCHORS)
    keep = np.exp(-STEP_S / WINDOW_S)
    out_a, out_b, out_r, out_ra = (np.zeros(len(t)) for _ in range(4))
    step = t[0]
    for i in range(len(t)):
        while t[i] > step + STEP_S:
            step += STEP_S
            n *= keep
            bias[n > 0] -= bias[n > 0].mean()
            residual = without_geometry(bias, n, tag[i], anchors)
        a, b = id_a[i], id_b[i]
        out_a[i], out_b[i], out_r[i], out_ra[i] = bias[a], bias[b], residual[b], residual[a]
        w = (GM_C2 / (GM_C2 + (innovation[i] / TDOA_STD) ** 2)) ** 2
        e = innovation[i] - (bias[b] - bias[a])
        n[a] += w
        n[b] += w
        bias[b] += w * e / (n[b] + PRIOR_N)
        bias[a] -= w * e / (n[a] + PRIOR_N)
    return out_a, out_b, out_r, out_ra


def flight_figures(flight: str) -> dict:
    from rig.bias.dataset import airborne_tdoa, measurement_features, true_tdoa, truth_latency
    from rig.data.importer import load_any
    from rig.estimator import metrics
    from rig.estimator.evaluate import estimator_config, evaluate, replay

    logging.disable(logging.WARNING)
    rec = load_any(paths.data_dir() / "flights" / flight)
    sel = airborne_tdoa(rec)
    rows = np.flatnonzero(sel)
    _, tag_pos, a_pos, b_pos = measurement_features(rec, sel, truth_latency(rec), "truth")
    id_a, id_b, t, z = rec.tdoa.id_a[rows], rec.tdoa.id_b[rows], rec.tdoa.t[rows], rec.tdoa.distance_diff[rows]
    _, truth_b = block_biases(t, z - true_tdoa(tag_pos, a_pos, b_pos), id_a, id_b)
    run = replay(rec, *estimator_config(use_nn=False, **UNWEIGHTED))
    estimate = metrics.interpolate(t, run.t, run.position)
    anchors = {a.id: np.asarray(a.position, float) for a in rec.anchors}
    track_a, track_b, residual_b, residual_a = tracked_biases(t, id_a, id_b, z - true_tdoa(estimate, a_pos, b_pos), estimate,
                                                  anchors)
    figures = {"correlation": float(np.corrcoef(track_b, truth_b)[0, 1]),
               "without geometry": float(np.corrcoef(residual_b, truth_b)[0, 1]),
               "spread truth m": float(truth_b.std()), "spread tracked m": float(track_b.std()),
               "as is": evaluate(rec, use_nn=False, **UNWEIGHTED)["rmse_3d"]}
    for tau in TAUS_M:
        keep = np.ones(len(rec.tdoa), bool)
        keep[rows[(np.abs(track_a) > tau) | (np.abs(track_b) > tau)]] = False
        figures[f"drop {tau:.2f}"] = evaluate(replace(rec, tdoa=rec.tdoa.select(keep)), use_nn=False,
                                              **UNWEIGHTED)["rmse_3d"]
        keep = np.ones(len(rec.tdoa), bool)
        keep[rows[(np.abs(residual_a) > tau) | (np.abs(residual_b) > tau)]] = False
        figures[f"geometry-free drop {tau:.2f}"] = evaluate(replace(rec, tdoa=rec.tdoa.select(keep)),
                                                            use_nn=False, **UNWEIGHTED)["rmse_3d"]
    return figures


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("flights", nargs="+")
    args = ap.parse_args()
    with ProcessPoolExecutor(2) as pool:
        for flight, fig in zip(args.flights, pool.map(flight_figures, args.flights)):
            print(f"{flight:12s} " + "  ".join(f"{k} {v:.3f}" for k, v in fig.items()))


if __name__ == "__main__":
    main()
