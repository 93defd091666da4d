"""What shape the bias has that `rig diagnose` names as anchors displaced by metres
(descriptive; it decides nothing).

    .venv/bin/python benchmarks/anchor_shapes.py [--flights 0426-traj1 ...] [--json out/anchor_shapes.json]   # 3 minutes for the 35

On the shared flights, where every anchor stands where it was surveyed, the diagnosis
names displacements of 1.6 m (median; benchmarks/richer_sizes.py), beyond the
catalog's 1 m. Two shapes could stand for them with physically bounded parameters:
- `anchor_gain`: each anchor's own gain on the calibrated link-bias shape
  (rig.sim.effects.link) in place of the shared one: the per-anchor deviation from
  the shared shape that the issue asks for; 1 parameter an anchor, bounded as the
  shared gain is (not negative, the largest bias it makes within LINK_BOUND_M);
- `tag_azimuth`: the tag's antenna and airframe seen from the anchor's azimuth in the
  tag's body frame (harmonics 2–4, weighted by cos^h of the elevation; the first is
  the lever arm), shared by all anchors; the calibrated shape has only the elevation.

Each flight's TDOA error (lever_arm_loads.flight_links: measured less predicted along
the ground truth and the survey; |error| < 1 m, the tag above 0.3 m) is fitted by
plain least squares with a delay per anchor, the lever arm and the calibrated link
bias's gain (`base`), then with each shape, with displacements (3 an anchor), and with
both. Printed per flight and model: the residual's standard deviation, the
displacements' median size and how many exceed the catalog's bound, and the
anchors' gains and how many are beyond their bound. If a shape stood for the displacements, adding it would shrink them.
Plain least squares on samples that are not independent: the diagnosis fits with
Huber weights, priors and standard errors that count the slow error, so its sizes
are smaller, but a shape that takes nothing from the displacements here will not there.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import lever_arm_loads  # noqa: E402  - the flights' TDOA errors, the lever arm's columns
from rig.data import paths  # noqa: E402
from rig.sim.effects import link  # noqa: E402
from rig.sim.effects.world import AnchorPosition  # noqa: E402

# Each model's columns besides the delays and the lever arm. The anchors' own gains
# replace the shared one: their columns sum to its column.
MODELS = {"base": ["link"], "displaced": ["link", "displaced"], "anchor_gain": ["anchor_gain"],
          "displaced+anchor_gain": ["displaced", "anchor_gain"], "tag_azimuth": ["link", "tag_azimuth"],
          "displaced+tag_azimuth": ["link", "displaced", "tag_azimuth"]}
HARMONICS = (2, 3, 4)
DISPLACEMENT_BOUND_M = AnchorPosition.bounds["offset_m"]
# the blocks the standard errors sum scores over: the width of the kernel that counts
# the slow TDOA error in the diagnosis's standard errors (docs/notebook/diagnosis.md)
SE_BLOCK_S = 2.0
INSIDE_OUT_M = 0.01      # a gain below zero by less than a centimetre of bias is zero


def side_columns(links: lever_arm_loads.FlightLinks, ids: np.ndarray, coeffs: np.ndarray) -> dict[str, np.ndarray]:
    """One link of each TDOA (its anchors `ids`): the range's derivative by the anchor's
    position (the unit vector to it) and by the lever arm, the calibrated link bias (the
    anchors turned as surveyed) and the tag-azimuth harmonics."""
    anchors, frames = links.anchor_positions(ids), links.anchor_frames(ids)
    to_anchor = anchors - links.position
    azimuth, elevation = link.direction_angles(links.rotation.inv().apply(to_anchor))
    return {"unit": to_anchor / np.linalg.norm(to_anchor, axis=1)[:, None],
            "lever": lever_arm_loads.link_columns(links.position, links.rotation, anchors, frames)["lever"],
            "bias": link.link_basis(links.position, links.rotation, anchors, frames) @ coeffs,
            "harmonics": np.column_stack([f(h * azimuth) * np.cos(elevation) ** h
                                          for h in HARMONICS for f in (np.cos, np.sin)])}


def columns(links: lever_arm_loads.FlightLinks, coeffs: np.ndarray) -> dict[str, np.ndarray]:
    """Every model's columns, each TDOA's link B less its link A."""
    a, b = side_columns(links, links.id_a, coeffs), side_columns(links, links.id_b, coeffs)
    on_a = {k: links.id_a == k for k in sorted(links.anchors)}
    on_b = {k: links.id_b == k for k in sorted(links.anchors)}
    return {"delay": links.delays(), "lever": b["lever"] - a["lever"], "link": (b["bias"] - a["bias"])[:, None],
            "displaced": np.column_stack([b["unit"][:, j] * on_b[k] - a["unit"][:, j] * on_a[k]
                                          for k in on_a for j in range(3)]),
            "anchor_gain": np.column_stack([b["bias"] * on_b[k] - a["bias"] * on_a[k] for k in on_a]),
            "tag_azimuth": b["harmonics"] - a["harmonics"]}


def fit(links: lever_arm_loads.FlightLinks, cols: dict[str, np.ndarray],
        names: list[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], float]:
    """Least-squares coefficients of `names`' columns and their standard errors that
    count the slow error (scores summed over SE_BLOCK_S), by name; the residual's std."""
    design = np.column_stack([cols[n] for n in names])
    coef, *_ = np.linalg.lstsq(design, links.error, rcond=None)
    residual = links.error - design @ coef
    _, se = lever_arm_loads.standard_errors(design, residual, links.t, SE_BLOCK_S)
    widths = np.cumsum([0] + [cols[n].shape[1] for n in names])
    by_name = [slice(widths[i], widths[i + 1]) for i in range(len(names))]
    return ({n: coef[k] for n, k in zip(names, by_name)}, {n: se[k] for n, k in zip(names, by_name)},
            float(np.std(residual)))


