"""What loads an untouched real flight's lever arm beyond the airframe (descriptive; it
decides nothing).

    .venv/bin/python benchmarks/lever_arm_loads.py [--flights 0426-traj1 ...] [--json out/lever_arm_loads.json]

`rig diagnose` fits every shared flight a lever arm of 0.2–1 m, beyond the airframe's
0.15 m, so it reports it as not explained (docs/notebook/diagnosis.md). This script
fits each flight's TDOA error (measured less predicted along the ground truth and the
survey; |error| < 1 m, the tag above 0.3 m) by plain least squares. Each model has a
delay per anchor and a lever arm, and adds in turn:
- `link`: the calibrated link bias (rig.sim.effects.link; the anchors turned as
  surveyed), with one gain;
- `kind`: sin(el_t) for the ceiling anchors and for the floor ones, each with its own
  coefficient; el_t is the anchor's elevation seen from the tag.
It prints the lever arm under each model. For the first model it also prints:
- how much of the lever arm's columns the delays explain (`delays_explain`);
- the lever arm fitted without delays (`without_delays`);
- the lever arm's standard error two ways. `se_white_m` treats the samples as
  independent. `se_blocks_m` sums the fit's scores over BLOCK_S blocks first, since
  most of the TDOA error varies slowly.
Over the flights it prints, per model, how many fit the lever arm beyond the
airframe, the gain's range and the per-kind coefficients by day.
It is a quick look and runs in seconds: the diagnosis fits with Huber weights, priors
and many more candidates.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.sim.effects import link  # noqa: E402
from rig.sim.effects.world import LeverArm  # noqa: E402
from rig.sim.simulate import Predictor  # noqa: E402

FLIGHTS = ["0426-traj1", "0426-traj3", "0426-traj5", "0426-traj8", "0425-traj1", "0425-traj9", "0425-traj21",
           "0422-log01"]
MODELS = {"base": [], "link": ["link"], "link+kind": ["link", "kind"]}
CEILING_Z_M = 1.5           # an anchor above this height is a ceiling anchor
MAX_ERROR_M = 1.0
MIN_HEIGHT_M = 0.3
AIRFRAME_M = LeverArm.bounds["offset_m"]      # the catalog's bound on a lever arm's component
BLOCK_S = 0.5               # the TDOA error's slow part varies over about this (issue 58)


def link_columns(position: np.ndarray, rotation, anchors: np.ndarray, frames: np.ndarray) -> dict[str, np.ndarray]:
    """Per link (tag at `position`, anchor at `anchors` turned by `frames`, anchor → world
    matrices as surveyed): the range's derivative by the
    lever arm (body frame), the calibrated link bias, and sin(el_t) by anchor kind."""
    to_anchor = anchors - position
    distance = np.linalg.norm(to_anchor, axis=1)
    unit = to_anchor / distance[:, None]
    lever = np.stack([-np.einsum("ni,ni->n", unit, rotation.apply(np.tile(e, (len(position), 1))))
                      for e in np.eye(3)], axis=1)
    bias = link.link_basis(position, rotation, anchors, frames) @ np.asarray(link.calibrated_link_bias())
    sin_el = rotation.inv().apply(to_anchor)[:, 2] / distance
    ceiling = anchors[:, 2] > CEILING_Z_M
    return {"lever": lever, "link": bias[:, None], "kind": np.column_stack([sin_el * ceiling, sin_el * ~ceiling])}


@dataclass
class FlightLinks:
    """A flight's TDOA errors (measured less predicted along the ground truth and the
    survey) that the fits use, with the tag's pose and the two anchors of each."""
    error: np.ndarray
    position: np.ndarray
    rotation: Rotation
    id_a: np.ndarray
    id_b: np.ndarray
    anchors: dict[int, np.ndarray]
    frames: dict[int, np.ndarray]           # each anchor's rotation matrix, anchor → world, as surveyed
    t: np.ndarray

    def anchor_positions(self, ids: np.ndarray) -> np.ndarray:
        return np.array([self.anchors[int(k)] for k in ids])

    def anchor_frames(self, ids: np.ndarray) -> np.ndarray:
        return np.array([self.frames[int(k)] for k in ids])

    def delays(self) -> np.ndarray:
        """One column per anchor: the TDOA's derivative by its delay."""
        return np.column_stack([(self.id_b == k).astype(float) - (self.id_a == k) for k in sorted(self.anchors)])


def flight_links(flight: str) -> FlightLinks:
    """The samples with both anchors surveyed, |error| < MAX_ERROR_M, the tag above MIN_HEIGHT_M."""
    rec = load_any(paths.data_dir() / "flights" / flight)
    predicted = Predictor(rec).tdoa([])
    error = rec.tdoa.distance_diff - predicted.value
    positions = {int(a.id): np.array(a.position) for a in rec.anchors}
    known = np.array([int(a) in positions and int(b) in positions for a, b in zip(predicted.id_a, predicted.id_b)])
    keep = known & np.isfinite(error) & (np.abs(error) < MAX_ERROR_M) & (predicted.tag_position[:, 2] > MIN_HEIGHT_M)
    frames = {int(a.id): a.rotation.as_matrix() for a in rec.anchors}
    return FlightLinks(error[keep], predicted.tag_position[keep], predicted.tag_rotation[keep], predicted.id_a[keep],
                       predicted.id_b[keep], positions, frames, rec.tdoa.t[keep])


