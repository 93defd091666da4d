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

Prints per flight the height, extra noise and evidence of each (— where none pays its
bar) and writes them to JSON."""

from __future__ import annotations

import argparse
import json
import os
import sys
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.diagnosis.candidates import MIN_EVIDENCE, PENALTY_PER_PARAMETER  # noqa: E402
from rig.diagnosis.diagnose import diagnose  # noqa: E402
from rig.diagnosis.floor_error import floor_multipath, local_noise  # noqa: E402
from rig.sim import effects as fx  # noqa: E402

RESIDUALS = ("recorded", "no_nlos", "model", "all_fits")
NOISE_LEVEL = ("multipath_floor",)


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
    out = {}
    for name, model in models.items():
        residual = recorded - problem.predict_channel("tdoa", model)
        fit = floor_multipath(local_noise(problem, residual), heights, bar)
        out[name] = None if fit is None else {"height_m": fit["height_m"], "std_m": round(fit["std_m"], 4),
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
    print(f"{'flight':12s} " + " ".join(f"{name:26s}" for name in RESIDUALS))
    for flight, fits in results.items():
        print(f"{flight:12s} " + " ".join(f"{describe(fits[name]):26s}" for name in RESIDUALS))
    named = {name: sum(fits[name] is not None for fits in results.values()) for name in RESIDUALS}
    agree = {name: sum((fits[name] is None) == (fits["model"] is None)
                       and (fits[name] is None or fits[name]["height_m"] == fits["model"]["height_m"])
                       for fits in results.values()) for name in RESIDUALS}
    print("flights naming a floor multipath: " + ", ".join(f"{k} {v}" for k, v in named.items()))
    print("the same verdict and height as `model`: " + ", ".join(f"{k} {v}" for k, v in agree.items()))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": results, "named": named, "agree_with_model": agree}, indent=1))


if __name__ == "__main__":
    main()
