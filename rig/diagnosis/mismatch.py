"""Where the untouched simulation and the recording differ, before any effect is
fitted (report.json `mismatch`, report.md "Where they differ"): per anchor and anchor
pair, with the tag on the floor, per IMU axis, per time block, per region of space
and per viewing angle of each anchor. What the catalog's effects are then fitted to
explain; a reader sees where to look before reading what was named."""

from __future__ import annotations

import numpy as np

from rig.diagnosis.channels import AXES, TIME_BLOCKS, Problem
from rig.diagnosis.floor_error import on_ground_delays
from rig.diagnosis.robust import MIN_SAMPLES, huber_mean, robust_rms
from rig.sim import effects as fx

CELL_M = 1.0              # regions of space: cubes of this side on a grid from the world origin
ANGLE_BIN_DEG = 30.0      # viewing angles: bins of this width in azimuth and in elevation
MIN_PAIR_SAMPLES = 20     # an anchor pair's fewest samples (TDOA3 spreads a flight over 56 ordered pairs)


def locate(problem: Problem, residual: dict[str, np.ndarray]) -> dict:
    """Robust mean mismatch per anchor (signed: positive = that anchor's ranges read
    long), per anchor pair (the later anchor's range against the earlier's), with the
    tag on the floor against in flight (tdoa_on_ground_m), per region of space (worst
    first, with the anchor that reads furthest off there), per viewing angle of each
    anchor, per IMU axis and per time block."""
    out: dict = {}
    if "tdoa" in residual:
        r, scale = residual["tdoa"], problem.scales["tdoa"]
        signs = {k: problem.anchor_sign(k) for k in problem.anchor_ids}
        out["tdoa_per_anchor_m"] = {str(k): _signed_mean(sign, r, sign != 0, scale[0]) for k, sign in signs.items()}
        out["tdoa_per_pair_m"] = _per_pair(problem, r)
        out["tdoa_on_ground_m"] = {k: float(v * scale[0])
                                   for k, v in on_ground_delays(problem, r / scale[0]).items()}
        out["tdoa_per_region"] = _per_region(problem, r, signs)
        out["tdoa_per_viewing_angle"] = _per_viewing_angle(problem, r, signs)
    for name in ("accel", "gyro"):
        if name in residual:
            r = residual[name]
            out[f"{name}_per_axis"] = {AXES[a]: huber_mean(r[a::3], problem.scales[name][a]) for a in range(3)}
    for name, r in residual.items():
        out[f"{name}_per_time_block"] = _per_time_block(problem, name, r)
    return out


def _signed_mean(sign: np.ndarray, r: np.ndarray, rows: np.ndarray, scale: float) -> float:
    """How long an anchor's ranges read (or a pair's later one against its earlier),
    robustly, over `rows`: residuals signed by `sign` (+1 where it is the pair's B)."""
    return huber_mean(sign[rows] * r[rows], scale)


def _per_pair(problem: Problem, r: np.ndarray) -> dict[str, dict]:
    """Each anchor pair "a-b" (a < b): how much longer b's range reads than a's."""
    d = problem.rec.tdoa
    id_a, id_b = d.id_a[problem.tdoa_rows], d.id_b[problem.tdoa_rows]
    low, high = np.minimum(id_a, id_b), np.maximum(id_a, id_b)
    sign = np.where(id_b == high, 1.0, -1.0)
    out = {}
    for a, b in sorted(set(zip(low.tolist(), high.tolist()))):
        rows = (low == a) & (high == b)
        if rows.sum() >= MIN_PAIR_SAMPLES:
            out[f"{a}-{b}"] = {"mean_m": _signed_mean(sign, r, rows, problem.scales["tdoa"][0]),
                               "samples": int(rows.sum())}
    return out


def _per_region(problem: Problem, r: np.ndarray, signs: dict[int, np.ndarray]) -> list[dict]:
    """Cubes of CELL_M the tag flew through, worst mismatch first: its robust RMS there
    and the anchor whose ranges read furthest off there (`signs`: each anchor's)."""
    cells = np.floor(problem.tag_positions() / CELL_M).astype(int)
    out = []
    for cell in np.unique(cells, axis=0):
        rows = np.all(cells == cell, axis=1)
        if rows.sum() < MIN_SAMPLES:
            continue
        seen = {k: rows & (sign != 0) for k, sign in signs.items()}
        means = {k: _signed_mean(signs[k], r, seen[k], problem.scales["tdoa"][0])
                 for k in signs if seen[k].sum() >= MIN_SAMPLES}
        worst = max(means, key=lambda k: abs(means[k]), default=None)
        out.append({"region": {"min": (cell * CELL_M).tolist(), "max": ((cell + 1) * CELL_M).tolist()},
                    "samples": int(rows.sum()),
                    "robust_rms": robust_rms(r[rows], problem.scales["tdoa"][rows]),
                    **({"anchor": int(worst), "anchor_mean_m": means[worst]} if worst is not None else {})})
    return sorted(out, key=lambda c: -c["robust_rms"])


def _per_viewing_angle(problem: Problem, r: np.ndarray, signs: dict[int, np.ndarray]) -> dict[str, list[dict]]:
    """For each anchor, how long its ranges read with the tag seen in each bin of
    azimuth and elevation in the anchor's own frame (where an antenna pattern shows)."""
    batch = problem.predictor.tdoa([])
    world = problem.predictor.world([])
    out = {}
    for k, sign in signs.items():
        azimuth, elevation = (np.degrees(a[problem.tdoa_rows]) for a in fx.viewing_angles(batch, world, k))
        bins = np.column_stack([np.floor(azimuth / ANGLE_BIN_DEG), np.floor(elevation / ANGLE_BIN_DEG)]).astype(int)
        rows_k = sign != 0
        out[str(k)] = []
        for az, el in np.unique(bins[rows_k], axis=0):
            rows = rows_k & (bins[:, 0] == az) & (bins[:, 1] == el)
            if rows.sum() >= MIN_SAMPLES:
                out[str(k)].append({"azimuth_deg": [float(az * ANGLE_BIN_DEG), float((az + 1) * ANGLE_BIN_DEG)],
                                    "elevation_deg": [float(el * ANGLE_BIN_DEG), float((el + 1) * ANGLE_BIN_DEG)],
                                    "samples": int(rows.sum()),
                                    "mean_m": _signed_mean(sign, r, rows, problem.scales["tdoa"][0])})
    return out


def _per_time_block(problem: Problem, name: str, r: np.ndarray) -> list[dict]:
    t = problem.times(name)
    edges = np.quantile(t, np.linspace(0, 1, TIME_BLOCKS + 1))
    block = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, TIME_BLOCKS - 1)
    return [{"time": [round(float(edges[b]), 2), round(float(edges[b + 1]), 2)],
             "robust_rms": robust_rms(r[block == b], problem.scales[name][block == b])}
            for b in range(TIME_BLOCKS) if (block == b).any()]
