"""Diagnosis of every shared flight; regenerates the real-data table of docs/diagnosis.md.

    .venv/bin/python benchmarks/diagnosis.py [--out out/diagnosis] [--reuse] [--doc docs/diagnosis.md]

Runs `rig diagnose` on each flight (two at a time) into OUT/<flight>/ (--reuse keeps
reports already there), prints the table and writes OUT/summary.json."""

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
sys.path.insert(0, str(ROOT))

from rig import paths  # noqa: E402
from rig.diagnose import left_out_text  # noqa: E402


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
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "diagnosis.md")
    args = parser.parse_args()
    flights = sorted((paths.data_dir() / "flights").iterdir())
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda f: run(f, args.out / f.name, args.reuse), flights))
    reports = {f.name: json.loads((args.out / f.name / "report.json").read_text()) for f in flights}
    table = tables(reports)
    print(table)
    (args.out / "summary.json").write_text(json.dumps(
        {name: {"channels": r["channels"], "findings": r["findings"]} for name, r in reports.items()}, indent=1))
    text = (ROOT / "docs" / "diagnosis.md.in").read_text()
    args.doc.write_text(text.replace("{{TABLE}}", table))
    print(f"wrote {args.doc} and {args.out / 'summary.json'}")


def tables(reports: dict) -> str:
    lines = []
    print = lines.append      # noqa: A001 - the table is built line by line
    print("| flight | TDOA mismatch [m] | accel [m/s²] | gyro [rad/s] | time offset [ms] | anchor delays [m] | "
          "NLOS anchors | floor multipath | accel bias [m/s²] |")
    print("|---|---|---|---|---|---|---|---|---|")
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
                          for f in by.get("multipath_floor", [])) or "—"
        bias = ", ".join(str([round(v, 2) for v in f["params"]["bias_mps2"]]) for f in by.get("imu_accel_bias", [])) or "—"
        print(f"| {name} | {fit.get('tdoa', '—')} | {fit.get('accel', '—')} | {fit.get('gyro', '—')} | {offset} | "
              f"{delays} | {nlos} | {floor} | {bias} |")
    gross = []
    for name, r in reports.items():
        left_out = left_out_text({chan: c["gross_errors_left_out"] for chan, c in r["channels"].items()})
        if left_out:
            gross.append(f"{name} ({left_out})")
    print("")
    print("Samples left out as corrupt (step 2; IMU samples are block means of an axis): " + ("; ".join(gross) or "none") + ".")
    print("")
    print("| effect | flights where it was found (of %d) |" % len(reports))
    print("|---|---|")
    for effect, n in counts.most_common():
        flights = sum(1 for r in reports.values() if any(f["effect"] == effect for f in r["findings"]))
        print(f"| {effect} | {flights} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
