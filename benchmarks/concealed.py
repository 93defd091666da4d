"""The concealed-effect cases of tests/test_diagnose.py on more flights than the suite
runs: each catalog effect injected alone into a flight, diagnosed, compared with the
untouched flight as control, judged by the suite's own tolerances.

    .venv/bin/python benchmarks/concealed.py [--flights sim 0426-traj1 ...] [--cases nlos ...] [--out out/concealed.json] [--rejudge]
    .venv/bin/python benchmarks/concealed.py --variants --out out/variants.json     # 8 minutes
    .venv/bin/python benchmarks/concealed.py --held-out --out out/held-out.json     # 9 minutes

By default the simulated flight and fourteen real ones (15–21 minutes on two cores).
`sim` is the suite's simulated flight (or, for an effect the suite flies on its own
circle or with its own shaking, that flight, with its own control). Prints a line per
effect and flight (found or missed, the recovered parameters after subtracting the
control) and a count per flight. A case whose injected effect is smaller than the size
from which the injected flight tells it from its look-alikes, along its direction
(rig.diagnosis.identifiability), is marked "below what the flight tells apart": its own signal
beyond the look-alikes does not pay for it, and it is found only as a change of the
flight's own effect of that kind or reported in its look-alike's place.
Each case is judged three ways (JUDGES): as the suite judges it; as a check that reads
the two reports' findings and nothing else would (an effect a report does not name
neutral there, an NLOS's change the difference of the two reports' mean shifts;
judge_alone), counting the fits a report lists as not explained (beyond their effect's
physical bound) as named; and so, but reading report.json's `findings` alone, with
what it leaves not explained as not named. Over the real flights that ran the issue's
whole catalog, it prints the share of the ways to draw 8 of its 12 cases in which at
least 7 are found, each way.
The findings themselves go to OUT with `.findings.json` for a suffix; `--rejudge` judges
those again without diagnosing (after a change to the judging). `--variants` runs other
sizes, signs, anchors and axes of the catalog effects (VARIANTS) on six real flights
instead of the suite's cases. `--held-out` runs the suite's cases on eight real flights
on which no change to the method was measured (HELD_OUT_FLIGHTS)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import asdict
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "tests" / "diagnosis")]

import diagnosis_cases as cases  # noqa: E402  - the cases and their tolerances are the suite's

from rig.data import paths
from rig.data.importer import load_any  # noqa: E402
from rig.diagnosis import compare  # noqa: E402
from rig.diagnosis.diagnose import diagnose  # noqa: E402
from rig.diagnosis.candidates import candidates  # noqa: E402
from rig.diagnosis.diagnose import nlos_identifiability  # noqa: E402
from rig.sim.effects import Region  # noqa: E402
from rig.sim.simulate import Predictor, inject, simulate  # noqa: E402

# Fourteen real flights of the three days, both UWB modes, with and without obstacles.
FLIGHTS = ["0426-traj1", "0426-traj4", "0425-traj5", "0422-log01", "0422-log00", "0422-log03", "0425-traj1",
           "0425-traj9", "0425-traj13", "0425-traj17", "0425-traj21", "0426-traj2", "0426-traj6", "0426-traj8"]
# Eight others of the three days, on which no concealed case ran before session 46:
# every change to the method was measured on FLIGHTS (and VARIANT_FLIGHTS, a subset).
# How it does on flights it was not built on (--held-out).
HELD_OUT_FLIGHTS = ["0422-log02", "0425-traj3", "0425-traj10", "0425-traj15", "0425-traj19", "0426-traj3",
                    "0426-traj5", "0426-traj7"]


# Other sizes, signs, anchors and axes than the suite's cases (--variants), each with a
# tolerance of the suite's kind for its size: whether the tool generalises beyond the
# cases it was built on. label: (effect, params, check)
VARIANTS = {
    "time_offset -50 ms": ("time_offset", {"seconds": -0.05}, cases.scalar_close("seconds", 0.35)),
    "time_offset +100 ms": ("time_offset", {"seconds": 0.1}, cases.scalar_close("seconds", 0.35)),
    # the sizes of two cases the issue reports missed on held-out flights (added in
    # session 62, measured only: nothing in the method is changed on their result)
    "time_offset +35 ms": ("time_offset", {"seconds": 0.035}, cases.scalar_close("seconds", 0.35)),
    "time_offset -35 ms": ("time_offset", {"seconds": -0.035}, cases.scalar_close("seconds", 0.35)),
    "anchor_position 4 (ceiling) 0.27 m": ("anchor_position", {"anchor": 4, "offset_m": [0.2, -0.15, 0.1]},
                                           cases.vector_close("offset_m", 0.06)),
    "clock_drift -1500 ppm": ("clock_drift", {"ppm": -1500.0}, cases.scalar_close("ppm", 0.25)),
    "anchor_delay 1 -0.15 m": ("anchor_delay", {"anchor": 1, "meters": -0.15}, cases.scalar_close("meters", 0.25)),
    "anchor_delay 7 +0.10 m": ("anchor_delay", {"anchor": 7, "meters": 0.1}, cases.scalar_close("meters", 0.25)),
    "anchor_position 0 up 0.2 m": ("anchor_position", {"anchor": 0, "offset_m": [0.0, 0.0, 0.2]},
                                   cases.vector_close("offset_m", 0.06)),
    "anchor_position 6 oblique": ("anchor_position", {"anchor": 6, "offset_m": [-0.15, 0.1, 0.1]},
                                  cases.vector_close("offset_m", 0.06)),
    "imu_accel_bias 3 axes": ("imu_accel_bias", {"bias_mps2": [0.1, -0.1, 0.1]},
                              cases.vector_close("bias_mps2", 0.03)),
    "imu_gyro_bias x, y": ("imu_gyro_bias", {"bias_rps": [0.01, -0.01, 0.0]}, cases.vector_close("bias_rps", 0.004)),
    "imu_accel_scale z 0.97": ("imu_accel_scale", {"scale": [1.0, 1.0, 0.97]}, cases.axis_close("scale", 2, 0.01)),
    "imu_accel_scale 3 axes 1.03": ("imu_accel_scale", {"scale": [1.03, 1.03, 1.03]},
                                    cases.vector_close("scale", 0.01)),
    "imu_gyro_scale 3 axes 1.05": ("imu_gyro_scale", {"scale": [1.05, 1.05, 1.05]}, cases.vector_close("scale", 0.03)),
    "imu_gyro_scale z 0.9": ("imu_gyro_scale", {"scale": [1.0, 1.0, 0.9]}, cases.axis_close("scale", 2, 0.03)),
    "lever_arm y 6 cm": ("lever_arm", {"offset_m": [0.0, 0.06, 0.0]}, cases.vector_close("offset_m", 0.03)),
    "lever_arm x, y 5 cm": ("lever_arm", {"offset_m": [0.05, -0.05, 0.0]}, cases.vector_close("offset_m", 0.03)),
    "antenna_pattern 5": ("antenna_pattern", {"anchor": 5, "coeffs_m": [-0.2, 0.0, 0.3]},
                          cases.vector_close("coeffs_m", 0.15)),
    "antenna_pattern 0": ("antenna_pattern", {"anchor": 0, "coeffs_m": [0.0, -0.3, 0.2]},
                          cases.vector_close("coeffs_m", 0.15)),
    "nlos 1 x < 0": ("nlos", {"anchor": 1, "fraction": 0.5, "mean_excess_m": 0.3,
                              "region": {"min": [-5, -5, -1], "max": [0, 5, 5]}}, cases.CASES["nlos"][1]),
    "nlos 3 above 1 m": ("nlos", {"anchor": 3, "fraction": 0.5, "mean_excess_m": 0.3,
                                  "region": {"min": [-5, -5, 1.0], "max": [5, 5, 5]}}, cases.CASES["nlos"][1]),
}
VARIANT_FLIGHTS = ["0426-traj1", "0425-traj5", "0422-log00", "0425-traj13", "0426-traj6", "0425-traj21"]


def case_set(variants: bool) -> dict[str, tuple]:
    """label: (effect, params, check) of the suite's cases or of the variants."""
    if variants:
        return VARIANTS
    return {name: (name, params, check) for name, (params, check) in cases.CASES.items()}


