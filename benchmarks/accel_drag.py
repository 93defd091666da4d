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
from rig.data.recording import Recording  # noqa: E402
from rig.diagnosis.lean import AIRBORNE_M, CUT_S, integrated, longest_stretch, measure_lean  # noqa: E402
from rig.sim.trajectory import GRAVITY, RecordedTrajectory  # noqa: E402

BLOCK_S = 0.2


def block_means(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.digitize(t, np.arange(t[0], t[-1], BLOCK_S))
    keys = np.unique(idx)
    return (np.array([t[idx == k].mean() for k in keys]), np.array([values[idx == k].mean(axis=0) for k in keys]))


def drag_fit(y: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """k of y ≈ k·v + c, and the correlation of y with v."""
    k = np.linalg.lstsq(np.column_stack([v, np.ones_like(v)]), y, rcond=None)[0][0]
    return float(k), float(np.corrcoef(y, v)[0, 1])


def flight_drag(rec: Recording, truth: RecordedTrajectory) -> dict:
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


def flight_lean(rec: Recording, truth: RecordedTrajectory) -> dict:
    """The lean on x and y by each sensor (rig.diagnosis.lean), rad per m/s."""
    lean = measure_lean(rec, truth)
    return {axis: {"gyroscope": float(lean.gyroscope[k]), "accelerometer": float(lean.accelerometer[k])}
            for k, axis in enumerate("xy")}


def circle_harmonics(rec: Recording, truth: RecordedTrajectory) -> dict:
    """At the circle's frequency, in the world frame (complex x + iy, turned by the
    ground truth's yaw; phase against the tag's angle around the circle's centre): the
    tilt of body z by the motion capture and by the gyroscope (its rates integrated,
    small angles), and the horizontal specific force as the accelerometer reads it, as
    the ground truth gives it, and as the ground truth gives it with the gyroscope's
    tilt in place of its own (minus g × the tilt's difference)."""
    t = rec.gyro.t
    lowest = np.nanpercentile(rec.truth.position[:, 2], 1)
    air = (t > truth.t_start + CUT_S) & (t < truth.t_end - CUT_S) & (truth.position(t)[:, 2] > lowest + AIRBORNE_M)
    run = np.flatnonzero(air)[longest_stretch(t[air])][::5]
    t, angle = t[run], integrated(t[run], rec.gyro.xyz[run])
    accel = np.column_stack([np.interp(t, rec.accel.t, rec.accel.xyz[:, i]) for i in range(3)])
    position, rotation = truth.position(t), truth.rotation(t)
    centre = position[:, :2].mean(axis=0)
    phase = np.unwrap(np.arctan2(position[:, 1] - centre[1], position[:, 0] - centre[0]))
    yaw = np.exp(1j * rotation.as_euler("ZYX")[:, 0])
    s = (t - t[0]) / (t[-1] - t[0])
    design = np.column_stack([np.exp(1j * phase), np.exp(-1j * phase), np.ones_like(s), s, s ** 2]).astype(complex)

    def harmonic(values: np.ndarray) -> complex:
        return complex(np.linalg.lstsq(design, values, rcond=None)[0][0])

    up = rotation.apply([0.0, 0.0, 1.0])
    tilt_truth = harmonic(up[:, 0] + 1j * up[:, 1])
    tilt_gyro = harmonic((angle[:, 1] - 1j * angle[:, 0]) * yaw)
    force = truth.specific_force(t)
    force_truth = harmonic((force[:, 0] + 1j * force[:, 1]) * yaw)
    force_accel = harmonic((accel[:, 0] + 1j * accel[:, 1]) * yaw)
    as_pair = lambda z: [abs(z), float(np.degrees(np.angle(z)))]     # noqa: E731
    return {"tilt_truth": as_pair(tilt_truth), "tilt_gyroscope": as_pair(tilt_gyro),
            "force_accelerometer": as_pair(force_accel), "force_truth": as_pair(force_truth),
            "force_truth_with_gyroscope_tilt": as_pair(force_truth - GRAVITY * (tilt_gyro - tilt_truth))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", help="flight names (default: every shared flight)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    root = paths.data_dir() / "flights"
    names = args.flights or sorted(p.name for p in root.iterdir())
    rows = {}
    print("| flight | x: k accelerometer / truth [1/s], ratio | r accelerometer, truth | y: k, ratio | r "
          "| lean x: gyroscope, accelerometer [mrad per m/s] | lean y "
          "| at the circle's frequency: tilt gyroscope / truth, turned by | force [m/s² ∠°]: accelerometer; truth; "
          "truth with the gyroscope's tilt |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        rec = load_any(root / name)
        truth = RecordedTrajectory(rec.truth)
        rows[name] = fit = {**flight_drag(rec, truth), "lean": flight_lean(rec, truth),
                            "circle": circle_harmonics(rec, truth)}
        x, y, lean, c = fit["x"], fit["y"], fit["lean"], fit["circle"]
        force = "; ".join(f"{c[k][0]:.3f} ∠{c[k][1]:+.0f}" for k in
                          ("force_accelerometer", "force_truth", "force_truth_with_gyroscope_tilt"))
        print(f"| {name} | {x['k_measured']:+.3f} / {x['k_truth']:+.3f}, {x['ratio']:.2f} | "
              f"{x['r_measured']:+.2f}, {x['r_truth']:+.2f} | {y['k_measured']:+.3f} / {y['k_truth']:+.3f}, "
              f"{y['ratio']:.2f} | {y['r_measured']:+.2f}, {y['r_truth']:+.2f} | "
              + " | ".join(f"{1e3 * lean[a]['gyroscope']:+.1f}, {1e3 * lean[a]['accelerometer']:+.1f}" for a in "xy")
              + f" | {c['tilt_gyroscope'][0] / c['tilt_truth'][0]:.2f}, "
              f"{(c['tilt_gyroscope'][1] - c['tilt_truth'][1] + 180) % 360 - 180:+.1f}° | {force} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
