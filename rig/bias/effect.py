"""What the bias correction does to one recording's TDOA errors, against its ground truth,
overall and on each pair of anchors.

A correction learnt in a room holds while the room and the tag stay as they were: on the
shared flights of a day whose anchors' pose-dependent bias differs from the training
days' (0422), it makes some pairs' errors larger and makes the estimate worse
(docs/notebook/bias.md). `rig evaluate` reports this with every corrected replay, so a
user sees which pairs a correction no longer fits; the features are computed as the
board computes them, from the estimator's own pose, and the errors from the ground truth.
"""

from __future__ import annotations

import numpy as np

from rig.bias.dataset import flight_samples
from rig.data.recording import Recording
from rig.estimator.bias_net import BiasNet


def correction_effect(rec: Recording, model: BiasNet) -> dict | None:
    """The TDOA errors' RMS (m) before and after `model`'s correction (int8, as the board
    runs it), overall and per pair of anchors (either order; the pairs the model
    corrects), with the pairs it makes worse, the worst first; None when the recording
    has no in-flight TDOA to score. The RMS about zero, not the spread about the mean: a
    correction that adds a constant to a pair's errors makes them worse. Per pair, not
    per anchor: a correction wrong on one anchor is wrong on every pair with it, and only
    those."""
    samples = flight_samples(rec, "recording")
    if len(samples) < 2:
        return None
    after = samples.label - model.quantized().predict(samples.features, samples.id_a, samples.id_b)
    corrected = model.trained_on(samples.id_a) & model.trained_on(samples.id_b)
    low, high = np.minimum(samples.id_a, samples.id_b).astype(int), np.maximum(samples.id_a, samples.id_b).astype(int)
    per_pair = {}
    for a, b in sorted(set(zip(low[corrected].tolist(), high[corrected].tolist()))):
        rows = corrected & (low == a) & (high == b)
        if rows.sum() >= 2:
            per_pair[f"{a}-{b}"] = {"before": _rms(samples.label[rows]), "after": _rms(after[rows]),
                                    "samples": int(rows.sum())}
    worse = sorted((k for k, s in per_pair.items() if s["after"] > s["before"]),
                     key=lambda k: per_pair[k]["before"] - per_pair[k]["after"])
    return {"tdoa_error_rms_m": {"before": _rms(samples.label), "after": _rms(after)},
            "samples": len(samples), "corrected_share": float(corrected.mean()), "per_pair": per_pair,
            "worse_pairs": worse}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))