def flight_shapes(links: lever_arm_loads.FlightLinks, coeffs: np.ndarray) -> dict:
    """Each model's residual, displacements and anchor gains on one flight."""
    cols = columns(links, coeffs)
    largest = float(np.max(np.abs(coeffs)))
    out = {}
    for model, extra in MODELS.items():
        fitted, se, residual = fit(links, cols, ["delay", "lever", *extra])
        row = {"residual_std_m": round(residual, 4), "lever_m": np.round(fitted["lever"], 3).tolist()}
        if "displaced" in fitted:
            sizes = np.linalg.norm(fitted["displaced"].reshape(-1, 3), axis=1)
            row["displacement_m"] = np.round(sizes, 3).tolist()
            row["displacement_vectors_m"] = np.round(fitted["displaced"].reshape(-1, 3), 3).tolist()
            row["displacement_se_m"] = np.round(np.linalg.norm(se["displaced"].reshape(-1, 3), axis=1), 3).tolist()
            row["displacements_beyond"] = int(np.sum(sizes > DISPLACEMENT_BOUND_M))
        if "anchor_gain" in fitted:
            gains = fitted["anchor_gain"]
            row["anchor_gain"] = np.round(gains, 3).tolist()
            row["anchor_gains_beyond"] = int(np.sum((np.abs(gains) * largest > link.LINK_BOUND_M)
                                                    | (gains * largest < -INSIDE_OUT_M)))
        if "tag_azimuth" in fitted:
            row["tag_azimuth_m"] = np.round(fitted["tag_azimuth"], 3).tolist()
        out[model] = row
    return out


def gain_agreement(gains: np.ndarray) -> dict:
    """Each anchor's gain (flights × anchors) over the flights: its median and the share
    of flights whose gain has the median's sign (do the flights agree on it?)."""
    median = np.median(gains, axis=0)
    return {"anchor_gain_median": np.round(median, 2).tolist(),
            "anchor_gain_sign_agreement": np.round(np.mean(np.sign(gains) == np.sign(median), axis=0), 2).tolist()}


def displacement_stability(results: dict[str, dict]) -> dict:
    """Per day, how much of a flight's displacements the day's other flights foretell:
    the squared norm of a flight's displacement vectors less the mean of the others',
    over its own (`left`, median over the day's flights; 0: the same on every flight,
    1: no better than none). A per-installation field of the anchors would have to be
    this stable to be calibrated away. `left_by_their_noise`: what would be left if
    every flight fitted one field and differed only by its fits' standard errors
    (its own and the mean's), the same ratio."""
    out = {}
    for day in sorted({f[:4] for f in results}):
        rows = [results[f]["displaced"] for f in results if f.startswith(day)]
        if len(rows) < 2:
            continue
        vectors = np.array([r["displacement_vectors_m"] for r in rows])
        variance = np.array([np.sum(np.square(r["displacement_se_m"])) for r in rows])
        n = len(rows)
        left = [np.sum((v - np.delete(vectors, i, axis=0).mean(axis=0)) ** 2) / np.sum(v ** 2)
                for i, v in enumerate(vectors)]
        noise = [(variance[i] + np.delete(variance, i).mean() / (n - 1)) / np.sum(v ** 2) for i, v in enumerate(vectors)]
        out[day] = {"left": round(float(np.median(left)), 2), "left_by_their_noise": round(float(np.median(noise)), 2)}
    return out


def summary(results: dict[str, dict]) -> dict:
    """Per model, over the flights: the median residual, the median displacement and the
    share of displacements and anchor gains beyond their bounds; how stable the
    displacements are within a day."""
    out = {}
    for model in MODELS:
        rows = [r[model] for r in results.values()]
        entry = {"residual_std_m": round(float(np.median([r["residual_std_m"] for r in rows])), 4)}
        if "displacement_m" in rows[0]:
            sizes = np.concatenate([r["displacement_m"] for r in rows])
            entry["displacement_median_m"] = round(float(np.median(sizes)), 3)
            entry["displacements_beyond"] = f"{sum(r['displacements_beyond'] for r in rows)} of {len(sizes)}"
            if model == "displaced":
                entry["left_by_the_days_other_flights"] = displacement_stability(results)
        if "anchor_gain" in rows[0]:
            count = sum(len(r["anchor_gain"]) for r in rows)
            entry["anchor_gains_beyond"] = f"{sum(r['anchor_gains_beyond'] for r in rows)} of {count}"
            if model == "anchor_gain":
                entry.update(gain_agreement(np.array([r["anchor_gain"] for r in rows])))
        out[model] = entry
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", nargs="+", help="default: every shared flight")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "anchor_shapes.json")
    args = parser.parse_args()
    flights = args.flights or [p.name for p in paths.flights()]
    coeffs = np.asarray(link.calibrated_link_bias())
    results = {}
    for flight in flights:
        results[flight] = flight_shapes(lever_arm_loads.flight_links(flight), coeffs)
        print(f"{flight:12s} " + " | ".join(
            f"{model} {row['residual_std_m']:.4f}"
            + (f" disp median {np.median(row['displacement_m']):.2f} m" if "displacement_m" in row else "")
            + (f" gains {row['anchor_gain']}" if "anchor_gain" in row else "")
            for model, row in results[flight].items()), flush=True)
    lever_arm_loads.write_results(results, summary(results), args.json)


if __name__ == "__main__":
    main()