def describe(shown: compare.Shown) -> str:
    limit = "at no size" if shown.told_apart_from is None else f"from {shown.told_apart_from:.3g}"
    return f"below what the flight tells apart ({shown.size:.3g}; told apart {limit})"


def diagnosed(job: tuple[str, str, str, dict]) -> tuple[str, str, list, list | None, dict | None, dict | None]:
    """The findings on the flight with the effect injected, on its own untouched flight
    when it is not the flight's shared control (a simulated case with its own circle or
    shaking), how well the injected flight shows the effect (rig.diagnosis.compare.Shown), and
    for an NLOS and for the control their TDOA samples, over which an NLOS's change is
    estimated."""
    flight, label, name, params = job
    effects = [] if label == "control" else [{"effect": name, "params": params}]
    control = None
    if flight == "sim":
        survey = paths.data_dir() / "surveys" / "anchor_0425.txt"
        diagnosis = diagnose(simulate(cases.sim_case(survey, name, effects)))
        if cases.own_sim_control(name):
            control = _listed(diagnose(simulate(cases.sim_case(survey, name, []))))
    else:
        rec = load_any(paths.data_dir() / "flights" / flight)
        if effects:
            rec = inject(rec, effects, seed=1, predictor=Predictor(rec))
        diagnosis = diagnose(rec)
    shown = shown_in(diagnosis, name, params) if effects else None
    samples = compare.TdoaSamples.of(diagnosis).to_json() if name == compare.NLOS or not effects else None
    return flight, label, _listed(diagnosis), control, asdict(shown) if shown else None, samples


