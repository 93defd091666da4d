"""How late the ground truth is against the IMU, measured on the gyroscope: the shift of
the motion capture's attitude rates that best matches the gyroscope's, per flight.

    .venv/bin/python benchmarks/truth_latency.py [--json out/truth_latency.json]

The ground truth (`estPose`) is radioed to the drone and stamped on arrival; the IMU is
stamped where it is sampled. The body rates of the ground truth's attitude (finite
differences of its attitude over 0.1 s intervals on a 10 ms grid, R(t)^T R(t + 0.1 s):
raw motion-capture steps are a few ms apart and their noise, differentiated, would
drown the rates) are compared with the gyroscope averaged over the same intervals, for
shifts of the ground truth from −150 to +150 ms in 1 ms
steps; the shift with the smallest median squared difference over the flight (tag above
0.3 m; the median is blind to the attitude's rare glitches) is that flight's latency. Unlike a TDOA-based estimate, no UWB bias enters: the
gyroscope and the attitude see the same rotation.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scipy.spatial.transform import Rotation  # noqa: E402

from rig.data import paths  # noqa: E402
from rig.data.importer import load_any  # noqa: E402
from rig.data.recording import Recording  # noqa: E402
from rig.estimator import metrics  # noqa: E402

SHIFTS_S = np.arange(-0.150, 0.1505, 0.001)
GRID_S, INTERVAL_S = 0.01, 0.1
RULE = metrics.SegmentRule(min_height=0.3, skip_after_takeoff=0.0)


def truth_rates(rec: Recording, start: float, end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interval starts and ends on a regular grid, and the ground truth's body rates over each (rad/s)."""
    from scipy.spatial.transform import Slerp

    t, keep = np.unique(rec.truth.t, return_index=True)
    slerp = Slerp(t, Rotation.from_quat(rec.truth.quaternion[keep]))
    starts = np.arange(max(start, t[0]), min(end, t[-1]) - INTERVAL_S, GRID_S)
    ends = starts + INTERVAL_S
    rates = (slerp(starts).inv() * slerp(ends)).as_rotvec() / INTERVAL_S
    return starts, ends, rates


def interval_means(t: np.ndarray, values: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The mean of `values` (sampled at `t`) over each [start, end), by cumulative sums."""
    cum = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    i0, i1 = np.searchsorted(t, start), np.searchsorted(t, end)
    n = np.maximum(i1 - i0, 1)[:, None]
    out = (cum[i1] - cum[i0]) / n
    out[i1 <= i0] = np.nan
    return out


def latency(rec: Recording) -> dict:
    """The shift of the ground truth (s, positive: it lags) that best matches the gyroscope."""
    window = metrics.flight_window(rec.truth, RULE)
    start, end, rates = truth_rates(rec, *window)
    cost = []
    for shift in SHIFTS_S:
        gyro = interval_means(rec.gyro.t, rec.gyro.xyz, start - shift, end - shift)
        ok = np.all(np.isfinite(gyro), axis=1)
        cost.append(np.median(np.sum((gyro[ok] - rates[ok]) ** 2, axis=1)))
    best = int(np.argmin(cost))
    return {"latency_s": float(SHIFTS_S[best]), "rms_rate_error_rps": float(np.sqrt(cost[best])),
            "rms_rate_error_at_zero_rps": float(np.sqrt(cost[int(np.argmin(np.abs(SHIFTS_S)))])),
            "intervals": int(len(start))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "truth_latency.json")
    args = parser.parse_args()
    results = {}
    for flight in paths.flights():
        results[flight.name] = latency(load_any(flight))
        r = results[flight.name]
        print(f"{flight.name:12s} ground truth late by {r['latency_s'] * 1e3:+5.0f} ms "
              f"(rate error {r['rms_rate_error_at_zero_rps']:.4f} -> {r['rms_rate_error_rps']:.4f} rad/s)")
    lat = np.array([r["latency_s"] for r in results.values()]) * 1e3
    print(f"all {len(lat)} flights: median {np.median(lat):+.0f} ms, range {lat.min():+.0f} to {lat.max():+.0f} ms")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"flights": results, "median_ms": float(np.median(lat))}, indent=1) + "\n")


if __name__ == "__main__":
    main()
