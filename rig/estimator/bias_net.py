"""The bias network as data: float weights with their normalisation, quantised
to the int8 layout of the C `bias_net_t` (per-output scales), saved as JSON.

Layer l computes y = relu(W_l x + b_l) (no ReLU on the output layer); inputs are
standardised as (x - in_mean) * in_scale; the bias in metres is
out_scale * y + out_offset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.data import paths

INPUTS, HIDDEN = 14, 30
DEFAULT_NETWORK = paths.SHIPPED_BIAS_NET
LANES = 32  # C storage width of a layer (BN_LANES): two zero neurons of padding

NET_DTYPE = np.dtype([
    ("in_mean", "<f4", INPUTS), ("in_scale", "<f4", INPUTS), ("out_scale", "<f4"), ("out_offset", "<f4"),
    ("w1", "i1", (INPUTS, LANES)), ("w2", "i1", (HIDDEN, LANES)), ("w3", "i1", (HIDDEN, LANES)),
    ("w4", "i1", HIDDEN),
    ("s1", "<f4", LANES), ("s2", "<f4", LANES), ("s3", "<f4", LANES), ("s4", "<f4"),
    ("b1", "<f4", LANES), ("b2", "<f4", LANES), ("b3", "<f4", LANES), ("b4", "<f4"),
], align=True)


@dataclass
class BiasNet:
    """Float weights (PyTorch layout: W[out, in]) and the model's normalisation."""

    weights: list[np.ndarray]  # shapes (30,14), (30,30), (30,30), (1,30)
    biases: list[np.ndarray]   # shapes (30,), (30,), (30,), (1,)
    in_mean: np.ndarray
    in_scale: np.ndarray
    out_scale: float = 1.0
    out_offset: float = 0.0

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Float reference inference on rows of raw features."""
        x = (np.atleast_2d(features) - self.in_mean) * self.in_scale
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = x @ w.T + b
            if k < len(self.weights) - 1:
                x = np.maximum(x, 0.0)
        return x[:, 0] * self.out_scale + self.out_offset

    def quantized(self) -> "BiasNet":
        """The same network with weights rounded exactly as `pack` stores them."""
        weights = []
        for w in self.weights:
            q, scale = _quantize_rows(w)
            weights.append(q.astype(np.float64) * scale[:, None])
        return BiasNet(weights, [b.copy() for b in self.biases], self.in_mean, self.in_scale,
                       self.out_scale, self.out_offset)

    def pack(self) -> np.ndarray:
        """One NET_DTYPE record, laid out like the C bias_net_t."""
        rec = np.zeros((), NET_DTYPE)
        rec["in_mean"], rec["in_scale"] = self.in_mean, self.in_scale
        rec["out_scale"], rec["out_offset"] = self.out_scale, self.out_offset
        for k, (w, b) in enumerate(zip(self.weights, self.biases), start=1):
            q, scale = _quantize_rows(w)
            if k < 4:  # C stores input-major, HIDDEN neurons in LANES slots (padding stays zero)
                rec[f"w{k}"][:, :HIDDEN] = q.T
                rec[f"s{k}"][:HIDDEN] = scale
                rec[f"b{k}"][:HIDDEN] = b
            else:
                rec[f"w{k}"], rec[f"s{k}"], rec[f"b{k}"] = q[0], scale[0], b[0]
        return np.ascontiguousarray(rec.reshape(1))

    def to_json(self) -> dict:
        return {
            "architecture": f"{INPUTS}-{HIDDEN}-{HIDDEN}-{HIDDEN}-1 relu",
            "in_mean": self.in_mean.tolist(), "in_scale": self.in_scale.tolist(),
            "out_scale": self.out_scale, "out_offset": self.out_offset,
            "weights": [w.tolist() for w in self.weights], "biases": [b.tolist() for b in self.biases],
        }

    @classmethod
    def from_json(cls, obj: dict) -> "BiasNet":
        return cls([np.array(w, float) for w in obj["weights"]], [np.array(b, float) for b in obj["biases"]],
                   np.array(obj["in_mean"], float), np.array(obj["in_scale"], float),
                   float(obj["out_scale"]), float(obj["out_offset"]))

    def save(self, path: Path) -> None:
        Path(path).write_text(json.dumps(self.to_json()) + "\n")

    @classmethod
    def load(cls, path: Path) -> "BiasNet":
        return cls.from_json(json.loads(Path(path).read_text()))


def _quantize_rows(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric int8 per output row: w ≈ q * scale, |q| ≤ 127."""
    peak = np.max(np.abs(w), axis=1)
    scale = np.where(peak > 0, peak / 127.0, 1.0).astype(np.float32)
    q = np.clip(np.round(w / scale[:, None]), -127, 127).astype(np.int8)
    return q, scale


def identity_probe_net(feature: int, gain: float = 1.0, offset: float = 0.0) -> BiasNet:
    """A network whose output is computable by hand: bias = gain * relu(feature) + offset.

    Neuron 0 of each hidden layer passes the (positive part of the) chosen raw
    feature through; every other weight is zero. Used to test the C inference."""
    w1 = np.zeros((HIDDEN, INPUTS)); w1[0, feature] = 1.0
    w2 = np.zeros((HIDDEN, HIDDEN)); w2[0, 0] = 1.0
    w3 = np.zeros((HIDDEN, HIDDEN)); w3[0, 0] = 1.0
    w4 = np.zeros((1, HIDDEN)); w4[0, 0] = 1.0
    zeros = [np.zeros(HIDDEN)] * 3 + [np.zeros(1)]
    return BiasNet([w1, w2, w3, w4], zeros, np.zeros(INPUTS), np.ones(INPUTS), gain, offset)