def flight_problem(flight: str) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """The TDOA error, the delays' columns, the other columns (each link B's less link
    A's) and the samples' times."""
    links = flight_links(flight)
    side_a = link_columns(links.position, links.rotation, links.anchor_positions(links.id_a), links.anchor_frames(links.id_a))
    side_b = link_columns(links.position, links.rotation, links.anchor_positions(links.id_b), links.anchor_frames(links.id_b))
    return links.error, links.delays(), {name: side_b[name] - side_a[name] for name in side_a}, links.t


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


def standard_errors(design: np.ndarray, residual: np.ndarray, t: np.ndarray,
                    block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Each least-squares coefficient's standard error with independent samples, and
    with the fit's scores summed over `block_s` blocks first (a sandwich), which counts
    an error that varies slowly."""
    bread = np.linalg.pinv(design.T @ design)
    block = np.floor((t - t[0]) / block_s).astype(int)
    summed = np.zeros((block.max() + 1, design.shape[1]))
    np.add.at(summed, block, design * residual[:, None])
    return np.sqrt(np.diag(bread) * np.var(residual)), np.sqrt(np.diag(bread @ (summed.T @ summed) @ bread))


def lever_arm_conditioning(error: np.ndarray, delays: np.ndarray, lever: np.ndarray, t: np.ndarray) -> dict:
    """How far the delays leave the lever arm its own signal, and its standard error with
    independent samples and with the scores summed over BLOCK_S blocks (a sandwich)."""
    design = np.column_stack([delays, lever])
    coef, *_ = np.linalg.lstsq(design, error, rcond=None)
    white, blocks = (se[-3:] for se in standard_errors(design, error - design @ coef, t, BLOCK_S))
    explained = lever - delays @ np.linalg.lstsq(delays, lever, rcond=None)[0]
    alone, *_ = np.linalg.lstsq(lever, error - error.mean(), rcond=None)
    return {"delays_explain": np.round(1 - explained.var(axis=0) / lever.var(axis=0), 3).tolist(),
            "without_delays": np.round(alone, 3).tolist(), "se_white_m": np.round(white, 3).tolist(),
            "se_blocks_m": np.round(blocks, 3).tolist()}


def summary(results: dict[str, dict]) -> dict:
    """Over the flights, per model: how many fit the lever arm beyond the airframe
    vertically and horizontally (a component beyond AIRFRAME_M, as the catalog bounds it), the range of the link bias's gain, and the median
    coefficients by anchor kind (ceiling, floor) per day."""
    out = {}
    for model in MODELS:
        levers = np.array([results[f][model]["lever"] for f in results])
        entry = {"flights": len(levers), "z_beyond": int(np.sum(np.abs(levers[:, 2]) > AIRFRAME_M)),
                 "horizontal_beyond": int(np.sum(np.max(np.abs(levers[:, :2]), axis=1) > AIRFRAME_M))}
        if "link" in MODELS[model]:
            gains = [results[f][model]["link"][0] for f in results]
            entry["link_gain_range"] = [min(gains), max(gains)]
        if "kind" in MODELS[model]:
            entry["kind_median_by_day"] = {
                day: np.round(np.median([results[f][model]["kind"] for f in results if f.startswith(day)], axis=0),
                              3).tolist() for day in sorted({f[:4] for f in results})}
        out[model] = entry
    return out


def write_results(results: dict, overall: dict, path: Path) -> None:
    """Print the summary a line per model and write it with every flight's fits as JSON."""
    for model, entry in overall.items():
        print(f"{model:22s} " + ", ".join(f"{k} {v}" for k, v in entry.items()))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"summary": overall, "flights": results}, indent=1) + "\n")
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", nargs="+", default=FLIGHTS)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "lever_arm_loads.json")
    args = parser.parse_args()
    results = {}
    for flight in args.flights:
        error, delays, columns, t = flight_problem(flight)
        results[flight] = {name: fit(error, delays, columns, extra) for name, extra in MODELS.items()}
        results[flight]["base"].update(lever_arm_conditioning(error, delays, columns["lever"], t))
        cells = [f"{name}: lever {fitted['lever']}"
                 + "".join(f" {n} {fitted[n]}" for n in MODELS[name]) for name, fitted in results[flight].items()]
        base = results[flight]["base"]
        print(f"{flight:12s} " + " | ".join(cells) + f" || delays explain {base['delays_explain']}, without delays "
              f"{base['without_delays']}, se white {base['se_white_m']}, se blocks {base['se_blocks_m']}", flush=True)
    write_results(results, summary(results), args.json)


if __name__ == "__main__":
    main()