def shown_in(diagnosis, name: str, params: dict) -> compare.Shown | None:
    """The injected effect against what its recording tells apart; an NLOS by its mean
    shift (fraction × mean excess) beyond every parametric candidate."""
    anchors = [params["anchor"]] if "anchor" in params else []
    if name != "nlos":
        return compare.shown(diagnosis.identifiability, name, anchors, params)
    problem = diagnosis.problem
    item = nlos_identifiability(problem, candidates(problem), params["anchor"], Region.from_json(params["region"]))
    return compare.shown([item], name, anchors, {"mean_shift_m": compare.mean_shift(params)})


def _listed(diagnosis) -> dict:
    """What the judge reads of a diagnosis: its findings, the parametric TDOA effects
    it does not name and the look-alikes in its named effects' places, as it estimates
    them."""
    report = diagnosis.to_json()
    return {"findings": compare.every_fit(report), "unnamed": report["unnamed_estimates"],
            "in_place": report["in_place_estimates"]}


# How a case is judged, and the key of its verdict in the rows: as the suite judges;
# by the two reports alone, the fits not explained counted; by their `findings` alone.
JUDGES = {"suite": "found", "reports": "found_alone", "findings": "found_in_findings"}


def judge(found: dict, control: dict, name: str, params: dict, check, real: bool,
          samples: compare.TdoaSamples | None, control_samples: compare.TdoaSamples | None,
          how: str = "suite") -> tuple[bool, str]:
    """`found`: the injected flight's fits (findings and those not explained), keyed;
    `control`: its control's, as listed. `how`: one of JUDGES (see judge_alone for
    "reports"; "findings" judges so after leaving out on both recordings every fit
    beyond its effect's physical bound, which report.json lists as not explained)."""
    own = cases.keyed(control["findings"])
    if how == "findings":
        found, own = within_bound(found), within_bound(own)
    try:
        if how != "suite":
            judge_alone(found, own, name, params, check, real, samples)
        else:
            cases.check_case(found, own, name, params, check, real=real, samples=samples,
                         control_samples=control_samples, control_unnamed=cases.keyed(control["unnamed"]),
                         control_in_place=control.get("in_place", ()))
        return True, "found"
    except AssertionError as error:
        return False, str(error).split(";")[0][:160]


