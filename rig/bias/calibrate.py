"""Fitting the link-bias model (`rig.sim.effects.link`) to flights with ground truth:
the six coefficients every link shares, with each flight's anchor delays fitted
alongside (they move by centimetres between flights, and a shared coefficient must
not absorb that), a robust (Huber) least-squares fit of the TDOA errors against the
ground truth, and the spread of each coefficient over flights resampled with
replacement (measurements 4 ms apart are not independent; flights are).

The result is a list of catalog effects (`link_bias`, then every anchor's mean delay
as `anchor_delay`), ready for a simulation config, with what the fit explains and
whether each coefficient lies within its physical bound."""

from __future__ import annotations

import logging
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rig.bias.dataset import MAX_ABS_ERROR_M, Samples, airborne_tdoa, tag_rotations, true_tdoa, truth_latency
from rig.data.recording import Recording
from rig.estimator import metrics
from rig.sim.effects import LINK_BOUND_M, LINK_TERMS, TdoaBatch, World, tdoa_basis

log = logging.getLogger(__name__)

HUBER_K = 1.345          # in robust standard deviations (95 % efficiency on Gaussian noise)
IRLS_ITERATIONS = 20


@dataclass
class FlightRows:
    """One flight's in-flight TDOA errors and the link basis at the true pose."""

    name: str
    error: np.ndarray      # measured − true TDOA (m)
    basis: np.ndarray      # (n, 6): LINK_TERMS, link B's minus link A's
    id_a: np.ndarray
    id_b: np.ndarray
    position: np.ndarray   # (n, 3): the tag's true position

    def select(self, mask: np.ndarray) -> "FlightRows":
        return FlightRows(self.name, self.error[mask], self.basis[mask], self.id_a[mask], self.id_b[mask],
                          self.position[mask])


def flight_rows(rec: Recording, name: str, latency: float | None = None) -> FlightRows:
    """The rows of `rec` the fit uses: in flight, known anchors, |error| ≤ MAX_ABS_ERROR_M."""
    latency = truth_latency(rec) if latency is None else latency
    sel = airborne_tdoa(rec)
    world = World.surveyed(rec.anchors)
    batch = _truth_batch(rec, rec.tdoa.t[sel] + latency, rec.tdoa.id_a[sel], rec.tdoa.id_b[sel])
    (a_pos, _), (b_pos, _) = world.anchor_poses(batch.id_a), world.anchor_poses(batch.id_b)
    error = rec.tdoa.distance_diff[sel] - true_tdoa(batch.tag_position, a_pos, b_pos)
    keep = np.abs(error) <= MAX_ABS_ERROR_M
    basis = tdoa_basis(batch, world, np.flatnonzero(keep))
    return FlightRows(name, error[keep], basis, batch.id_a[keep], batch.id_b[keep], batch.tag_position[keep])


def link_bias_of(rec: Recording, t: np.ndarray, id_a: np.ndarray, id_b: np.ndarray, latency: float,
                 coeffs: np.ndarray) -> np.ndarray:
    """The link bias with `coeffs` of TDOA measurements of `rec` (times on its clock,
    anchor ids), at the true tag pose read `latency` later: β(link B) − β(link A)."""
    world = World.surveyed(rec.anchors)
    known = np.flatnonzero(world.known_pairs(id_a, id_b))
    out = np.zeros(len(t))
    out[known] = tdoa_basis(_truth_batch(rec, t + latency, id_a, id_b), world, known) @ np.asarray(coeffs, float)
    return out


def samples_link_bias(samples: Samples, flights: list[Path], latency: dict[str, float],
                      coeffs: np.ndarray) -> np.ndarray:
    """`link_bias_of` every sample, each flight read from `flights` (paths by name)."""
    from rig.data.importer import load_any

    by_name = {Path(f).name: Path(f) for f in flights}
    out = np.zeros(len(samples))
    for name in sorted(set(samples.flight.tolist())):
        rows = np.flatnonzero(samples.flight == name)
        out[rows] = link_bias_of(load_any(by_name[name]), samples.t[rows], samples.id_a[rows], samples.id_b[rows],
                                 float(latency[name]), coeffs)
    return out


def _truth_batch(rec: Recording, t: np.ndarray, id_a: np.ndarray, id_b: np.ndarray) -> TdoaBatch:
    """Measurements between anchors id_a and id_b with the tag at its true pose at `t`."""
    return TdoaBatch(t, id_a, id_b, metrics.interpolate_positions(rec.truth, t),
                     Rotation.from_matrix(tag_rotations(rec.truth, t)), np.zeros(len(t)))


def _load_rows(flight: Path) -> FlightRows:
    from rig.data.importer import load_any

    return flight_rows(load_any(flight), Path(flight).name)


def load_flights(flights: list[Path], workers: int = 2, progress=None) -> list[FlightRows]:
    with ProcessPoolExecutor(max_workers=workers) as pool:
        rows = pool.map(_load_rows, sorted(flights))
        return list(progress(rows) if progress else rows)


