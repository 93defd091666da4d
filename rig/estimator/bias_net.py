"""The bias correction as data: float weights with their normalisation, quantised to
the int8 layout of the C `bias_net_t` (per-output scales), saved as JSON.

Two forms (estimator_c/include/bias_net.h):
- "pair": a network of the 14 features of a measurement, 14-30-30-30-1, whose output
  is the TDOA bias;
- "link": one network g of the 7 features of a tag-anchor link, 7-20-20-20-1, shared
  by every link; the TDOA bias is g(link B) − g(link A), the difference of the two
  links' range biases.

Layer l computes y = relu(W_l x + b_l) (no ReLU on the output layer); inputs are
standardised as (x - in_mean) * in_scale (a scale of 0 keeps a feature out); the output
in metres is out_scale * y + out_offset (the link form's offset cancels in the
difference: 0). A link model may add each anchor's own range offset (`anchor_offset`,
zero for an anchor it never saw): TDOA bias = g(B) + d[B] − g(A) − d[A].

A model knows the anchors it was trained on (`anchors`) and does not correct a
measurement with another one: a network that tells anchors apart by their position
only extrapolates to a new anchor, and widened the error there
(docs/notebook/bias-validation.md, leave-anchor-out). It may also carry where it was
trained (`trained_region`, rig.estimator.trained_region): the host reports it, the
board does not use it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.data import paths
from rig.data.errors import ModelFileError
from rig.data.files import write_text_whole
from rig.estimator.trained_region import TrainedRegion

INPUTS, HIDDEN = 14, 30               # the measurement's features; the pair form's hidden width
LINK_INPUTS, LINK_HIDDEN = 7, 20      # one link's features; the link form's hidden width
FORMS = ("link", "pair")
FORM_CODE = {"pair": 0, "link": 1}    # bias_net_t.form
# Which of the 14 measurement features belong to link A and to link B (BN_LINK_A/B).
LINK_A = [0, 1, 2, 6, 8, 10, 12]
LINK_B = [3, 4, 5, 7, 9, 11, 13]
DEFAULT_NETWORK = paths.SHIPPED_BIAS_NET
LANES = 32  # C storage width of a pair layer (BN_LANES): two zero neurons of padding
ANCHORS = 16  # anchor ids with an offset (BN_ANCHORS)
EVERY_ANCHOR = 0xFFFFFFFF  # bias_net_t.anchors of a model that corrects every anchor (BN_EVERY_ANCHOR)


def _layer_dtype(n_in: int, hidden: int, lanes: int, offset: bool, anchors: int = 0) -> np.dtype:
    return np.dtype([
        ("in_mean", "<f4", n_in), ("in_scale", "<f4", n_in), ("out_scale", "<f4"),
        *([("out_offset", "<f4")] if offset else []),
        ("w1", "i1", (n_in, lanes)), ("w2", "i1", (hidden, lanes)), ("w3", "i1", (hidden, lanes)),
        ("w4", "i1", hidden),
        ("s1", "<f4", lanes), ("s2", "<f4", lanes), ("s3", "<f4", lanes), ("s4", "<f4"),
        ("b1", "<f4", lanes), ("b2", "<f4", lanes), ("b3", "<f4", lanes), ("b4", "<f4"),
        *([("anchor_offset", "<f4", anchors)] if anchors else []),
    ], align=True)


PAIR_DTYPE = _layer_dtype(INPUTS, HIDDEN, LANES, offset=True)
LINK_DTYPE = _layer_dtype(LINK_INPUTS, LINK_HIDDEN, LANES, offset=False, anchors=ANCHORS)
# bias_net_t: the form, the anchors it was trained on (a bit per id), then a union of
# the two layouts.
NET_DTYPE = np.dtype({"names": ["form", "anchors", "pair", "link"], "formats": ["<u4", "<u4", PAIR_DTYPE, LINK_DTYPE],
                      "offsets": [0, 4, 8, 8], "itemsize": 8 + max(PAIR_DTYPE.itemsize, LINK_DTYPE.itemsize)})


def shape(form: str) -> tuple[int, int]:
    """Inputs and hidden width of a form's network."""
    return (LINK_INPUTS, LINK_HIDDEN) if form == "link" else (INPUTS, HIDDEN)


