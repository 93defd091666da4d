"""Does the IMU noise of real flights move the estimator? The default recording's
config flown again with its IMU noise (the sensor's own 0.05 m/s² and 0.005 rad/s)
replaced by the IMU noise the diagnosis fitted on real flights (per axis, with the
shaking's peak and the on-board low-pass: `imu_noise`, `imu_resonance`,
`imu_lowpass` of each flight's model), each replayed through the C estimator
(robust, without the bias network, as the demo's accuracy bar is set).

    .venv/bin/python benchmarks/diagnosis.py            # first: the flights' models in out/diagnosis
    .venv/bin/python benchmarks/imu_noise_accuracy.py [--flights 0426-traj1 ...] [--out out/imu_noise_accuracy.json]

Prints each flight's noise and the RMSE on the default flight with it, and the
default's RMSE over ten seeds (the scale of chance), and writes them to OUT."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.diagnosis.report import SENSORS  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402
from rig.sim import effects as fx  # noqa: E402
from rig.sim.simulate import SimConfig, simulate  # noqa: E402

NOISE = ("imu_noise", "imu_resonance", "imu_lowpass")
# two calm flights of the third day (0426) and three that shook (0422-log01, 0425-traj1, -traj9)
FLIGHTS = ["0426-traj1", "0422-log01", "0425-traj1", "0425-traj9", "0426-traj6"]
SEEDS = list(range(1, 11))


def flight_noise(models: Path, flight: str) -> list[dict]:
    model = json.loads((models / flight / "report.json").read_text())["model"]
    return [e for e in model if e["effect"] in NOISE]


def rmse_with(config: SimConfig, noise: list[dict], seed: int | None = None) -> float:
    effects = [e for e in config.effects if e["effect"] not in NOISE] + noise
    flown = replace(config, effects=effects, seed=config.seed if seed is None else seed)
    return float(evaluate(simulate(flown), use_nn=False)["rmse_3d"])


def described(noise: list[dict]) -> str:
    """The accelerometer's and gyroscope's noise in a few words (sizes per axis)."""
    sizes = fx.params_by_name(noise)
    words = []
    for sensor, (_, unit) in SENSORS.items():
        white = sizes["imu_noise"][f"{sensor}_std"]
        text = f"{sensor} {json.dumps(white if isinstance(white, float) else [round(v, 3) for v in white])} {unit}"
        peak = sizes.get("imu_resonance", {})
        if peak.get(f"{sensor}_hz", 0.0) > 0:
            text += f" + {[round(v, 3) for v in peak[f'{sensor}_std']]} at {peak[f'{sensor}_hz']:.1f} Hz"
        words.append(text)
    return "; ".join(words)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", default=FLIGHTS)
    parser.add_argument("--models", type=Path, default=ROOT / "out" / "diagnosis",
                        help="benchmarks/diagnosis.py's output (one directory per flight)")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "imu_noise_accuracy.json")
    args = parser.parse_args()
    config = SimConfig.load(ROOT / "recordings" / "default.sim.json")
    own = [e for e in config.effects if e["effect"] in NOISE]
    rows = {"default": {"noise": own, "rmse_3d_m": rmse_with(config, own)}}
    for flight in args.flights:
        noise = flight_noise(args.models, flight)
        rows[flight] = {"noise": noise, "rmse_3d_m": rmse_with(config, noise)}
    # the IMU noise draws from the simulation's random stream before the TDOA noise does,
    # so another noise is another TDOA noise too: the default's spread over seeds is the
    # scale the differences compare with
    seeds = [rmse_with(config, own, seed) for seed in SEEDS]
    for label, row in rows.items():
        print(f"{label:12s} RMSE {row['rmse_3d_m']:.3f} m   {described(row['noise'])}")
    print(f"the default over seeds {SEEDS[0]}-{SEEDS[-1]}: RMSE {min(seeds):.3f}-{max(seeds):.3f} m")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"flights": rows, "default_over_seeds_m": seeds}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