def within_bound(keyed: dict) -> dict:
    """The fits report.json lists as findings: those within their effect's physical bound."""
    return {key: fit for key, fit in keyed.items() if not fit.get("beyond_physical_bound")}


def judge_alone(found: dict, own: dict, name: str, params: dict, check, real: bool,
                samples: compare.TdoaSamples | None) -> None:
    """The suite's judge without what only `rig diagnose --control` reports: an effect
    a report does not name is neutral there (not its `unnamed_estimates`), and an
    NLOS's change is the injected report's mean shift less the control's on that
    anchor, wherever either found it (not both recordings' estimates in the region
    found). Where it is located is still judged over the injected recording's own
    positions, which such a check has too."""
    if name != compare.NLOS:
        cases.check_case(found, own, name, params, check, real=real, samples=samples)
        return
    key = (name, (params["anchor"],))
    assert key in found, f"{name} not named; found {sorted(found)}"
    shift = compare.mean_shift(found[key]["params"]) - (compare.mean_shift(own[key]["params"]) if key in own else 0.0)
    assert check({"mean_shift_m": shift}, params), f"{name}: a mean shift of {shift:.3f} m beyond the control's"
    assert found[key]["fit_after"] < found[key]["fit_before"]
    cases.check_region(found[key]["params"], params, samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--flights", nargs="+",
                        help="default: sim and the fourteen real flights (FLIGHTS); with --variants, VARIANT_FLIGHTS")
    parser.add_argument("--cases", nargs="+", help="only these cases (default: all of the set)")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "concealed.json")
    parser.add_argument("--rejudge", action="store_true", help="judge the findings of the last run again")
    parser.add_argument("--held-out", action="store_true",
                        help=f"the suite's cases on flights no change to the method was measured on: "
                             f"{' '.join(HELD_OUT_FLIGHTS)}")
    parser.add_argument("--variants", action="store_true",
                        help=f"other sizes, signs, anchors and axes than the suite's cases (default flights: "
                             f"{' '.join(VARIANT_FLIGHTS)})")
    args = parser.parse_args()
    chosen = case_set(args.variants)
    if args.cases:
        unknown = set(args.cases) - set(chosen)
        if unknown:
            parser.error(f"unknown cases {sorted(unknown)}; known: {', '.join(chosen)}")
        chosen = {label: chosen[label] for label in args.cases}
    raw = args.out.with_suffix(".findings.json")
    if args.rejudge:
        results = {tuple(key.split("|")): value for key, value in json.loads(raw.read_text()).items()}
        flights = list(dict.fromkeys(flight for flight, _ in results))
        chosen = {label: case for label, case in chosen.items() if (flights[0], label) in results}   # the run's
    else:
        flights = args.flights or (VARIANT_FLIGHTS if args.variants else HELD_OUT_FLIGHTS if args.held_out
                                   else ["sim", *FLIGHTS])
        jobs = [(f, label, *(chosen[label][:2] if label != "control" else ("", {})))
                for f in flights for label in ["control", *chosen]]
        with Pool(2) as pool:
            done = {(f, n): rest for f, n, *rest in pool.imap_unordered(diagnosed, jobs)}
        results = {job[:2]: done[job[:2]] for job in jobs}     # in the order of the flights, for --rejudge
        raw.parent.mkdir(parents=True, exist_ok=True)
        raw.write_text(json.dumps({f"{f}|{n}": value for (f, n), value in results.items()}))
    summary = {}
    for flight in flights:
        rows = {}
        for label, (name, params, check) in chosen.items():
            found, own, listed_shown, listed_samples = results[(flight, label)]
            shown = listed_shown and compare.Shown(**listed_shown)
            samples = listed_samples and compare.TdoaSamples.from_json(listed_samples)
            control, _, _, control_samples = results[(flight, "control")]
            control_samples = control_samples and compare.TdoaSamples.from_json(control_samples)
            verdicts = {how: judge(cases.keyed(found["findings"]), own or control, name, params, check,
                                   flight != "sim", samples, control_samples, how) for how in JUDGES}
            (ok, detail), (alone_ok, alone_detail) = verdicts["suite"], verdicts["reports"]
            below = None if shown is None else shown.below
            rows[label] = {**{JUDGES[how]: v[0] for how, v in verdicts.items()}, "detail": detail,
                           "below_told_apart": below}
            print(f"{flight:12s} {label:28s} {'found ' if ok else 'MISSED'} {'' if ok else detail}"
                  + (f" [{describe(shown)}]" if below else "")
                  + (f" [by the reports alone: {'found' if alone_ok else alone_detail}]" if alone_ok != ok else "")
                  + (" [not in `findings`]" if alone_ok and not verdicts["findings"][0] else ""))
        summary[flight] = {**{key: sum(r[key] for r in rows.values()) for key in JUDGES.values()},
                           "of": len(rows), "cases": rows}
        print(f"{flight}: {summary[flight]['found']} of {len(rows)} (by the reports alone "
              f"{summary[flight]['found_alone']}, by their findings alone {summary[flight]['found_in_findings']})")
    real = [flight for flight in flights if flight != "sim"]
    per_effect = {label: sum(summary[f]["cases"][label]["found"] for f in real) for label in chosen}
    below = {label: below_told_apart([summary[f]["cases"][label] for f in real]) for label in chosen}
    for label, found in per_effect.items():
        print(f"{label:28s} found on {found:2d} of {len(real)} real flights"
              + (f"; below what the flight tells apart on {below[label]['flights']}, found on "
                 f"{below[label]['found']} of those" if below[label] and below[label]["flights"] else ""))
    draws = {key: draws_finding_most([summary[f]["cases"] for f in real], key) for key in JUDGES.values()}
    print(f"real: {sum(per_effect.values())} of {len(real) * len(chosen)} "
          f"(by the reports alone {sum(summary[f]['found_alone'] for f in real)}, "
          f"by their findings alone {sum(summary[f]['found_in_findings'] for f in real)})")
    if all(draws.values()):
        print(f"draws of {DRAWN} of the issue's catalog finding at least {DRAWN - 1}: {draws['found']:.0%} "
              f"(by the reports alone {draws['found_alone']:.0%}, by their findings alone "
              f"{draws['found_in_findings']:.0%})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"flights": summary, "real_flights_per_effect": per_effect,
                                    "below_told_apart_per_effect": below, "draws_finding_most": draws}, indent=1))


