"""Diagnosis of every shared flight; regenerates the real-data table of docs/notebook/diagnosis.md.

    .venv/bin/python benchmarks/diagnosis.py [--out out/diagnosis] [--reuse] [--doc docs/notebook/diagnosis.md]

Runs `rig diagnose` on each flight (two at a time) into OUT/<flight>/ (--reuse keeps
reports already there), prints the tables (the findings; the IMU low-pass the models
carry and how much of the noise power lies above 100 Hz) and writes OUT/summary.json."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "diagnosis")]

import numpy as np  # noqa: E402
from diagnosis_cases import CASES  # noqa: E402  - the suite's concealed cases, for their sizes

from rig.data import paths
from rig.data.importer import load_any  # noqa: E402
from rig.data.recording import Vec3Series  # noqa: E402
from rig.diagnosis import compare, imu_spectrum  # noqa: E402
from rig.diagnosis.channels import left_out_text  # noqa: E402
from rig.diagnosis.diagnose import bound_measure  # noqa: E402
from rig.diagnosis.floor_error import ON_GROUND_M  # noqa: E402
from rig.diagnosis.identifiability import figures, measured_size  # noqa: E402
from rig.diagnosis.imu_spectrum import vibration_spread  # noqa: E402
from rig.sim import effects as fx  # noqa: E402


def run(flight: Path, out: Path, reuse: bool) -> None:
    if reuse and (out / "report.json").is_file():
        return
    # one BLAS thread per process: two processes with spinning BLAS threads each on two
    # cores run several times slower than one after the other
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    subprocess.run([sys.executable, "-m", "rig", "diagnose", str(flight), "--out", str(out)], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL, env=env)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "diagnosis")
    parser.add_argument("--reuse", action="store_true", help="keep reports already in OUT")
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "notebook" / "diagnosis.md")
    args = parser.parse_args()
    flights = sorted((paths.data_dir() / "flights").iterdir())
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda f: run(f, args.out / f.name, args.reuse), flights))
    reports = {f.name: json.loads((args.out / f.name / "report.json").read_text()) for f in flights}
    models = {f.name: json.loads((args.out / f.name / "model.json").read_text()) for f in flights}
    table = tables(reports) + "\n\n" + in_short(reports, models)
    print(table)
    (args.out / "summary.json").write_text(json.dumps(
        {name: {"channels": r["channels"], "findings": r["findings"]} for name, r in reports.items()}, indent=1))
    spectra = imu_spectra(reports, {f.name: f for f in flights})
    print(spectra)
    told_apart = identifiability(reports)
    print(told_apart)
    text = (ROOT / "docs" / "notebook" / "diagnosis.md.in").read_text()
    args.doc.write_text(text.replace("{{TABLE}}", table).replace("{{IMU_SPECTRUM}}", spectra)
                        .replace("{{IDENTIFIABILITY}}", told_apart))
    print(f"wrote {args.doc} and {args.out / 'summary.json'}")


def tables(reports: dict) -> str:
    lines = []
    print = lines.append      # noqa: A001 - the table is built line by line
    print("| flight | TDOA mismatch [m] | accel [m/s²] | gyro [rad/s] | time offset [ms] | anchor delays [m] | "
          "NLOS anchors | floor multipath | accel bias [m/s²] | link bias (gain) | not explained |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    counts: Counter = Counter()
    for name, r in reports.items():
        by = {}
        for f in r["findings"]:
            by.setdefault(f["effect"], []).append(f)
            counts[f["effect"]] += 1
        ch = r["channels"]
        fit = {k: f"{c['fit_before']:.3f} → {c['fit_after']:.3f}" for k, c in ch.items()}
        offset = ", ".join(f"{f['params']['seconds'] * 1e3:+.0f}" for f in by.get("time_offset", [])) or "—"
        delays = ", ".join(f"{f['anchors'][0]}: {f['params']['meters']:+.2f}"
                           for f in sorted(by.get("anchor_delay", []), key=lambda f: f["anchors"])) or "—"
        nlos = ", ".join(str(f["anchors"][0]) for f in sorted(by.get("nlos", []), key=lambda f: f["anchors"])) or "—"
        floor = ", ".join(f"< {f['params']['height_m']} m: +{f['params']['std_m']:.2f} m"
                          + (f" and < {f['params']['upper_height_m']} m: +{f['params']['upper_std_m']:.2f} m"
                             if "upper_height_m" in f["params"] else "")
                          for f in by.get("multipath_floor", [])) or "—"
        bias = ", ".join(str([round(v, 2) for v in f["params"]["bias_mps2"]]) for f in by.get("imu_accel_bias", [])) or "—"
        link = ", ".join(f"{f['params']['gain']:.2f}" for f in by.get("link_bias", [])) or "—"
        unexplained = ", ".join(f"{effect} × {n}" for effect, n in
                                Counter(f["effect"] for f in r.get("not_explained", [])).most_common()) or "—"
        print(f"| {name} | {fit.get('tdoa', '—')} | {fit.get('accel', '—')} | {fit.get('gyro', '—')} | {offset} | "
              f"{delays} | {nlos} | {floor} | {bias} | {link} | {unexplained} |")
    gross = []
    for name, r in reports.items():
        left_out = left_out_text({chan: c["gross_errors_left_out"] for chan, c in r["channels"].items()})
        if left_out:
            gross.append(f"{name} ({left_out})")
    print("")
    print("Samples left out as corrupt (step 2; IMU samples are block means of an axis): " + ("; ".join(gross) or "none") + ".")
    print("")
    print(on_ground(reports))
    print("")
    print("| effect | flights where it was named (of %d) | reported in a look-alike's place (`alternative_to`) |"
          % len(reports))
    print("|---|---|---|")
    for effect, n in counts.most_common():
        ways = [{"alternative_to" in f for f in r["findings"] if f["effect"] == effect} for r in reports.values()]
        named, alternative = sum(False in w for w in ways), sum(True in w for w in ways)
        print(f"| {effect} | {named} | {alternative or '—'} |")
    print("")
    print(bound_check(reports))
    return "\n".join(lines)


def bound_check(reports: dict) -> str:
    """The report's contract, checked on every flight: each finding, rebuilt as its
    catalog effect, lies within that effect's physical bounds (what is beyond them is
    under `not_explained`, never a finding)."""
    findings = [(name, f) for name, r in reports.items() for f in r["findings"]]
    beyond = [f"{name}: {f['effect']} {', '.join(fx.make_effect(f['effect'], f['params']).beyond_bound())}"
              for name, f in findings
              if f.get("beyond_physical_bound") or fx.make_effect(f["effect"], f["params"]).beyond_bound()]
    moved = [f for r in reports.values() for f in r.get("not_explained", [])]
    within = sum(1 for f in moved if not fx.make_effect(f["effect"], f["params"]).beyond_bound())
    return (f"Findings beyond their effect's physical bound: {len(beyond)} of {len(findings)} on "
            f"{len(reports)} flights" + (f" ({'; '.join(beyond)})" if beyond else "")
            + f"; {len(moved)} fits are under `not_explained`: {len(moved) - within} beyond it, {within} "
            "within it but left out of the re-simulating model beside one beyond it.")


def in_short(reports: dict, models: dict) -> str:
    """The figures the page's summary quotes: how much closer to the recording the
    re-simulated TDOA comes, and the time offset as named and as the models carry it."""
    closer = [1 - r["channels"]["tdoa"]["fit_after"] / r["channels"]["tdoa"]["fit_before"] for r in reports.values()]
    named = [f["params"]["seconds"] for r in reports.values() for f in r["findings"] if f["effect"] == "time_offset"]
    modelled = [e["params"]["seconds"] for m in models.values() for e in m["effects"] if e["effect"] == "time_offset"]
    return (f"Re-simulated TDOA closer to the recording by {min(closer):.0%}–{max(closer):.0%} "
            f"(median {np.median(closer):.0%}); time offset named on {len(named)} flights, median "
            f"{np.median(named) * 1e3:+.0f} ms, in the re-simulating model on {len(modelled)}, median "
            f"{np.median(modelled) * 1e3:+.0f} ms.")


def on_ground(reports: dict) -> str:
    """How each anchor's ranges read with the tag on the floor against in flight, over
    the flights, median (min–max) per anchor: located against the untouched simulation
    (`mismatch.tdoa_on_ground_m`), and as the models carry it (`on_ground_delay`,
    with the shapes it was named with: a step, or a fade above its height)."""
    located = [r["mismatch"].get("tdoa_on_ground_m", {}) for r in reports.values()]
    modelled = [f for r in reports.values() for f in r["findings"] if f["effect"] == "on_ground_delay"]
    shapes = Counter((f["params"]["height_m"], f["params"].get("fade_m", 0.0)) for f in modelled)
    return (f"With the tag on the floor (below {ON_GROUND_M:g} m; {sum(map(bool, located))} of {len(reports)} "
            f"flights), each anchor's ranges read, against its own in flight (relative to the other anchors'), "
            f"median (min–max) over the flights: {_per_anchor_spans(located)}. Modelled (`on_ground_delay`) on "
            f"{len(modelled)} of {len(reports)} flights, "
            + ", ".join(f"{_shape(h, fade)} on {n}" for (h, fade), n in sorted(shapes.items()))
            + f": {_per_anchor_spans([f['params']['meters'] for f in modelled])}.")


def identifiability(reports: dict) -> str:
    """Per candidate effect, over the flights (and anchors), the size from which each
    flight shows it and tells it from its look-alikes (report.json's
    `identifiability`), median (min–max), how often that is within its physical
    bound, and the size of the suite's concealed case of it."""
    items: dict[str, list[dict]] = {}
    for r in reports.values():
        for i in r["identifiability"]:
            items.setdefault(i["effect"], []).append(i)
    lines = ["| effect | shows from | told from its look-alikes from | told apart (of flights × anchors) | "
             "the concealed case's size | look-alikes |", "|---|---|---|---|---|---|"]
    for effect, found in items.items():
        unit = f" {found[0]['unit']}" if found[0]["unit"] else ""
        apart = [i["smallest_told_apart"] for i in found if i["smallest_told_apart"] is not None]
        lines.append(f"| {effect} (`{found[0]['param']}`) | {_span([i['smallest_seen'] for i in found], 3, unit)} | "
                     f"{_span(apart, 3, unit)} | {sum(i['told_apart'] for i in found)} of {len(found)} | "
                     f"{_case_size(effect, found[0]['param'], unit)} | "
                     f"{', '.join(found[0]['look_alikes']) or '—'} |")
    return "\n".join(lines)