def delay_columns(rows: FlightRows, anchors: list[int]) -> np.ndarray:
    """±1 where a measurement involves anchor k (B: +1, A: −1)."""
    return np.stack([(rows.id_b == k).astype(float) - (rows.id_a == k) for k in anchors], axis=1)


def _huber_weights(residual: np.ndarray) -> np.ndarray:
    scale = 1.4826 * float(np.median(np.abs(residual))) or 1.0
    return np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(residual), 1e-12))


def fit_coefficients(flights: list[FlightRows], anchors: list[int], terms: int = len(LINK_TERMS)
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The shared coefficients and each flight's delays (flights × anchors, centred), a
    Huber fit by iteratively reweighted least squares. Each flight's delays are
    eliminated from the normal equations (a Schur complement per flight), so the
    fit costs a few small solves per flight however many flights there are; a
    flight's delays are known only relative to each other (pseudo-inverse). With
    `terms` = 0, the delays alone."""
    columns = [delay_columns(r, anchors) for r in flights]
    weights = [np.ones(len(r.error)) for r in flights]
    for _ in range(IRLS_ITERATIONS):
        normal, moment, parts = np.zeros((terms, terms)), np.zeros(terms), []
        for rows, d, w in zip(flights, columns, weights):
            basis = rows.basis[:, :terms]
            bw, dw = basis * w[:, None], d * w[:, None]
            cross, delay_inv = bw.T @ d, np.linalg.pinv(dw.T @ d)
            normal += bw.T @ basis - cross @ delay_inv @ cross.T
            moment += bw.T @ rows.error - cross @ delay_inv @ (dw.T @ rows.error)
            parts.append((cross, delay_inv, dw.T @ rows.error))
        coeffs = np.linalg.solve(normal, moment) if terms else np.zeros(0)
        delays = np.array([inv @ (dy - cross.T @ coeffs) for cross, inv, dy in parts])
        residuals = [r.error - r.basis[:, :terms] @ coeffs - d @ dl
                     for r, d, dl in zip(flights, columns, delays)]
        weights = np.split(_huber_weights(np.concatenate(residuals)), np.cumsum([len(r) for r in residuals])[:-1])
    return coeffs, delays - delays.mean(axis=1, keepdims=True)


def _std(values: np.ndarray) -> float:
    return float(np.std(values)) if len(values) else float("nan")


def calibrate(flights: list[FlightRows], bootstrap: int = 20, seed: int = 0, progress=None) -> dict:
    """Fit the link bias to `flights`; its effects, coefficients with their spread over
    `bootstrap` resamplings of the flights, bounds, and the TDOA error's spread before
    and after."""
    if not flights:
        raise ValueError("no flight to calibrate on")
    anchors = sorted({int(k) for r in flights for k in np.concatenate([r.id_a, r.id_b])})
    coeffs, delays = fit_coefficients(flights, anchors)
    rng = np.random.default_rng(seed)
    resamples = range(bootstrap)
    resampled = np.array([fit_coefficients([flights[i] for i in rng.integers(0, len(flights), len(flights))],
                                           anchors)[0] for _ in (progress(resamples) if progress else resamples)])
    spread = resampled.std(axis=0) if bootstrap > 1 else np.full(len(LINK_TERMS), np.nan)
    error = np.concatenate([r.error for r in flights])
    delays_alone = fit_coefficients(flights, anchors, terms=0)[1]
    after_delays = np.concatenate([r.error - delay_columns(r, anchors) @ d for r, d in zip(flights, delays_alone)])
    after = np.concatenate([r.error - delay_columns(r, anchors) @ d - r.basis @ coeffs
                            for r, d in zip(flights, delays)])
    mean_delays = delays.mean(axis=0)
    terms = {name: {"value_m": float(v), "spread_m": float(s), "within_bound": bool(abs(v) <= LINK_BOUND_M)}
             for name, v, s in zip(LINK_TERMS, coeffs, spread)}
    return {
        "effects": [{"effect": "link_bias", "params": {"coeffs_m": [round(float(v), 4) for v in coeffs]}}]
        + [{"effect": "anchor_delay", "params": {"anchor": k, "meters": round(float(d), 4)}}
           for k, d in zip(anchors, mean_delays)],
        "terms": terms,
        "bound_m": LINK_BOUND_M,
        "within_bounds": all(t["within_bound"] for t in terms.values()),
        "delays_by_flight_m": {r.name: dict(zip(map(str, anchors), np.round(d, 4).tolist()))
                               for r, d in zip(flights, delays)},
        # with each flight's own delays: what the shared terms explain beyond them
        "tdoa_error_std_m": {"before": _std(error), "after_delays": _std(after_delays), "after_link": _std(after)},
        "flights": [r.name for r in flights],
        "samples": int(len(error)),
        "bootstrap": {"resamples": bootstrap, "seed": seed},
    }