# The issue's catalog: the effects the check that draws its cases from knows by name
# (the rectification is this tool's addition).
ISSUE_CATALOG = ["time_offset", "clock_drift", "anchor_position", "anchor_delay", "antenna_pattern", "nlos",
                 "multipath_floor", "imu_accel_bias", "imu_gyro_bias", "imu_accel_scale", "imu_gyro_scale",
                 "lever_arm"]
DRAWN = 8      # the issue's check injects this many and asks for all but one


def draws_finding_most(flights: list[dict], how: str) -> float | None:
    """Over `flights` (each its cases' verdicts, by label), the share of the ways to
    draw DRAWN of the issue's catalog cases in which at least DRAWN − 1 are found,
    `how` they were judged; None unless every flight ran the whole catalog."""
    shares = []
    for rows in flights:
        if not set(ISSUE_CATALOG) <= set(rows):
            return None
        missed = sum(not rows[label][how] for label in ISSUE_CATALOG)
        kept = len(ISSUE_CATALOG) - missed
        ways = math.comb(kept, DRAWN) + missed * math.comb(kept, DRAWN - 1)
        shares.append(ways / math.comb(len(ISSUE_CATALOG), DRAWN))
    return float(sum(shares) / len(shares)) if shares else None


def below_told_apart(rows: list[dict]) -> dict | None:
    """On how many flights a case is below what the flight tells apart, and on how many
    of those it is found anyway (None for a case without design columns)."""
    if any(r["below_told_apart"] is None for r in rows):
        return None
    below = [r for r in rows if r["below_told_apart"]]
    return {"flights": len(below), "found": sum(r["found"] for r in below)}


if __name__ == "__main__":
    main()
