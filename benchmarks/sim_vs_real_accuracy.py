"""Does the fitted model explain the estimator's error? Each real flight is
diagnosed and replayed through the C estimator (robust, without the bias network)
against simulations of the same flight (its ground truth, anchors, UWB mode and
TDOA rate): with only the noise the diagnosis measured (TDOA noise; IMU noise, peak
and low-pass); with its whole model (the named effects too); and with the model
and, for TDOA noise, the very errors the model leaves on the recording, drawn
independently (heavy tails and all, without their order in time); and with the
model and the bias network's pose-dependent bias (`learned_bias`, gain 1). If the
named effects are the physics the simulator left out, the model's RMSE comes close
to the real one; what the third leaves is error that is ordered in time and pose,
not a matter of its distribution, and the fourth asks whether it is the bias the
network learned (the shipped network was trained on these flights, so the answer
flatters it).

    .venv/bin/python benchmarks/sim_vs_real_accuracy.py [--flights ...] [--out out/sim_vs_real_accuracy.json]

Prints a line per flight and the medians, writes them to OUT (about 6 minutes for all 35
flights on two cores)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.data.recording import Recording  # noqa: E402
from rig.diagnosis.diagnose import diagnose  # noqa: E402
from rig.estimator.evaluate import evaluate  # noqa: E402
from rig.sim.simulate import SimConfig, simulate  # noqa: E402

NOISE = ("tdoa_noise", "imu_noise", "imu_resonance", "imu_lowpass")
KINDS = ("real", "noise", "model", "model_and_residuals", "model_and_learned_bias")
LEARNED_BIAS = {"effect": "learned_bias", "params": {"gain": 1.0}}


def rmse(rec: Recording) -> float:
    return float(evaluate(rec, use_nn=False)["rmse_3d"])


def flown(rec: Recording, effects: list[dict]) -> Recording:
    """The recording's own flight simulated with `effects`, at its UWB mode and rate."""
    d = rec.tdoa
    config = SimConfig(trajectory="recording", recording=rec.metadata["source"], effects=effects, seed=1,
                       uwb_mode=rec.metadata.get("uwb_mode", "TDOA2"),
                       tdoa_hz=float(len(d.t) / (d.t[-1] - d.t[0])))
    return simulate(config)


def with_tdoa_errors(rec: Recording, errors: np.ndarray) -> Recording:
    """The simulated recording with `errors` drawn independently onto its TDOA values."""
    drawn = np.random.default_rng(0).choice(errors, len(rec.tdoa.t))
    return replace(rec, tdoa=replace(rec.tdoa, distance_diff=rec.tdoa.distance_diff + drawn))


def compared(flight: str) -> tuple[str, dict]:
    rec = load_any(paths.data_dir() / "flights" / flight)
    diagnosis = diagnose(rec)
    model = diagnosis.to_json()["model"]
    noiseless_tdoa = flown(rec, [e for e in model if e["effect"] != "tdoa_noise"])
    return flight, {"real": rmse(rec), "noise": rmse(flown(rec, [e for e in model if e["effect"] in NOISE])),
                    "model": rmse(flown(rec, model)),
                    "model_and_residuals": rmse(with_tdoa_errors(noiseless_tdoa, diagnosis.residual_after["tdoa"])),
                    "model_and_learned_bias": rmse(flown(rec, model + [LEARNED_BIAS]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", help="default: every shared flight")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "sim_vs_real_accuracy.json")
    args = parser.parse_args()
    flights = args.flights or [f.name for f in paths.flights()]
    rows = {}
    with Pool(2) as pool:
        for flight, row in pool.imap(compared, flights):
            rows[flight] = row
            print(f"{flight:12s} RMSE [m]: real {row['real']:.3f}; simulated with the noise {row['noise']:.3f}, "
                  f"the model {row['model']:.3f}, the model and its residuals {row['model_and_residuals']:.3f}, "
                  f"the model and the learned bias {row['model_and_learned_bias']:.3f}",
                  flush=True)
    summary = {kind: float(np.median([r[kind] for r in rows.values()])) for kind in KINDS}
    for kind in KINDS[1:]:
        summary[f"{kind}_gap_median"] = float(np.median([abs(r[kind] - r["real"]) for r in rows.values()]))
    print(f"medians: real {summary['real']:.3f} m; simulated with " + "; ".join(
        f"{kind.replace('_', ' ')} {summary[kind]:.3f} m (|sim - real| {summary[kind + '_gap_median']:.3f} m)"
        for kind in KINDS[1:]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"flights": rows, "summary": summary}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
