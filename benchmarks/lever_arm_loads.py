"""What loads an untouched real flight's lever arm beyond the airframe (descriptive; it
decides nothing).

    .venv/bin/python benchmarks/lever_arm_loads.py [--flights 0426-traj1 ...] [--json out/lever_arm_loads.json]

`rig diagnose` fits every shared flight a lever arm of 0.2–1 m, beyond the airframe's
0.15 m, so it reports it as not explained (docs/notebook/diagnosis.md). This script
fits each flight's TDOA error (measured less predicted along the ground truth and the
survey; |error| < 1 m, the tag above 0.3 m) by plain least squares. Each model has a
delay per anchor and a lever arm, and adds in turn:
- `link`: the calibrated link bias (rig.sim.effects.link), with one gain;
- `kind`: sin(el_t) for the ceiling anchors and for the floor ones, each with its own
  coefficient; el_t is the anchor's elevation seen from the tag.
It prints the lever arm under each model. It is a quick look and runs in seconds: the
diagnosis fits with Huber weights, priors and many more candidates.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.sim.effects import link  # noqa: E402
from rig.sim.simulate import Predictor  # noqa: E402

FLIGHTS = ["0426-traj1", "0426-traj3", "0426-traj5", "0426-traj8", "0425-traj1", "0425-traj9", "0425-traj21",
           "0422-log01"]
MODELS = {"base": [], "link": ["link"], "link+kind": ["link", "kind"]}
CEILING_Z_M = 1.5           # an anchor above this height is a ceiling anchor
MAX_ERROR_M = 1.0
MIN_HEIGHT_M = 0.3


def link_columns(position: np.ndarray, rotation, anchors: np.ndarray) -> dict[str, np.ndarray]:
    """Per link (tag at `position`, anchor at `anchors`): the range's derivative by the
    lever arm (body frame), the calibrated link bias, and sin(el_t) by anchor kind."""
    to_anchor = anchors - position
    distance = np.linalg.norm(to_anchor, axis=1)
    unit = to_anchor / distance[:, None]
    lever = np.stack([-np.einsum("ni,ni->n", unit, rotation.apply(np.tile(e, (len(position), 1))))
                      for e in np.eye(3)], axis=1)
    upright = np.broadcast_to(np.eye(3), (len(position), 3, 3))       # the shared flights' anchors face up
    bias = link.link_basis(position, rotation, anchors, upright) @ np.asarray(link.calibrated_link_bias())
    sin_el = rotation.inv().apply(to_anchor)[:, 2] / distance
    ceiling = anchors[:, 2] > CEILING_Z_M
    return {"lever": lever, "link": bias[:, None], "kind": np.column_stack([sin_el * ceiling, sin_el * ~ceiling])}


def flight_problem(flight: str) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The TDOA error, the delays' columns and the other columns (each link B's less link A's)."""
    rec = load_any(paths.data_dir() / "flights" / flight)
    predicted = Predictor(rec).tdoa([])
    error = rec.tdoa.distance_diff - predicted.value
    positions = {a.id: np.array(a.position) for a in rec.anchors}
    known = np.array([int(a) in positions and int(b) in positions for a, b in zip(predicted.id_a, predicted.id_b)])
    keep = known & np.isfinite(error) & (np.abs(error) < MAX_ERROR_M) & (predicted.tag_position[:, 2] > MIN_HEIGHT_M)
    position, rotation = predicted.tag_position[keep], predicted.tag_rotation[keep]
    id_a, id_b = predicted.id_a[keep], predicted.id_b[keep]
    side_a = link_columns(position, rotation, np.array([positions[int(k)] for k in id_a]))
    side_b = link_columns(position, rotation, np.array([positions[int(k)] for k in id_b]))
    delays = np.column_stack([(id_b == k).astype(float) - (id_a == k) for k in sorted(positions)])
    return error[keep], delays, {name: side_b[name] - side_a[name] for name in side_a}


def fit(error: np.ndarray, delays: np.ndarray, columns: dict[str, np.ndarray], extra: list[str]) -> dict:
    names = ["lever", *extra]
    design = np.column_stack([delays] + [columns[n] for n in names])
    coef, *_ = np.linalg.lstsq(design, error, rcond=None)
    out, start = {}, delays.shape[1]
    for name in names:
        width = columns[name].shape[1]
        out[name] = np.round(coef[start:start + width], 3).tolist()
        start += width
    out["residual_std_m"] = round(float(np.std(error - design @ coef)), 4)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", nargs="+", default=FLIGHTS)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "lever_arm_loads.json")
    args = parser.parse_args()
    results = {}
    for flight in args.flights:
        error, delays, columns = flight_problem(flight)
        results[flight] = {name: fit(error, delays, columns, extra) for name, extra in MODELS.items()}
        cells = [f"{name}: lever {fitted['lever']}"
                 + "".join(f" {n} {fitted[n]}" for n in MODELS[name]) for name, fitted in results[flight].items()]
        print(f"{flight:12s} " + " | ".join(cells), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
