"""A UWB-only reference estimate: robust TDOA multilateration over short windows.

No IMU, no motion model: every window's measurements are solved for one position
by Gauss–Newton with Huber weights, warm-started from the previous window. It is
the rig's sanity check of a recording (its TDOA convention, its anchors and its
ground truth must agree for this to be accurate) and a floor that any real
estimator must beat.
"""

from __future__ import annotations

import numpy as np

from rig.recording import Recording

HUBER_M = 0.3         # residual (m) beyond which a measurement's weight decays
MIN_MEASUREMENTS = 6  # per window
ITERATIONS = 8


def _solve(p: np.ndarray, a: np.ndarray, b: np.ndarray, d: np.ndarray) -> np.ndarray:
    for _ in range(ITERATIONS):
        ra = np.linalg.norm(p - a, axis=1)
        rb = np.linalg.norm(p - b, axis=1)
        residual = d - (rb - ra)
        jac = (p - b) / rb[:, None] - (p - a) / ra[:, None]
        weight = np.minimum(1.0, HUBER_M / np.maximum(np.abs(residual), 1e-9))
        jw = jac * weight[:, None]
        step = np.linalg.lstsq(jw.T @ jac + 1e-6 * np.eye(3), jw.T @ residual, rcond=None)[0]
        p = p + step
        if np.linalg.norm(step) < 1e-4:
            break
    return p


def multilaterate(rec: Recording, window: float = 0.1, start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions at the end of each `window`-second slice of the TDOA stream."""
    anchors = rec.anchor_map()
    known = np.array([a in anchors and b in anchors for a, b in zip(rec.tdoa.id_a, rec.tdoa.id_b)], bool)
    finite = np.isfinite(rec.tdoa.distance_diff) & known
    tdoa = rec.tdoa.select(finite)
    if len(tdoa) == 0:
        return np.zeros(0), np.zeros((0, 3))
    pos_a = np.array([anchors[k].position for k in tdoa.id_a])
    pos_b = np.array([anchors[k].position for k in tdoa.id_b])
    p = np.array(start if start is not None else np.mean([a.position for a in rec.anchors], axis=0), float)
    edges = np.arange(tdoa.t[0], tdoa.t[-1] + window, window)
    slices = np.searchsorted(tdoa.t, edges)
    times, positions = [], []
    for lo, hi, t_end in zip(slices[:-1], slices[1:], edges[1:]):
        if hi - lo < MIN_MEASUREMENTS:
            continue
        p = _solve(p, pos_a[lo:hi], pos_b[lo:hi], tdoa.distance_diff[lo:hi])
        times.append(t_end)
        positions.append(p.copy())
    return np.array(times), np.array(positions).reshape(-1, 3)
