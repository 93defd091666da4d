"""The concealed-effect cases of tests/test_diagnose.py on more flights than the suite
runs: each catalog effect injected alone into a flight, diagnosed, compared with the
untouched flight as control, judged by the suite's own tolerances.

    .venv/bin/python benchmarks/concealed.py [--flights sim 0426-traj1 ...] [--out out/concealed.json] [--rejudge]

By default the simulated flight and fourteen real ones (15–21 minutes on two cores).
`sim` is the suite's simulated flight (or, for an effect the suite flies on its own
circle or with its own shaking, that flight, with its own control). Prints a line per
effect and flight (found or missed, the recovered parameters after subtracting the
control) and a count per flight.
The findings themselves go to OUT with `.findings.json` for a suffix; `--rejudge` judges
those again without diagnosing (after a change to the judging)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import test_diagnose as cases  # noqa: E402  - the cases and their tolerances are the suite's

from rig import paths  # noqa: E402
from rig.importer import load_any  # noqa: E402
from rig.simulate import Predictor, inject, simulate  # noqa: E402


# Fourteen real flights of the three days, both UWB modes, with and without obstacles.
FLIGHTS = ["0426-traj1", "0426-traj4", "0425-traj5", "0422-log01", "0422-log00", "0422-log03", "0425-traj1",
           "0425-traj9", "0425-traj13", "0425-traj17", "0425-traj21", "0426-traj2", "0426-traj6", "0426-traj8"]


def diagnosed(job: tuple[str, str]) -> tuple[str, str, list, list | None]:
    """The findings on the flight with the effect injected, and on its own untouched
    flight when it is not the flight's shared control (a simulated case with its own
    circle or shaking)."""
    flight, name = job
    effects = [] if name == "control" else [{"effect": name, "params": cases.CASES[name][0]}]
    if flight == "sim":
        survey = paths.data_dir() / "surveys" / "anchor_0425.txt"
        found = _listed(cases.diagnose(simulate(cases.sim_case(survey, name, effects))))
        own = cases.own_sim_control(name)
        control = _listed(cases.diagnose(simulate(cases.sim_case(survey, name, [])))) if own else None
        return flight, name, found, control
    rec = load_any(paths.data_dir() / "flights" / flight)
    if effects:
        rec = inject(rec, effects, seed=1, predictor=Predictor(rec))
    return flight, name, _listed(cases.diagnose(rec)), None


def _listed(diagnosis) -> list:
    return diagnosis.to_json()["findings"]


def judge(found: dict, control: dict, name: str, real: bool) -> tuple[bool, str]:
    params, check = cases.CASES[name]
    try:
        cases._check(found, control, name, params, check, real=real)
        return True, "found"
    except AssertionError as error:
        return False, str(error).split(";")[0][:160]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+", default=["sim", *FLIGHTS])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "concealed.json")
    parser.add_argument("--rejudge", action="store_true", help="judge the findings of the last run again")
    args = parser.parse_args()
    raw = args.out.with_suffix(".findings.json")
    if args.rejudge:
        results = {tuple(key.split("|")): value for key, value in json.loads(raw.read_text()).items()}
        flights = list(dict.fromkeys(flight for flight, _ in results))
    else:
        flights = args.flights
        jobs = [(f, n) for f in flights for n in ["control", *cases.CASES]]
        with Pool(2) as pool:
            done = {(f, n): (found, own) for f, n, found, own in pool.imap_unordered(diagnosed, jobs)}
        results = {job: done[job] for job in jobs}             # in the order of the flights, for --rejudge
        raw.parent.mkdir(parents=True, exist_ok=True)
        raw.write_text(json.dumps({f"{f}|{n}": value for (f, n), value in results.items()}))
    summary = {}
    for flight in flights:
        rows = {}
        for name in cases.CASES:
            found, own = results[(flight, name)]
            control = cases.keyed(own or results[(flight, "control")][0])
            ok, how = judge(cases.keyed(found), control, name, real=flight != "sim")
            rows[name] = {"found": ok, "detail": how}
            print(f"{flight:12s} {name:16s} {'found ' if ok else 'MISSED'} {'' if ok else how}")
        summary[flight] = {"found": sum(r["found"] for r in rows.values()), "of": len(rows), "cases": rows}
        print(f"{flight}: {summary[flight]['found']} of {len(rows)}")
    real = [flight for flight in flights if flight != "sim"]
    per_effect = {name: sum(summary[f]["cases"][name]["found"] for f in real) for name in cases.CASES}
    for name, found in per_effect.items():
        print(f"{name:16s} found on {found} of {len(real)} real flights")
    print(f"real: {sum(per_effect.values())} of {len(real) * len(cases.CASES)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"flights": summary, "real_flights_per_effect": per_effect}, indent=1))


if __name__ == "__main__":
    main()
