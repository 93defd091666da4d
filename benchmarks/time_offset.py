"""The UWB time offset of every shared flight with and without the shared link bias in
the diagnosis's model: does the offset the catalog names stand for the pose-dependent
bias?

    .venv/bin/python benchmarks/time_offset.py [--json out/time_offset.json]     # about 16 minutes

Per flight (two at a time): `rig diagnose`'s named time offset (its estimate, which the
link bias does not move: it is judged after the catalog), and the offset in the model
that re-simulates the flight (every named effect within its bound refitted jointly),
without the link bias and with it, and the link bias's gain. The gyroscope's own
measure of the ground truth's latency is `benchmarks/truth_latency.py`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402


def offsets(flight: str) -> dict:
    from rig.data.importer import load_any
    from rig.diagnosis.diagnose import diagnose

    rec = load_any(paths.data_dir() / "flights" / flight)
    row: dict = {"flight": flight}
    for key, link_bias in (("with_link_bias", True), ("without_link_bias", False)):
        result = diagnose(rec, link_bias=link_bias)
        named = [f.params["seconds"] for f in result.findings if f.effect == "time_offset"]
        modelled = [e.params()["seconds"] for e in result.model if e.name == "time_offset"]
        gain = [f.params["gain"] for f in result.findings if f.effect == "link_bias"]
        row[key] = {"named_s": named[0] if named else None, "model_s": modelled[0] if modelled else 0.0,
                    "link_gain": gain[0] if gain else None}
    return row


def table(rows: list[dict]) -> str:
    lines = ["| flight | named [ms] | in the model without the link bias [ms] | with it [ms] | link bias gain |",
             "|---|---|---|---|---|"]
    ms = lambda s: "—" if s is None else f"{s * 1e3:+.0f}"      # noqa: E731
    for r in rows:
        w, wo = r["with_link_bias"], r["without_link_bias"]
        gain = "—" if w["link_gain"] is None else f"{w['link_gain']:.2f}"
        lines.append(f"| {r['flight']} | {ms(w['named_s'])} | {ms(wo['model_s'])} | {ms(w['model_s'])} | {gain} |")
    named = [r for r in rows if r["with_link_bias"]["named_s"] is not None]
    without = np.array([r["without_link_bias"]["model_s"] for r in named]) * 1e3
    with_ = np.array([r["with_link_bias"]["model_s"] for r in named]) * 1e3
    lines += ["", f"Named on {len(named)} of {len(rows)} flights. On those, in the model: median "
              f"{np.median(without):+.0f} ms without the link bias, {np.median(with_):+.0f} ms with it; "
              f"median |offset| {np.median(np.abs(without)):.0f} → {np.median(np.abs(with_)):.0f} ms; "
              f"smaller in size with it on {int(np.sum(np.abs(with_) < np.abs(without)))} of {len(named)}."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "time_offset.json")
    args = parser.parse_args()
    flights = sorted(p.name for p in (paths.data_dir() / "flights").iterdir())
    with Pool(2) as pool:
        rows = pool.map(offsets, flights, chunksize=1)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rows, indent=1) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
