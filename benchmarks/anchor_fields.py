"""Each anchor's range bias around the circle, per flight and per day: what changed on a
day the correction does not carry to (docs/notebook/bias.md, "Anchor delays per
installation").

    .venv/bin/python benchmarks/anchor_fields.py [--out out/anchor_fields.json]     # seconds

Every shared flight circles the origin. Per flight, each anchor k's range bias is fitted
as a function of the tag's bearing θ about the origin, β_k(θ) = d_k + Σ_h a_kh cos hθ +
b_kh sin hθ (h = 1, 2), to the TDOA errors, TDOA = β_B − β_A, by least squares. Printed
per anchor and day: the amplitude and phase of the first harmonic and the amplitude of
the second, of the day's mean field; and how each day's flights' fields project on the
mean field of the 0425 and 0426 flights (slope 1: the same bias; 0: none of it).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.bias.train import load_or_build_dataset  # noqa: E402
from rig.data import paths  # noqa: E402
from rig.data.files import write_json  # noqa: E402
from rig.data.survey import parse_survey  # noqa: E402

CACHE = ROOT / "out" / "cache" / "all.npz"
HARMONICS = 2
ANCHORS = 8
DAYS = ("0422", "0425", "0426")
REFERENCE_DAYS = ("0425", "0426")
GRID = np.linspace(-np.pi, np.pi, 72, endpoint=False)


def basis(theta: np.ndarray) -> np.ndarray:
    """A constant and HARMONICS harmonics of the bearing, as columns."""
    return np.column_stack([np.ones_like(theta)] + [f(h * theta) for h in range(1, HARMONICS + 1)
                                                    for f in (np.cos, np.sin)])


def flight_fields(samples, surveys: dict) -> dict[str, np.ndarray]:
    """Per flight, each anchor's fitted coefficients (ANCHORS, 1 + 2 HARMONICS)."""
    out = {}
    width = 1 + 2 * HARMONICS
    for name in sorted(set(samples.flight.tolist())):
        rows = samples.flight == name
        ia, ib = samples.id_a[rows].astype(int), samples.id_b[rows].astype(int)
        anchors = surveys[name.split("-")[0]]
        tag = np.array([anchors[k] for k in ia]) - samples.features[rows][:, 0:3]
        columns = basis(np.arctan2(tag[:, 1], tag[:, 0]))
        design = np.zeros((rows.sum(), ANCHORS * width))
        for k in range(ANCHORS):
            design[:, k * width:(k + 1) * width] += columns * (ib == k)[:, None] - columns * (ia == k)[:, None]
        out[name] = np.linalg.lstsq(design, samples.label[rows], rcond=None)[0].reshape(ANCHORS, width)
    return out


def varying(coeffs: np.ndarray) -> np.ndarray:
    """The fields on the bearing grid without their constants (the delays): (grid, ANCHORS)."""
    return basis(GRID)[:, 1:] @ coeffs[:, 1:].T


def summary(fields: dict[str, np.ndarray]) -> dict:
    names = sorted(fields)
    reference = np.mean([varying(fields[n]) for n in names if n.startswith(REFERENCE_DAYS)], axis=0)
    out = {}
    for k in range(ANCHORS):
        per_day = {}
        for day in DAYS:
            mine = [n for n in names if n.startswith(day)]
            mean = np.mean([fields[n][k] for n in mine], axis=0)
            slopes = [float(varying(fields[n])[:, k] @ reference[:, k] / (reference[:, k] @ reference[:, k]))
                      for n in mine]
            per_day[day] = {"first_harmonic_m": float(np.hypot(mean[1], mean[2])),
                            "first_harmonic_phase_deg": float(np.degrees(np.arctan2(mean[2], mean[1]))),
                            "second_harmonic_m": float(np.hypot(mean[3], mean[4])),
                            "slope_on_reference_median": float(np.median(slopes)), "flights": len(mine)}
        out[str(k)] = per_day
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "anchor_fields.json")
    args = parser.parse_args()
    samples = load_or_build_dataset(paths.flights(), CACHE)[0]
    surveys = {day: {a.id: np.asarray(a.position, float) for a in parse_survey(paths.data_dir() / "surveys" /
                                                                             f"anchor_{day}.txt")} for day in DAYS}
    result = summary(flight_fields(samples, surveys))
    print("anchor | day | first harmonic (m, phase) | second (m) | slope on the 0425+0426 field (median)")
    for k, days in result.items():
        for day, f in days.items():
            print(f"{k} | {day} | {f['first_harmonic_m']:.3f} at {f['first_harmonic_phase_deg']:+.0f}° | "
                  f"{f['second_harmonic_m']:.3f} | {f['slope_on_reference_median']:.2f}")
    write_json(args.out, result)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
