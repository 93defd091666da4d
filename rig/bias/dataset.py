"""Training data for the TDOA bias network: features and labels of every in-flight
TDOA measurement of real flights.

Features are computed by the C estimator's own `bn_features` (through the native
library) with the surveyed anchor poses, so training and the onboard inference share
one definition. The tag's pose they use is, by default, the estimator's own: a
replay of the flight without correction, read at each measurement's time. In flight
the network sees the estimated pose, whose error is of the size of the bias field's
structure and caused by the bias itself: features from the ground truth teach it a
function it is never asked for (`FEATURES_FROM`: "estimate" or "truth"). The label
is measured − true TDOA, from the ground truth.

The ground truth (`estPose`, the motion-capture pose radioed to the drone) is
stamped with the drone's clock on arrival, so it lags the true motion. The lag is
estimated per flight as the shift of the ground truth that makes the TDOA errors
most consistent (smallest robust spread after removing each anchor pair's median);
labels use the shifted ground truth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields
from pathlib import Path
from typing import BinaryIO

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from rig.bias.config import FEATURES_FROM, RECIPE_ESTIMATOR
from rig.data.recording import PoseSeries, Recording
from rig.estimator import metrics, native
from rig.sim.effects import World

log = logging.getLogger(__name__)

MAX_ABS_ERROR_M = 1.0      # larger errors are outliers: the robust update's job, not the network's
LATENCY_GRID_S = np.arange(-0.2, 0.2001, 0.005)
FLIGHT_RULE = metrics.SegmentRule(min_height=0.3, skip_after_takeoff=0.0)


@dataclass
class Samples:
    """One row per TDOA measurement."""

    features: np.ndarray   # (n, 14) float32, from the C feature code
    label: np.ndarray      # (n,) measured - true TDOA (m)
    flight: np.ndarray     # (n,) flight name
    id_a: np.ndarray
    id_b: np.ndarray
    t: np.ndarray          # measurement time on the recording's clock (s)

    def __len__(self) -> int:
        return len(self.label)

    def select(self, mask: np.ndarray) -> "Samples":
        return Samples(*(getattr(self, f.name)[mask] for f in fields(self)))

    @classmethod
    def concatenate(cls, parts: list["Samples"]) -> "Samples":
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))

    def save(self, path: Path | BinaryIO) -> None:
        np.savez_compressed(path, **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load(cls, path: Path) -> "Samples":
        with np.load(path) as data:
            return cls(*(data[f.name] for f in fields(cls)))


def true_tdoa(position: np.ndarray, a_pos: np.ndarray, b_pos: np.ndarray) -> np.ndarray:
    return np.linalg.norm(position - b_pos, axis=1) - np.linalg.norm(position - a_pos, axis=1)


def known_pairs(rec: Recording) -> np.ndarray:
    """Measurements between two different surveyed anchors."""
    d = rec.tdoa
    return World.surveyed(rec.anchors).known_pairs(d.id_a, d.id_b) & (d.id_a != d.id_b)


def airborne_tdoa(rec: Recording) -> np.ndarray:
    start, end = metrics.flight_window(rec.truth, FLIGHT_RULE)
    t = rec.tdoa.t
    return (t >= start) & (t <= end) & known_pairs(rec) & np.isfinite(rec.tdoa.distance_diff)


def _errors(rec: Recording, sel: np.ndarray, latency: float, a_pos: np.ndarray, b_pos: np.ndarray) -> np.ndarray:
    position = metrics.interpolate_positions(rec.truth, rec.tdoa.t[sel] + latency)
    return rec.tdoa.distance_diff[sel] - true_tdoa(position, a_pos, b_pos)


def _consistency(err: np.ndarray, pair: np.ndarray) -> float:
    """Robust spread of the errors after removing each pair's median (outliers excluded)."""
    keep = np.abs(err) < MAX_ABS_ERROR_M
    err, pair = err[keep], pair[keep]
    centred = np.empty_like(err)
    for p in np.unique(pair):
        m = pair == p
        centred[m] = err[m] - np.median(err[m])
    return float(np.median(np.abs(centred)))


