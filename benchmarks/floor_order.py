"""Does the floor multipath a diagnosis names depend on which other effects model the mean?

    .venv/bin/python benchmarks/floor_order.py [--flights 0426-traj1 ...] [--json out/floor_order.json]

The floor multipath is a noise-level effect judged on each TDOA residual less the
running median of its anchor pair's neighbours (rig.diagnosis.floor_error.local_noise),
meant not to depend on the rest of the model. Session 87 saw two floor findings go
when the antenna patterns left the re-simulating model. This measures, on every
shared flight (two at a time, about 5 minutes), the floor fit on four residuals of the
same diagnosis, deciding nothing:

- `recorded`: recorded − simulated, no effect modelled;
- `no_nlos`: the re-simulating model without its NLOS effects (region-confined steps);
- `model`: the re-simulating model, as `rig diagnose` judges it;
- `all_fits`: that model and every TDOA fit beyond its bound (under *Not explained*).

Each on two local noises (NOISES): `median`, each residual less the running median
of its pair's neighbours, as `rig diagnose` has it; `edge`, less the median of its
neighbours on one side only, the side it is nearer (edge_deviations), so that a step
of the mean (an NLOS region's edge in the model, or in the recording) does not enter
it. Prints per flight the height, extra noise and evidence of each (— where none pays
its bar) and writes them to JSON."""

from __future__ import annotations

import argparse
import json
import os
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER  # noqa: E402
from rig.diagnosis.diagnose import diagnose  # noqa: E402
from rig.diagnosis.floor_error import LOCAL_SAMPLES, floor_multipath, local_noise, median_deviations  # noqa: E402
from rig.diagnosis.robust import mad_scale  # noqa: E402
from rig.sim import effects as fx  # noqa: E402

RESIDUALS = ("recorded", "no_nlos", "model", "all_fits")
NOISE_LEVEL = ("multipath_floor",)


def one_sided_deviations(values: np.ndarray) -> np.ndarray:
    """Each value less the median of its LOCAL_SAMPLES neighbours on the side where
    that deviation is smaller (on the one side there is, at the ends), unscaled."""
    k, n = LOCAL_SAMPLES, len(values)
    windows = np.lib.stride_tricks.sliding_window_view(values, k)
    medians = np.median(windows, axis=1)                  # medians[j]: values[j:j + k]
    left = np.full(n, np.nan)
    right = np.full(n, np.nan)
    left[k:] = values[k:] - medians[:n - k]
    right[:n - k] = values[:n - k] - medians[1:]
    return np.where(np.isnan(left) | (np.abs(right) < np.abs(left)), right, left)


def _white_noise_scale(samples: int = 200_000, seed: int = 0) -> float:
    """What one_sided_deviations makes of white noise of unit deviation, in the
    normal-equivalent MAD the floor fit reads: fixed by simulation, not by a flight."""
    return mad_scale(one_sided_deviations(np.random.default_rng(seed).standard_normal(samples)))


EDGE_SCALE = _white_noise_scale()


def edge_deviations(values: np.ndarray) -> np.ndarray:
    """one_sided_deviations scaled to keep white noise's deviation; a pair with too few
    measurements for two windows as median_deviations."""
    if len(values) <= 2 * LOCAL_SAMPLES:
        return median_deviations(values)
    return one_sided_deviations(values) / EDGE_SCALE


NOISES = {"median": median_deviations, "edge": edge_deviations}


def floor_fits(flight: str) -> tuple[str, dict]:
    """The floor fit on each of RESIDUALS of `flight`'s diagnosis."""
    d = diagnose(load_any(paths.data_dir() / "flights" / flight))
    problem = d.problem
    recorded = problem.recorded("tdoa")
    beyond = [fx.make_effect(f.effect, f.params) for f in d.not_explained
              if f.channel == "tdoa" and f.effect not in NOISE_LEVEL]
    models = {"recorded": [], "no_nlos": [e for e in d.model if e.name != "nlos"], "model": d.model,
              "all_fits": d.model + beyond}
    heights = problem.tag_positions()[:, 2]
    bar = MIN_EVIDENCE + 2 * PENALTY_PER_PARAMETER
    out = {noise: {} for noise in NOISES}
    for name, model in models.items():
        residual = recorded - problem.predict_channel("tdoa", model)
        for noise, deviations in NOISES.items():
            fit = floor_multipath(local_noise(problem, residual, deviations), heights, bar)
            out[noise][name] = None if fit is None else {"height_m": fit["height_m"],
                                                         "std_m": round(fit["std_m"], 4),
                                                         "evidence": round(fit["evidence"], 1)}
    return flight, out


def describe(fit: dict | None) -> str:
    return "—" if fit is None else f"<{fit['height_m']} m +{fit['std_m']:.3f} m ({fit['evidence']:.0f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", help="default: every shared flight")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "floor_order.json")
    args = parser.parse_args()
    flights = args.flights or [path.name for path in paths.flights()]
    with Pool(2) as pool:
        results = dict(pool.imap(floor_fits, flights))
    summary = {}
    for noise in NOISES:
        print(f"\nlocal noise: {noise}\n{'flight':12s} " + " ".join(f"{name:26s}" for name in RESIDUALS))
        for flight, fits in results.items():
            print(f"{flight:12s} " + " ".join(f"{describe(fits[noise][name]):26s}" for name in RESIDUALS))
        named = {name: sum(fits[noise][name] is not None for fits in results.values()) for name in RESIDUALS}
        agree = {name: sum(same(fits[noise][name], fits[noise]["model"]) for fits in results.values())
                 for name in RESIDUALS}
        print("flights naming a floor multipath: " + ", ".join(f"{k} {v}" for k, v in named.items()))
        print("the same verdict and height as `model`: " + ", ".join(f"{k} {v}" for k, v in agree.items()))
        summary[noise] = {"named": named, "agree_with_model": agree}
    as_shipped = sum(same(fits["edge"]["model"], fits["median"]["model"]) for fits in results.values())
    print(f"`model`: the same verdict and height on both local noises on {as_shipped} of {len(results)} flights")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": results, "noises": summary, "model_same_on_both": as_shipped},
                                    indent=1))


def same(fit: dict | None, other: dict | None) -> bool:
    """The same verdict and, where named, the same height."""
    return (fit is None) == (other is None) and (fit is None or fit["height_m"] == other["height_m"])


if __name__ == "__main__":
    main()
