"""Each anchor's range delay in a flight's TDOA errors, and per installation.

A TDOA between anchors A and B carries d[B] − d[A], d an anchor's range delay (its
antenna delay, its cable, its mount). TDOA sees only differences, so a flight's delays
are fitted up to a constant: least squares, the smallest solution (zero mean over the
anchors the flight measured). Delays move between flights of a day by a few centimetres
and between days by up to 0.3 m (docs/notebook/bias.md), so `rig train
--installation-delays` trains the network on labels without each flight's own delays
and keeps, per installation, the median of its flights' delays: the model applies them
only to a recording of that installation (rig.estimator.bias_net.Installation).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from rig.bias.dataset import Samples
from rig.data import paths
from rig.data.survey import parse_survey
from rig.estimator.bias_net import ANCHORS, DELAY_BOUND_M, Installation

log = logging.getLogger(__name__)


def flight_delays(samples: Samples) -> dict[str, np.ndarray]:
    """Per flight, each anchor id's delay (ANCHORS,) that best explains its labels, zero
    mean over the anchors it measured (NaN for the others)."""
    out = {}
    for name in sorted(set(samples.flight.tolist())):
        rows = samples.flight == name
        a, b, label = samples.id_a[rows].astype(int), samples.id_b[rows].astype(int), samples.label[rows]
        # normal equations of label ≈ d[b] − d[a]: a graph Laplacian, singular along the
        # constant, whose pseudo-inverse gives the zero-mean solution
        laplacian, rhs = np.zeros((ANCHORS, ANCHORS)), np.zeros(ANCHORS)
        np.add.at(laplacian, (a, a), 1.0)
        np.add.at(laplacian, (b, b), 1.0)
        np.add.at(laplacian, (a, b), -1.0)
        np.add.at(laplacian, (b, a), -1.0)
        np.add.at(rhs, b, label)
        np.add.at(rhs, a, -label)
        seen = np.union1d(a, b)
        delays = np.full(ANCHORS, np.nan)
        delays[seen] = np.linalg.pinv(laplacian[np.ix_(seen, seen)]) @ rhs[seen]
        out[name] = delays
    return out


def undelayed(samples: Samples, delays: dict[str, np.ndarray]) -> Samples:
    """The samples with each flight's delays (those `delays` has) removed from its labels."""
    shift = np.zeros(len(samples))
    for name, d in delays.items():
        rows = samples.flight == name
        shift[rows] = d[samples.id_b[rows].astype(int)] - d[samples.id_a[rows].astype(int)]
    return replace(samples, label=samples.label - shift)


def installations(delays: dict[str, np.ndarray], flight_dir: Path) -> list[Installation]:
    """Per installation (the anchors of the survey of each flight's day), each anchor's
    median delay over the flights that measured it, held within DELAY_BOUND_M."""
    groups: dict[tuple, tuple[dict, list[np.ndarray]]] = {}
    for name, d in sorted(delays.items()):
        anchors = {a.id: np.asarray(a.position, float) for a in parse_survey(paths.survey_for(flight_dir / name))}
        key = tuple((k, *np.round(p, 4)) for k, p in sorted(anchors.items()))
        groups.setdefault(key, (anchors, []))[1].append(d)
    out = []
    for anchors, flights in groups.values():
        with warnings.catch_warnings():        # an anchor no flight measured: NaN, left out below
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(np.array(flights), axis=0)
        if np.any(np.abs(median[np.isfinite(median)]) > DELAY_BOUND_M):
            log.warning("an installation's delays %s exceed ±%g m: held at the bound", np.round(median, 3), DELAY_BOUND_M)
        median = np.clip(median, -DELAY_BOUND_M, DELAY_BOUND_M)
        out.append(Installation(anchors, {k: float(median[k]) for k in anchors
                                          if k < ANCHORS and np.isfinite(median[k])}))
    return out
