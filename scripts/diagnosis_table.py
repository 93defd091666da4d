"""Summarise `rig diagnose` reports of many flights as the Markdown tables of
docs/diagnosis.md.

    for d in $UWB_RIG_DATA/flights/*; do rig diagnose $d --out out/diagnosis/$(basename $d); done
    .venv/bin/python scripts/diagnosis_table.py out/diagnosis
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path


def main(root: Path) -> None:
    reports = {d.name: json.loads((d / "report.json").read_text())
               for d in sorted(root.iterdir()) if (d / "report.json").is_file()}
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
    print()
    print("| effect | flights where it was found (of %d) |" % len(reports))
    print("|---|---|")
    for effect, n in counts.most_common():
        flights = sum(1 for r in reports.values() if any(f["effect"] == effect for f in r["findings"]))
        print(f"| {effect} | {flights} |")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "out/diagnosis"))