def link_features(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The link features of rows of measurement features: link A's and link B's."""
    features = np.atleast_2d(features)
    return features[:, LINK_A], features[:, LINK_B]


@dataclass
class BiasNet:
    """Float weights (PyTorch layout: W[out, in]) and the model's normalisation."""

    weights: list[np.ndarray]  # pair: (30,14), (30,30), (30,30), (1,30); link: (20,7), (20,20), (20,20), (1,20)
    biases: list[np.ndarray]
    in_mean: np.ndarray
    in_scale: np.ndarray
    out_scale: float = 1.0
    out_offset: float = 0.0
    form: str = "pair"
    anchor_offset: np.ndarray | None = None   # link form: (ANCHORS,) range offset per anchor id (m)
    anchors: list[int] | None = None          # the anchor ids it was trained on (None: it corrects every one)
    region: TrainedRegion | None = None       # where it was trained (reported by `rig evaluate`, not used onboard)

    def __post_init__(self) -> None:
        if self.form not in FORMS:
            raise ValueError(f"form must be one of {FORMS}, not {self.form!r}")
        self._check_layers()
        if self.anchors is not None:
            self.anchors = sorted({int(k) for k in self.anchors})
            if any(not 0 <= k < ANCHORS for k in self.anchors):
                raise ValueError(f"the anchors a model was trained on are ids 0..{ANCHORS - 1}, not {self.anchors}")
        if self.anchor_offset is not None:
            self.anchor_offset = np.asarray(self.anchor_offset, float)
            if self.form != "link" or self.anchor_offset.shape != (ANCHORS,):
                raise ValueError(f"anchor offsets belong to the link form, one per anchor id 0..{ANCHORS - 1}")
            if not np.isfinite(self.anchor_offset).all():
                raise ValueError("its anchor offsets are not all finite")
            if not np.any(self.anchor_offset):
                self.anchor_offset = None

    def _check_layers(self) -> None:
        """The form's layer shapes, and finite numbers everywhere: a diverged training or a
        damaged file would otherwise reach the board as a correction of NaN."""
        n_in, hidden = shape(self.form)
        self.weights = [np.asarray(w, float) for w in self.weights]
        self.biases = [np.asarray(b, float) for b in self.biases]
        self.in_mean, self.in_scale = np.asarray(self.in_mean, float), np.asarray(self.in_scale, float)
        shapes = [(hidden, n_in), (hidden, hidden), (hidden, hidden), (1, hidden)]
        if [w.shape for w in self.weights] != shapes or [b.shape for b in self.biases] != [s[:1] for s in shapes] \
                or self.in_mean.shape != (n_in,) or self.in_scale.shape != (n_in,):
            raise ValueError(f"the {self.form} form's layers are {shapes} with {n_in} inputs, not "
                             f"{[w.shape for w in self.weights]} with {self.in_mean.shape}")
        arrays = {"weights": self.weights, "biases": self.biases, "in_mean": [self.in_mean],
                  "in_scale": [self.in_scale], "out_scale": [self.out_scale], "out_offset": [self.out_offset]}
        for name, values in arrays.items():
            if not all(np.isfinite(v).all() for v in values):
                raise ValueError(f"its {name} are not all finite")

    def offsets(self, ids: np.ndarray) -> np.ndarray:
        """Each id's range offset (m); 0 for ids beyond the table, as the C code does."""
        ids = np.asarray(ids, int)
        out = np.zeros(ids.shape)
        if self.anchor_offset is not None:
            inside = (ids >= 0) & (ids < ANCHORS)
            out[inside] = self.anchor_offset[ids[inside]]
        return out

    @property
    def anchor_mask(self) -> int:
        """bias_net_t.anchors: bit k for anchor id k."""
        return EVERY_ANCHOR if self.anchors is None else sum(1 << k for k in self.anchors)

    def trained_on(self, ids) -> np.ndarray:
        """Whether each anchor id is one the model was trained on."""
        ids = np.asarray(ids, int)
        return np.ones(ids.shape, bool) if self.anchors is None else np.isin(ids, self.anchors)

    def _network(self, x: np.ndarray) -> np.ndarray:
        x = (np.atleast_2d(x) - self.in_mean) * self.in_scale
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = x @ w.T + b
            if k < len(self.weights) - 1:
                x = np.maximum(x, 0.0)
        return x[:, 0] * self.out_scale

    def link_bias(self, links: np.ndarray) -> np.ndarray:
        """The link form's range bias (m) of rows of link features."""
        return self._network(links)

    def predict(self, features: np.ndarray, id_a=None, id_b=None) -> np.ndarray:
        """Float reference inference on rows of raw measurement features and their anchor
        ids: the TDOA bias (m), 0 where the model never saw one of the two anchors. The
        ids may be left out of a model without anchor offsets that corrects every anchor."""
        needs_ids = self.anchor_offset is not None or self.anchors is not None
        if needs_ids and (id_a is None or id_b is None):
            raise ValueError("this model has per-anchor offsets or knows its anchors: predict needs the anchor ids")
        if self.form == "pair":
            bias = self._network(features) + self.out_offset
        else:
            a, b = link_features(features)
            bias = self.link_bias(b) - self.link_bias(a)
            if self.anchor_offset is not None:
                bias = bias + self.offsets(id_b) - self.offsets(id_a)
        if self.anchors is None:
            return bias
        return np.where(self.trained_on(id_a) & self.trained_on(id_b), bias, 0.0)

    def quantized(self) -> "BiasNet":
        """The same network with weights rounded exactly as `pack` stores them."""
        weights = []
        for w in self.weights:
            q, scale = _quantize_rows(w)
            weights.append(q.astype(np.float64) * scale[:, None])
        offsets = None if self.anchor_offset is None else self.anchor_offset.astype(np.float32).astype(float)
        return BiasNet(weights, [b.copy() for b in self.biases], self.in_mean, self.in_scale,
                       self.out_scale, self.out_offset, self.form, offsets, self.anchors, self.region)

    def pack(self) -> np.ndarray:
        """One NET_DTYPE record, laid out like the C bias_net_t."""
        rec = np.zeros((), NET_DTYPE)
        rec["form"] = FORM_CODE[self.form]
        rec["anchors"] = self.anchor_mask
        layout = rec[self.form]
        hidden = shape(self.form)[1]
        layout["in_mean"], layout["in_scale"], layout["out_scale"] = self.in_mean, self.in_scale, self.out_scale
        if self.form == "pair":
            layout["out_offset"] = self.out_offset
        elif self.anchor_offset is not None:
            layout["anchor_offset"] = self.anchor_offset
        for k, (w, b) in enumerate(zip(self.weights, self.biases), start=1):
            q, scale = _quantize_rows(w)
            if k < 4:  # C stores input-major, `hidden` neurons in its lanes (padding stays zero)
                layout[f"w{k}"][:, :hidden] = q.T
                layout[f"s{k}"][:hidden] = scale
                layout[f"b{k}"][:hidden] = b
            else:
                layout[f"w{k}"], layout[f"s{k}"], layout[f"b{k}"] = q[0], scale[0], b[0]
        rec[self.form] = layout
        return np.ascontiguousarray(rec.reshape(1))

    def to_json(self) -> dict:
        n_in, hidden = shape(self.form)
        return {
            "form": self.form, "architecture": f"{n_in}-{hidden}-{hidden}-{hidden}-1 relu",
            "in_mean": self.in_mean.tolist(), "in_scale": self.in_scale.tolist(),
            "out_scale": self.out_scale, "out_offset": self.out_offset,
            "weights": [w.tolist() for w in self.weights], "biases": [b.tolist() for b in self.biases],
            **({"anchor_offset": self.anchor_offset.tolist()} if self.anchor_offset is not None else {}),
            **({"anchors": self.anchors} if self.anchors is not None else {}),
            **({"trained_region": self.region.to_json()} if self.region is not None else {}),
        }

    @classmethod
    def from_json(cls, obj: dict) -> "BiasNet":
        return cls([np.array(w, float) for w in obj["weights"]], [np.array(b, float) for b in obj["biases"]],
                   np.array(obj["in_mean"], float), np.array(obj["in_scale"], float),
                   float(obj["out_scale"]), float(obj["out_offset"]), obj.get("form", "pair"),
                   obj.get("anchor_offset"), obj.get("anchors"),
                   TrainedRegion.from_json(obj["trained_region"]) if "trained_region" in obj else None)

    def save(self, path: Path) -> None:
        write_text_whole(path, json.dumps(self.to_json()) + "\n")      # a failed write keeps the old model

    @classmethod
    def load(cls, path: Path) -> "BiasNet":
        """The model in a file `save` wrote; ModelFileError for one that is not."""
        path = Path(path)
        try:
            return cls.from_json(json.loads(path.read_text()))
        except KeyError as exc:
            raise ModelFileError(f"{path} is not a bias model: it lacks {exc}") from exc
        except (ValueError, TypeError, AttributeError) as exc:   # JSONDecodeError is a ValueError
            raise ModelFileError(f"{path} is not a usable bias model: {exc}") from exc


def _quantize_rows(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric int8 per output row: w ≈ q * scale, |q| ≤ 127."""
    peak = np.max(np.abs(w), axis=1)
    scale = np.where(peak > 0, peak / 127.0, 1.0).astype(np.float32)
    q = np.clip(np.round(w / scale[:, None]), -127, 127).astype(np.int8)
    return q, scale


def identity_probe_net(feature: int, gain: float = 1.0, offset: float = 0.0, form: str = "pair") -> BiasNet:
    """A network whose output is computable by hand: pair form, bias = gain * relu(feature)
    + offset; link form, the link bias is gain * relu(link feature), so the TDOA bias is
    gain * (relu(B's) − relu(A's)).

    Neuron 0 of each hidden layer passes the (positive part of the) chosen raw
    feature through; every other weight is zero. Used to test the C inference."""
    n_in, hidden = shape(form)
    w1 = np.zeros((hidden, n_in)); w1[0, feature] = 1.0
    w2 = np.zeros((hidden, hidden)); w2[0, 0] = 1.0
    w3 = np.zeros((hidden, hidden)); w3[0, 0] = 1.0
    w4 = np.zeros((1, hidden)); w4[0, 0] = 1.0
    zeros = [np.zeros(hidden)] * 3 + [np.zeros(1)]
    return BiasNet([w1, w2, w3, w4], zeros, np.zeros(n_in), np.ones(n_in), gain, offset if form == "pair" else 0.0,
                   form)