def _case_size(effect: str, param: str, unit: str) -> str:
    """The size of the suite's concealed case of `effect`: its parameter's change from
    neutral, as the effect's bound measures it (as `identifiability`'s sizes)."""
    if effect not in CASES:
        return "—"
    change = np.subtract(CASES[effect][0][param], compare.neutral(effect))
    return f"{figures(measured_size(np.ravel(change), bound_measure(effect, param)))}{unit}"


def _shape(height: float, fade: float) -> str:
    return f"fading out from {height:g} to {height + fade:g} m" if fade else f"below {height:g} m"


def _per_anchor_spans(readings: list[dict[str, float]]) -> str:
    per_anchor: dict[str, list[float]] = {}
    for flight in readings:
        for k, v in flight.items():
            per_anchor.setdefault(k, []).append(v)
    return "; ".join(f"{k}: {_span(v, 2)} m" for k, v in sorted(per_anchor.items(), key=lambda kv: int(kv[0]))) or "—"


def imu_spectra(reports: dict, flights: dict[str, Path]) -> str:
    """The IMU low-pass and resonance each flight's model carries (corner and peak
    frequency: range and median over the flights, per sensor), the share of the noise
    power above SHARE_ABOVE_HZ: in the recording, in the model and in white noise, the
    model without them (over FIT_FROM_HZ to the highest corner a filter can have), and
    what an estimator at 100 Hz sees of the noise (_estimator_spread)."""
    rows = {"accel": [], "gyro": []}
    for name, report in reports.items():
        model = fx.params_by_name(report["model"])
        rec = load_any(flights[name])
        for sensor in rows:
            spec = imu_spectrum.spectrum(getattr(rec, sensor))
            corner = model.get("imu_lowpass", {}).get(f"{sensor}_hz", 0.0)
            if spec is None:
                continue
            band = imu_spectrum.fit_band(spec)
            freq, recorded = spec.freq[band], spec.power[:, band].mean(axis=0)
            shape = imu_spectrum.model_density(freq, spec.rate, model, sensor)
            shares = [imu_spectrum.share_above(freq, p, SHARE_ABOVE_HZ) for p in (recorded, shape, np.ones(len(freq)))]
            peak = model.get("imu_resonance", {}).get(f"{sensor}_hz", 0.0)
            rows[sensor].append((corner, *shares, *_estimator_spread(getattr(rec, sensor), model, sensor), peak))
    lines = [f"| sensor | low-pass: flights | corner [Hz]: median (range) | peak: flights | peak [Hz]: median "
             f"(range) | power above {SHARE_ABOVE_HZ:g} Hz: recorded | model | white | 10 ms means' spread ÷ "
             "recorded, x, y, z: model | one size through the low-pass | white of one size |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for sensor, values in rows.items():
        found = {key: [v[k] for v in values if v[k] > 0] for key, k in (("corner", 0), ("peak", 7))}
        spans = {"corner": _span(found["corner"], 0), "peak": _span(found["peak"], 1)}
        shares = [np.median([v[k] for v in values]) for k in (1, 2, 3)]
        spreads = [np.median([v[k] for v in values], axis=0) for k in (4, 5, 6)]
        lines.append(f"| {sensor} | {len(found['corner'])} of {len(values)} | {spans['corner']} | "
                     f"{len(found['peak'])} of {len(values)} | {spans['peak']} | "
                     + " | ".join(f"{share:.1%}" for share in shares) + " | "
                     + " | ".join(", ".join(f"{r:.2f}" for r in ratio) for ratio in spreads) + " |")
    lines.append("")
    lines.append("(medians over the flights; a 10 ms mean is what an estimator running at 100 Hz takes in; "
                 "\"one size\": the axes' mean spread on all three)")
    return "\n".join(lines)


def _span(values: list[float], digits: int, unit: str | None = None) -> str:
    """'median (min–max)', or a dash for none: `digits` decimals, or with a `unit`
    (sizes that span ppm to rad/s) significant figures and the unit."""
    if not values:
        return "—"
    if unit is None:
        return f"{np.median(values):.{digits}f} ({min(values):.{digits}f}–{max(values):.{digits}f})"
    return f"{figures(np.median(values))} ({figures(min(values))}–{figures(max(values))}){unit}"


SHARE_ABOVE_HZ = 100.0
ESTIMATOR_S = 0.01             # the estimator's step: it takes in 10 ms means of the IMU


def _estimator_spread(series, model: dict, sensor: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per axis, the spread of 10 ms means of the model's noise (its white noise and
    resonance, per axis, through its low-pass), of white noise of one size (the axes'
    mean) through the same low-pass, and of white noise of that one size unfiltered,
    each over that of the recording's fast part (the readings less their 0.2 s
    running mean)."""
    fast, rate = imu_spectrum.fast_part(series)
    t = series.t[: len(fast)]
    white = np.broadcast_to(np.asarray(model["imu_noise"][f"{sensor}_std"], float), (3,))
    corner = model.get("imu_lowpass", {}).get(f"{sensor}_hz", 0.0)
    peak = model.get("imu_resonance", {})
    resonance = imu_spectrum.Resonance(peak[f"{sensor}_hz"], peak[f"{sensor}_q"], np.zeros(3)) if peak else None
    modelled = imu_spectrum.logged_noise(np.random.default_rng(0), t, corner, white, resonance,
                                         np.asarray(peak.get(f"{sensor}_std", np.zeros(3))))
    one_size = np.mean(vibration_spread(series))      # white noise of one size: the axes' mean spread
    noise = np.random.default_rng(0).normal(size=fast.shape)
    recorded = imu_spectrum.means_spread(fast, rate, ESTIMATOR_S)
    candidates = (modelled, fx.lowpass(t, noise * one_size / imu_spectrum.noise_gain(corner, rate), corner),
                  noise * one_size)
    return tuple(imu_spectrum.means_spread(imu_spectrum.fast_part(Vec3Series(t, values))[0], rate, ESTIMATOR_S)
                 / recorded
                 for values in candidates)            # each as the recording's: less its 0.2 s running mean


if __name__ == "__main__":
    main()
