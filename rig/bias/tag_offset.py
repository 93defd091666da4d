"""The part of a TDOA error that a constant offset of the tag explains.

A constant offset δ of the tag's position changes every TDOA by H δ, H = u_A − u_B (u:
the unit vector from the tag to the anchor). TDOA and IMU cannot tell it from the tag
really being δ away, so a correction that carries one moves every estimate by −δ,
whatever the flight. On the shared flights each flight's own δ differs (mostly a pattern
of anchor delays, which a flight around a circle cannot tell from an offset; not the
ground truth's height, which the downward laser checks), so the shipped correction is
trained on labels with each flight's δ removed (`rig train --untranslated`;
docs/notebook/bias.md, "The tag's constant offset"). It may carry the training flights'
median δ as one explicit constant instead (`--tag-offset`), bounded by the airframe.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rig.bias.dataset import Samples
from rig.estimator.bias_net import offset_basis

# The largest tag offset taken for physical: the antenna's distance from the body origin
# on a 92 mm airframe with its deck, or a misalignment of the ground truth's frame.
TAG_OFFSET_BOUND_M = 0.15


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


def calibrated_offset(samples: Samples) -> np.ndarray:
    """The tag offset carried as a calibration constant: the median flight's, axis by axis
    (a flight whose offset differs does not drag it). Beyond TAG_OFFSET_BOUND_M it is no
    offset of the tag, and an error."""
    offsets = np.array(list(tag_offsets(samples).values()))
    if not len(offsets):
        raise ValueError("no flight to calibrate the tag offset on")
    offset = np.median(offsets, axis=0)
    if np.linalg.norm(offset) > TAG_OFFSET_BOUND_M:
        raise ValueError(f"the flights' median tag offset {np.round(offset, 3).tolist()} m is beyond the "
                         f"{TAG_OFFSET_BOUND_M} m an antenna can sit from the body origin")
    return offset
