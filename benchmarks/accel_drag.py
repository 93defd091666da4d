"""What a flight's horizontal accelerometer readings follow: rotor drag, and a lean
into the motion that both IMU sensors feel and the ground truth's attitude does not show.

    .venv/bin/python benchmarks/accel_drag.py [--flights 0426-traj1 ...] [--json out/accel_drag.json]

In near-level flight the thrust is along body z, so a body axis's horizontal specific
force is the rotor drag, about −k·v along that axis. Per flight, over 0.2 s means of
the time in the air (tag above 0.5 m, 3 s cut at each end), the accelerometer's x and
y and the ground truth's specific force (rig.sim.trajectory) are each fitted as
k·v_body + c: k of each, their ratio (what a scale of the truth's specific force can
stand in for), and each one's correlation with the velocity (session 74).

Then the lean into the motion (session 75), in mrad per m/s of body velocity
(`attitude_lean`'s c), as the gyroscope and as the accelerometer measure it against
the ground truth (rig.diagnosis.lean, which `rig diagnose` reports too). A lean shows
alike in both; what the accelerometer alone shows is not one. Seconds per flight; it
decides nothing (docs/notebook/diagnosis-experiments.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.diagnosis.lean import measure_lean  # noqa: E402
from rig.sim.trajectory import RecordedTrajectory  # noqa: E402

BLOCK_S = 0.2
AIRBORNE_M = 0.5
CUT_S = 3.0


def block_means(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.digitize(t, np.arange(t[0], t[-1], BLOCK_S))
    keys = np.unique(idx)
    return (np.array([t[idx == k].mean() for k in keys]), np.array([values[idx == k].mean(axis=0) for k in keys]))


def drag_fit(y: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """k of y ≈ k·v + c, and the correlation of y with v."""
    k = np.linalg.lstsq(np.column_stack([v, np.ones_like(v)]), y, rcond=None)[0][0]
    return float(k), float(np.corrcoef(y, v)[0, 1])


def flight_drag(flight: Path) -> dict:
    rec = load_any(flight)
    truth = RecordedTrajectory(rec.truth)
    t, accel = rec.accel.t, rec.accel.xyz
    keep = (t > truth.t_start + CUT_S) & (t < truth.t_end - CUT_S)
    t, accel = t[keep], accel[keep]
    air = truth.position(t)[:, 2] > AIRBORNE_M
    tb, measured = block_means(t[air], accel[air])
    force = truth.specific_force(tb)
    velocity = truth.body_velocity(tb)
    out = {}
    for axis, name in enumerate("xy"):
        k_meas, r_meas = drag_fit(measured[:, axis], velocity[:, axis])
        k_truth, r_truth = drag_fit(force[:, axis], velocity[:, axis])
        out[name] = {"k_measured": k_meas, "k_truth": k_truth, "ratio": k_meas / k_truth,
                     "r_measured": r_meas, "r_truth": r_truth}
    return out


def flight_lean(flight: Path) -> dict:
    """The lean on x and y by each sensor (rig.diagnosis.lean), rad per m/s."""
    rec = load_any(flight)
    lean = measure_lean(rec, RecordedTrajectory(rec.truth))
    return {axis: {"gyroscope": float(lean.gyroscope[k]), "accelerometer": float(lean.accelerometer[k])}
            for k, axis in enumerate("xy")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", help="flight names (default: every shared flight)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    root = paths.data_dir() / "flights"
    names = args.flights or sorted(p.name for p in root.iterdir())
    rows = {}
    print("| flight | x: k accelerometer / truth [1/s], ratio | r accelerometer, truth | y: k, ratio | r "
          "| lean x: gyroscope, accelerometer [mrad per m/s] | lean y |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        rows[name] = fit = {**flight_drag(root / name), "lean": flight_lean(root / name)}
        x, y, lean = fit["x"], fit["y"], fit["lean"]
        print(f"| {name} | {x['k_measured']:+.3f} / {x['k_truth']:+.3f}, {x['ratio']:.2f} | "
              f"{x['r_measured']:+.2f}, {x['r_truth']:+.2f} | {y['k_measured']:+.3f} / {y['k_truth']:+.3f}, "
              f"{y['ratio']:.2f} | {y['r_measured']:+.2f}, {y['r_truth']:+.2f} | "
              + " | ".join(f"{1e3 * lean[a]['gyroscope']:+.1f}, {1e3 * lean[a]['accelerometer']:+.1f}" for a in "xy")
              + " |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
