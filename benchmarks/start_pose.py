"""A flight without ground truth replayed from where the drone stood (`rig replay
--start-position`), against the same flight started from the ground truth's pose; and
why the start is not guessed from the TDOA: their error on the floor.

    .venv/bin/python benchmarks/start_pose.py [--flights 0426-traj1 ...] [--json out/start_pose.json]   # seconds

For each flight: the median |TDOA residual| at the true position over the second after
the first IMU sample (the drone on the floor) and over a second in flight (take-off +
5 s); then the shipped estimator's 3D RMSE started from the ground truth 1 s before
take-off (as `rig evaluate`), and with the ground truth set aside, started level at the
first IMU sample from the ground truth's first position (what a pilot would give) at
yaw 0 (as `--start-position` without `--start-yaw`), and from that position moved by
each of OFFSETS along x and along z (a drone placed off the spot its pilot gives). All
are scored against the ground truth over the same scored segment.
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

import numpy as np  # noqa: E402

from rig.data import paths  # noqa: E402

FLIGHTS = ["0426-traj1", "0426-traj6", "0425-traj3", "0425-traj9", "0425-traj15", "0422-log01"]
OFFSETS_M = (0.5, 1.0, 2.0)


def tdoa_residual(rec, t0: float, seconds: float = 1.0) -> float:
    """Median |measured − true TDOA| over [t0, t0 + seconds], at the ground truth's position."""
    from rig.estimator.metrics import interpolate_positions

    anchors = rec.anchor_map()
    near = (rec.tdoa.t >= t0) & (rec.tdoa.t < t0 + seconds)
    pairs = zip(rec.tdoa.id_a[near], rec.tdoa.id_b[near])
    known = np.array([a in anchors and b in anchors for a, b in pairs], bool)
    t = rec.tdoa.t[near][known]
    a = np.array([anchors[i].position for i in rec.tdoa.id_a[near][known]])
    b = np.array([anchors[i].position for i in rec.tdoa.id_b[near][known]])
    p = interpolate_positions(rec.truth, t)
    true = np.linalg.norm(p - b, axis=1) - np.linalg.norm(p - a, axis=1)
    return float(np.median(np.abs(rec.tdoa.distance_diff[near][known] - true)))


def flight_figures(flight: str) -> dict:
    from rig.data.importer import load_any
    from rig.data.recording import PoseSeries
    from rig.estimator import metrics
    from rig.estimator.evaluate import StartPose, estimator_config, evaluate, replay, start_time

    rec = load_any(paths.data_dir() / "flights" / flight)
    first = float(max(rec.accel.t[0], rec.gyro.t[0]))
    params, model = estimator_config()
    bare = replace(rec, truth=PoseSeries.empty())

    def rmse_from(offset: tuple[float, float, float]) -> float:
        stood = StartPose(tuple((rec.truth.position[0] + np.array(offset)).tolist()))
        run = replay(bare, params, model, start_pose=stood)
        return metrics.score(run.t, run.position, rec.truth)["rmse_3d"]

    return {"flight": flight, "floor_residual_m": tdoa_residual(rec, first),
            "flight_residual_m": tdoa_residual(rec, metrics.takeoff_time(rec.truth) + 5.0),
            "rmse_truth_start_m": evaluate(rec)["rmse_3d"], "rmse_given_start_m": rmse_from((0.0, 0.0, 0.0)),
            "rmse_start_off_x_m": {str(d): rmse_from((d, 0.0, 0.0)) for d in OFFSETS_M},
            "rmse_start_off_z_m": {str(d): rmse_from((0.0, 0.0, d)) for d in OFFSETS_M},
            "given_start_s_before_truth_start": start_time(rec) - first}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", nargs="+", default=FLIGHTS)
    parser.add_argument("--json", type=Path, default=Path("out/start_pose.json"))
    args = parser.parse_args()
    with ProcessPoolExecutor(max_workers=2) as pool:
        rows = list(pool.map(flight_figures, args.flights))
    offsets = " ".join(f"{f'{d:g} m off x, z':>16}" for d in OFFSETS_M)
    print(f"{'flight':<12} {'TDOA |res| floor':>16} {'in flight':>10} {'RMSE truth start':>17} {'given start':>12} "
          f"{offsets}")
    for r in rows:
        moved = " ".join(f"{r['rmse_start_off_x_m'][str(d)]:>7.3f}, {r['rmse_start_off_z_m'][str(d)]:.3f}"
                         for d in OFFSETS_M)
        print(f"{r['flight']:<12} {r['floor_residual_m']:>14.2f} m {r['flight_residual_m']:>8.2f} m "
              f"{r['rmse_truth_start_m']:>15.3f} m {r['rmse_given_start_m']:>10.3f} m {moved}")
    gap = max(abs(r["rmse_given_start_m"] - r["rmse_truth_start_m"]) for r in rows)
    print(f"largest difference of the two starts: {gap:.3f} m (RMSE, m)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": rows, "largest_difference_m": gap}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
