"""Accuracy metrics: align an estimate stream with ground truth, pick the flight
segment, report RMSE and error percentiles, plot trajectory and error."""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rig.data.errors import InputError
from rig.data.recording import PoseSeries

log = logging.getLogger(__name__)


@dataclass
class SegmentRule:
    """Which part of a flight is scored: ground truth above `min_height`, from
    `skip_after_takeoff` seconds after take-off (the first time above it) until
    landing (the last time above it)."""

    min_height: float = 0.3
    skip_after_takeoff: float = 5.0


class MetricsError(InputError):
    """Not enough overlap between estimates and ground truth to score anything."""


def _airborne(truth: PoseSeries, rule: SegmentRule) -> np.ndarray:
    if len(truth) == 0:
        raise MetricsError("the recording has no ground truth: nothing to score against")
    airborne = truth.position[:, 2] > rule.min_height
    if not airborne.any():
        raise MetricsError(f"ground truth never rises above {rule.min_height} m: no flight to score")
    return airborne


def takeoff_time(truth: PoseSeries, rule: SegmentRule = SegmentRule()) -> float:
    """The first ground-truth time above `rule.min_height`."""
    return float(truth.t[np.argmax(_airborne(truth, rule))])


def flight_window(truth: PoseSeries, rule: SegmentRule) -> tuple[float, float]:
    """Start and end time of the scored segment."""
    airborne = _airborne(truth, rule)
    takeoff = truth.t[np.argmax(airborne)]
    landing = truth.t[len(airborne) - 1 - np.argmax(airborne[::-1])]
    start = takeoff + rule.skip_after_takeoff
    if start >= landing:
        raise MetricsError("flight shorter than the take-off margin: no segment to score")
    return float(start), float(landing)


def interpolate(t: np.ndarray, ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each column of `values` (sampled at `ts`) linearly interpolated at `t`."""
    return np.column_stack([np.interp(t, ts, values[:, i]) for i in range(values.shape[1])])


def interpolate_positions(truth: PoseSeries, t: np.ndarray) -> np.ndarray:
    return interpolate(t, truth.t, truth.position)


@dataclass
class Alignment:
    """Estimates and interpolated ground truth on the scored segment."""

    t: np.ndarray
    estimate: np.ndarray
    truth: np.ndarray

    @property
    def error(self) -> np.ndarray:
        return self.estimate - self.truth


def align(t: np.ndarray, position: np.ndarray, truth: PoseSeries, rule: SegmentRule = SegmentRule()) -> Alignment:
    """Interpolate ground truth at the estimate times, keep the scored segment."""
    t = np.asarray(t, float)
    position = np.asarray(position, float)
    start, end = flight_window(truth, rule)
    inside = (t >= start) & (t <= end) & (t >= truth.t[0]) & (t <= truth.t[-1])
    if not inside.any():
        raise MetricsError(f"no estimate inside the scored segment [{start:.2f}, {end:.2f}] s")
    t_in = t[inside]
    est = position[inside]
    z = np.interp(t_in, truth.t, truth.position[:, 2])
    keep = z > rule.min_height
    return Alignment(t_in[keep], est[keep], interpolate_positions(truth, t_in[keep]))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def accuracy(alignment: Alignment) -> dict:
    """RMSE (3D and per axis), max and percentiles of the 3D error, as plain JSON types.

    A non-finite estimate counts as an infinitely large error, so it cannot hide."""
    err = alignment.error
    norm = np.linalg.norm(err, axis=1)
    norm = np.where(np.isfinite(norm), norm, np.inf)
    finite = np.isfinite(norm)
    # with an infinite error among them, a percentile is an order statistic (interpolating
    # between two infinities is not a number)
    method = "linear" if finite.all() else "inverted_cdf"
    return {
        "rmse_3d": _rms(norm) if finite.all() else float("inf"),
        "rmse_xyz": [_rms(err[:, i]) if finite.all() else float("inf") for i in range(3)],
        "mean_xyz": [float(np.mean(err[:, i])) if finite.all() else float("nan") for i in range(3)],
        "max_3d": float(np.max(norm)),
        **{f"p{q}_3d": float(np.percentile(norm, q, method=method)) for q in (50, 90, 95, 99)},
        "n_scored": int(len(norm)),
        "n_not_finite": int((~finite).sum()),
        "segment_s": [float(alignment.t[0]), float(alignment.t[-1])] if len(alignment.t) else [],
    }


def score(t: np.ndarray, position: np.ndarray, truth: PoseSeries, rule: SegmentRule = SegmentRule()) -> dict:
    """The library entry point: metrics of an estimate stream against ground truth."""
    result = accuracy(align(t, position, truth, rule))
    result["segment_rule"] = asdict(rule)
    return result


def plot(t: np.ndarray, position: np.ndarray, truth: PoseSeries, path: Path,
         rule: SegmentRule = SegmentRule(), title: str = "") -> Path:
    """Top and side views of estimate against ground truth, and 3D error over time (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alignment = align(t, position, truth, rule)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    views = ((0, 1, "top view", "x [m]", "y [m]"), (0, 2, "side view", "x [m]", "z [m]"))
    for ax, (i, j, name, xl, yl) in zip(axes[:2], views):
        ax.plot(truth.position[:, i], truth.position[:, j], color="0.6", lw=1, label="ground truth")
        ax.plot(alignment.estimate[:, i], alignment.estimate[:, j], color="tab:blue", lw=0.8, label="estimate")
        ax.set(title=name, xlabel=xl, ylabel=yl)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(loc="upper right", fontsize=8)
    err = alignment.error
    axes[2].plot(alignment.t, np.linalg.norm(err, axis=1), color="k", lw=1, label="3D")
    for k, axis in enumerate("xyz"):
        axes[2].plot(alignment.t, err[:, k], lw=0.6, label=axis)
    axes[2].set(title="error over time (scored segment)", xlabel="t [s]", ylabel="error [m]")
    axes[2].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def read_estimates(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Estimates from a CSV (t,x,y,z with a header line) or from an MCAP `estimate` topic."""
    from rig.data.recording import read_topics

    if path.suffix == ".mcap":
        messages, _ = read_topics(path)
        topics = [t for t in messages if "estimate" in t]
        if not topics:
            raise InputError(f"{path} has no topic with 'estimate' in its name")
        msgs = messages[topics[0]]
        return (np.array([m["t"] for m in msgs], float),
                np.array([[m["position"][c] for c in "xyz"] for m in msgs], float))
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read estimates from {path}: {exc}") from exc
    if data.shape[1] < 4:
        raise InputError(f"{path}: expected columns t,x,y,z")
    return data[:, 0], data[:, 1:4]