def truth_latency(rec: Recording, grid: np.ndarray = LATENCY_GRID_S) -> float:
    """Seconds by which the ground truth lags the drone's clock (best on `grid`)."""
    sel = airborne_tdoa(rec)
    if sel.sum() < 100:
        return 0.0
    world = World.surveyed(rec.anchors)
    (a_pos, _), (b_pos, _) = world.anchor_poses(rec.tdoa.id_a[sel]), world.anchor_poses(rec.tdoa.id_b[sel])
    pair = rec.tdoa.id_a[sel] * 256 + rec.tdoa.id_b[sel]
    spread = [_consistency(_errors(rec, sel, lag, a_pos, b_pos), pair) for lag in grid]
    return float(grid[int(np.argmin(spread))])


def tag_rotations(truth: PoseSeries, t: np.ndarray) -> np.ndarray:
    times, keep = np.unique(truth.t, return_index=True)
    slerp = Slerp(times, Rotation.from_quat(truth.quaternion[keep]))
    return slerp(np.clip(t, times[0], times[-1])).as_matrix()


def estimated_poses(rec: Recording, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The robust estimator's position and rotation matrix at times `t`, from a replay of
    `rec` without bias correction (what the network's input is computed from in flight), as
    the recipe replays it (RECIPE_ESTIMATOR)."""
    from rig.estimator.evaluate import estimator_config, replay

    run = replay(rec, *estimator_config(robust=True, use_nn=False, **RECIPE_ESTIMATOR))
    estimate = PoseSeries(run.t, run.position, run.outputs["quat"].astype(float))
    return metrics.interpolate_positions(estimate, t), tag_rotations(estimate, t)


def measurement_features(rec: Recording, sel: np.ndarray, latency: float, features_from: str = "estimate"
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 14 features of the selected TDOA rows (known anchors), with the true tag
    position (ground truth read `latency` later) and both anchors' positions. The
    features' tag pose is the estimator's (`features_from="estimate"`) or the truth's."""
    if features_from not in FEATURES_FROM:
        raise ValueError(f"features_from must be one of {FEATURES_FROM}, not {features_from!r}")
    world = World.surveyed(rec.anchors)
    (a_pos, a_rot), (b_pos, b_rot) = world.anchor_poses(rec.tdoa.id_a[sel]), world.anchor_poses(rec.tdoa.id_b[sel])
    t = rec.tdoa.t[sel]
    tag_pos = metrics.interpolate_positions(rec.truth, t + latency)
    if features_from == "truth":
        pos, rot = tag_pos, tag_rotations(rec.truth, t + latency)
    else:
        pos, rot = estimated_poses(rec, t)
    feats = native.features_batch(pos, rot, a_pos, a_rot, b_pos, b_rot)
    return feats, tag_pos, a_pos, b_pos


def flight_samples(rec: Recording, name: str, latency: float | None = None,
                   features_from: str = "estimate") -> Samples:
    """Every in-flight TDOA measurement of `rec` with |error| <= MAX_ABS_ERROR_M."""
    if latency is None:
        latency = truth_latency(rec)
    sel = airborne_tdoa(rec)
    id_a, id_b, t = rec.tdoa.id_a[sel], rec.tdoa.id_b[sel], rec.tdoa.t[sel]
    feats, tag_pos, a_pos, b_pos = measurement_features(rec, sel, latency, features_from)
    label = rec.tdoa.distance_diff[sel] - true_tdoa(tag_pos, a_pos, b_pos)
    keep = np.abs(label) <= MAX_ABS_ERROR_M
    log.info("%s: %d samples (%d outliers dropped), ground-truth latency %.0f ms", name, keep.sum(),
             (~keep).sum(), latency * 1e3)
    return Samples(feats, label, np.full(len(label), name), id_a, id_b, t).select(keep)


def shared_flight_samples(flight: Path, features_from: str = "estimate") -> tuple[Samples, float]:
    """Samples of one shared flight log, and its estimated ground-truth latency."""
    from rig.data.importer import load_any

    rec = load_any(flight)
    latency = truth_latency(rec)
    return flight_samples(rec, Path(flight).name, latency, features_from), latency


def build_dataset(flights: list[Path], workers: int = 2, progress=None, features_from: str = "estimate"
                  ) -> tuple[Samples, dict[str, float]]:
    """Samples of all `flights` (in parallel) and each flight's ground-truth latency."""
    from concurrent.futures import ProcessPoolExecutor

    flights = sorted(Path(f) for f in flights)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = pool.map(shared_flight_samples, flights, [features_from] * len(flights))
        results = list(progress(results) if progress else results)
    latency = {f.name: lat for f, (_, lat) in zip(flights, results)}
    return Samples.concatenate([s for s, _ in results]), latency
