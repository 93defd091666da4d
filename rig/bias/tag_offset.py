"""The part of a TDOA error that a constant offset of the tag explains.

A constant offset δ of the tag's position changes every TDOA by H δ, H = u_A − u_B (u:
the unit vector from the tag to the anchor). TDOA and IMU cannot tell it from the tag
really being δ away, so a correction that carries one moves every estimate by −δ,
whatever the flight. On the shared flights each flight's own δ differs (mostly a pattern
of anchor delays, which a flight around a circle cannot tell from an offset; not the
ground truth's height, which the downward laser checks). `rig train --untranslated`
trains on labels with each flight's δ removed, so that the correction carries none; the
shipped correction was trained so in sessions 59–62 and is trained on the labels as
measured since (docs/notebook/bias.md, "The labels on the pinned branch").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rig.bias.dataset import Samples


def offset_basis(features: np.ndarray) -> np.ndarray:
    """H = u_A − u_B per measurement: the TDOA's change per metre of tag offset. The
    measurement features' first six are anchor A's and B's positions relative to the tag."""
    a, b = features[:, 0:3], features[:, 3:6]
    return a / np.linalg.norm(a, axis=1, keepdims=True) - b / np.linalg.norm(b, axis=1, keepdims=True)


def tag_offsets(samples: Samples, values: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per flight, the constant tag offset that best explains `values` (default: the
    labels, the TDOA errors) in least squares."""
    values = samples.label if values is None else values
    basis = offset_basis(samples.features)
    out = {}
    for name in sorted(set(samples.flight.tolist())):
        rows = samples.flight == name
        out[name] = np.linalg.lstsq(basis[rows], values[rows], rcond=None)[0]
    return out


def untranslated(samples: Samples) -> Samples:
    """The samples with each flight's own tag offset removed from its labels."""
    offsets = tag_offsets(samples)
    shift = np.array([offsets[name] for name in samples.flight.tolist()]).reshape(-1, 3)
    return replace(samples, label=samples.label - np.sum(offset_basis(samples.features) * shift, axis=1))
