"""Train the TDOA bias network (paper Section III) with torch on the CPU.

Flights, not samples, are split into training, validation and test sets (samples
20 ms apart are not independent). Mini-batch Adam on the mean squared error of
the standardised label, early stopping when the validation error has not improved
for `patience` epochs, the best epoch's weights kept. A few restarts from different
initialisations; the one kept is the one with which the robust estimator tracks the
validation flights best (lowest mean 3D RMSE, replayed in closed loop): on the shared
flights the end-to-end result varies by 0.01-0.02 m from one initialisation to the
next, and the validation TDOA error ranks them poorly (docs/notebook/bias.md). Seeded: the same
data and seed give the same network on the same CPU (`import_torch` pins the kernels of
torch's BLAS, which otherwise follow the machine). Another CPU gives another network, so
the provenance says which CPU trained it (`cpu_identity`).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from rig.bias.config import ANCHOR_OFFSET_BOUND_M, RECIPE_ESTIMATOR, TrainConfig
from rig.bias.dataset import Samples
from rig.bias.tag_offset import untranslated
from rig.data import paths
from rig.data.files import write_text_whole
from rig.estimator.bias_net import ANCHORS, BiasNet, link_features, shape
from rig.estimator.trained_region import TrainedRegion

log = logging.getLogger(__name__)
# what reading a damaged .npz or sidecar raises (a truncated archive, a bad member, garbage)
DAMAGED_CACHE = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, zlib.error)



@dataclass
class Split:
    train: list[str]
    validation: list[str]
    test: list[str]


def split_flights(names: list[str], seed: int, test: list[str] | None = None,
                  fractions: tuple[float, float] = (0.70, 0.15)) -> Split:
    """Shuffle flight names (seeded) and cut 70/15/15 (train/validation/test). With `test`
    given, those flights are the test set and the rest is cut in the same 70:15 proportion."""
    names = sorted(set(names) - set(test or []))
    order = [str(n) for n in np.random.default_rng(seed).permutation(names)]
    n = len(order)
    if n < 2:
        raise ValueError(f"need at least two training flights, got {n}")
    if test is None:
        n_val = max(1, round(fractions[1] * n))
        n_test = max(1, n - round(fractions[0] * n) - n_val)
        test = order[n - n_test:]
        order = order[:n - n_test]
    else:
        n_val = max(1, round(len(order) * fractions[1] / sum(fractions)))
    return Split(sorted(order[n_val:]), sorted(order[:n_val]), sorted(test))


def error_stats(residual: np.ndarray) -> dict:
    return {"mean": float(np.mean(residual)), "std": float(np.std(residual)),
            "rmse": float(np.sqrt(np.mean(residual ** 2))), "n": int(len(residual))}


# MKL, torch's BLAS on x86-64, picks its kernels by CPU (SSE2 ... AVX-512) and the
# training's path parts with them: one split and seed gave 0.191, 0.198 and 0.197 m
# under three of its branches (docs/notebook/bias.md). Its reproducibility branch
# COMPATIBLE takes that choice away, so a training repeats from one machine to another
# of the same CPU. Not across CPUs: on an AMD EPYC the shipped recipe gives another
# network than on the Intel Xeon it was made on (session 77), so every provenance says
# its CPU (cpu_identity). MKL_CBWR set beforehand (e.g. AVX512, to repeat a figure made
# with that branch) wins.
MKL_BRANCH = "COMPATIBLE"


def cpu_identity(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU a training runs on, as "vendor family model" (e.g. "GenuineIntel 6 207"),
    or the machine's architecture where /proc/cpuinfo does not say."""
    fields = {}
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    if {"vendor_id", "cpu family", "model"} <= set(fields):
        return f"{fields['vendor_id']} {fields['cpu family']} {fields['model']}"
    import platform

    return platform.machine() or "unknown"


def import_torch():
    """torch, for training: one thread (fastest for these small networks, and its sums
    in one order) and MKL on a fixed code branch."""
    if "torch" not in sys.modules:
        os.environ.setdefault("MKL_CBWR", MKL_BRANCH)
    elif "MKL_CBWR" not in os.environ:
        log.warning("torch was imported before the training pinned MKL's code branch: "
                    "the training may not repeat on another machine (set MKL_CBWR=%s)", MKL_BRANCH)
    import torch

    torch.set_num_threads(1)
    return torch


def _model(torch, config: TrainConfig):
    """The network to train: the pair form maps a measurement's 14 standardised features
    to its bias; the link form applies one network g to both links' 7 standardised
    features and returns g(B) − g(A), plus d[B] − d[A] with anchor offsets."""
    nn = torch.nn
    n_in, hidden = shape(config.form)
    mlp = nn.Sequential(nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                        nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))
    if config.form == "pair":
        return mlp

    class LinkDifference(nn.Module):
        def __init__(self):
            super().__init__()
            self.g = mlp
            self.offset = nn.Parameter(torch.zeros(ANCHORS)) if config.anchor_offsets else None

        def forward(self, x):
            bias = self.g(x[:, n_in:2 * n_in]) - self.g(x[:, :n_in])
            if self.offset is None:
                return bias
            ids = x[:, 2 * n_in:].long()            # the anchor ids ride in the last two columns
            return bias + (self.offset[ids[:, 1]] - self.offset[ids[:, 0]])[:, None]

    return LinkDifference()


def _linears(model) -> list:
    return [m for m in (model.g if hasattr(model, "g") else model) if hasattr(m, "weight")]


def _masked(features: np.ndarray, keep: list[int]) -> np.ndarray:
    out = np.zeros_like(features, dtype=np.float64)
    out[:, keep] = features[:, keep]
    return out


def _normalisation(x: np.ndarray, keep: list[int]) -> tuple[np.ndarray, np.ndarray]:
    mean = x.mean(axis=0)
    std = x.std(axis=0)
    scale = np.where(std > 1e-9, 1.0 / np.maximum(std, 1e-9), 0.0)
    dropped = np.setdiff1d(np.arange(x.shape[1]), keep)
    mean[dropped], scale[dropped] = 0.0, 0.0  # a dropped feature cannot reach the network
    return mean, scale


def _network_inputs(features: np.ndarray, config: TrainConfig) -> np.ndarray:
    """What the network's standardisation sees: the kept measurement features (pair
    form), or link A's kept features then link B's, side by side (link form)."""
    if config.form == "link":
        return np.hstack([_masked(link, config.kept_features()) for link in link_features(features)])
    return _masked(features, config.kept_features())


def _standardisation(train_set: Samples, config: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Input mean and scale: per feature (pair form), or per link feature over both
    links' rows stacked (link form: one network sees either link)."""
    x = _network_inputs(train_set.features, config)
    if config.form == "link":
        n = x.shape[1] // 2
        return _normalisation(np.vstack([x[:, :n], x[:, n:]]), config.kept_features())
    return _normalisation(x, config.kept_features())


def _to_bias_net(model, in_mean, in_scale, out_scale, out_offset, form: str, seen: np.ndarray) -> BiasNet:
    linears = _linears(model)
    return BiasNet([m.weight.detach().double().numpy().copy() for m in linears],
                   [m.bias.detach().double().numpy().copy() for m in linears],
                   in_mean, in_scale, float(out_scale), float(out_offset), form,
                   _anchor_offsets(model, out_scale, seen))


def _anchor_offsets(model, out_scale: float, seen: np.ndarray) -> np.ndarray | None:
    """The learnt offsets in metres, bounded, zero-mean over the anchors seen in training.
    A TDOA sees only differences of offsets, so their common level is free; fixing it
    at the seen anchors' mean gives an unseen anchor (offset 0) their mean delay."""
    offset = getattr(model, "offset", None)
    if offset is None:
        return None
    metres = offset.detach().double().numpy() * out_scale
    out = np.zeros(ANCHORS)
    out[seen] = metres[seen] - metres[seen].mean()
    return np.clip(out, -ANCHOR_OFFSET_BOUND_M, ANCHOR_OFFSET_BOUND_M)


def train(train_set: Samples, validation_set: Samples, config: TrainConfig = TrainConfig(),
          progress=None, score: Callable[[BiasNet], float] | None = None) -> tuple[BiasNet, dict]:
    """Fit `config.restarts` networks from different initialisations and keep the one with the
    lowest `score` (default: the validation error); returns it with its training history and
    every restart's result."""
    torch = import_torch()
    in_mean, in_scale = _standardisation(train_set, config)
    # a difference of link biases has no offset of its own
    out_offset = float(train_set.label.mean()) if config.form == "pair" else 0.0
    out_scale = float(train_set.label.std())
    repeat = 2 if config.form == "link" else 1          # the link form standardises both links alike

    def tensors(samples: Samples):
        x = (_network_inputs(samples.features, config) - np.tile(in_mean, repeat)) * np.tile(in_scale, repeat)
        if config.anchor_offsets:
            x = np.hstack([x, _anchor_ids(samples)])
        y = (samples.label - out_offset) / out_scale
        return torch.tensor(x, dtype=torch.float32), torch.tensor(y[:, None], dtype=torch.float32)

    data = (*tensors(train_set), *tensors(validation_set))
    seen = np.unique(np.concatenate([train_set.id_a, train_set.id_b]).astype(int))
    tic = time.perf_counter()
    runs = []
    for restart in range(config.first_restart, config.first_restart + config.restarts):
        model, run = _train_once(torch, data, config, restart, progress)
        net = _to_bias_net(model, in_mean, in_scale, out_scale, out_offset, config.form, seen)
        if score is not None:
            run["validation_rmse_3d"] = score(net)
        runs.append((net, run))
    key = "validation_mse" if score is None else "validation_rmse_3d"
    net, best = min(runs, key=lambda pair: pair[1][key])
    info = {**best, "selected_by": key, "seconds": time.perf_counter() - tic, "config": asdict(config),
            "restarts": [{k: v for k, v in run.items() if k != "history"} for _, run in runs]}
    return net, info


def closed_loop_rmse(recordings: list, net: BiasNet) -> float:
    """The robust estimator's mean 3D RMSE over `recordings` with the whole of `net`'s
    correction applied (inf if any replay diverges). The whole: a restart is chosen for
    its network, and the share a flight supports would hide how the restarts differ. The
    estimator is the recipe's (RECIPE_ESTIMATOR)."""
    from rig.estimator.evaluate import evaluate

    results = [evaluate(rec, model=net, full_trust=True, **RECIPE_ESTIMATOR) for rec in recordings]
    if any(r["diverged"] for r in results):
        return float("inf")
    return float(np.mean([r["rmse_3d"] for r in results]))


def _train_once(torch, data: tuple, config: TrainConfig, restart: int, progress=None) -> tuple:
    """One training run from the initialisation `config.init_seed(restart)`."""
    xt, yt, xv, yv = data
    init_seed = config.init_seed(restart)
    torch.manual_seed(init_seed)
    rng = np.random.default_rng(init_seed)
    model = _model(torch, config)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    loss_fn = torch.nn.MSELoss()
    best, best_state, best_epoch, history = np.inf, None, -1, []
    epochs = range(config.max_epochs)
    for epoch in progress(epochs) if progress else epochs:
        model.train()
        order = torch.from_numpy(rng.permutation(len(xt)))
        for start in range(0, len(xt), config.batch_size):
            idx = order[start:start + config.batch_size]
            optimiser.zero_grad()
            loss = loss_fn(model(xt[idx]), yt[idx])
            loss.backward()
            optimiser.step()
        model.eval()
        with torch.no_grad():
            val = float(loss_fn(model(xv), yv)) if len(xv) else float(loss)
        history.append({"epoch": epoch, "validation_mse": val})
        if val < best - 1e-6:
            best, best_epoch = val, epoch
            best_state = {k: v.clone() for k, v in model.state_dict().items()}
        elif epoch - best_epoch >= config.patience:
            break
    model.load_state_dict(best_state)
    return model, {"restart": restart, "init_seed": init_seed, "validation_mse": best,
                   "epochs": len(history), "best_epoch": best_epoch, "history": history}


def _anchor_ids(samples: Samples) -> np.ndarray:
    ids = np.column_stack([samples.id_a, samples.id_b]).astype(int)
    if ids.size and (ids.min() < 0 or ids.max() >= ANCHORS):
        raise ValueError(f"anchor ids must be 0..{ANCHORS - 1} to have an offset, got {ids.min()}..{ids.max()}")
    return ids


def residual_stats(net: BiasNet, samples: Samples) -> dict:
    """TDOA error before and after subtracting the network's prediction (float and int8 weights)."""
    if not len(samples):
        return {}
    return {"before": error_stats(samples.label),
            "after": error_stats(samples.label - net.predict(samples.features, samples.id_a, samples.id_b)),
            "after_int8": error_stats(samples.label - net.quantized().predict(samples.features, samples.id_a,
                                                                              samples.id_b))}




def involves(samples: Samples, anchors: list[int]) -> np.ndarray:
    return np.isin(samples.id_a, anchors) | np.isin(samples.id_b, anchors)


def fit(samples: Samples, split: Split, config: TrainConfig = TrainConfig(), exclude_anchors: list[int] = (),
        progress=None, flight_dir: Path | None = None) -> tuple[BiasNet, dict]:
    """Train on `split`; with `exclude_anchors`, training and validation never see a measurement
    involving them and the test set is exactly the test flights' measurements that do. The
    validation flights' recordings (for selecting a restart in closed loop) are read from
    `flight_dir`, by default the shared flights. With `config.untranslated`, every
    flight's labels lose their own constant tag offset first."""
    exclude_anchors = list(exclude_anchors)
    absent = sorted(set(exclude_anchors) - set(samples.id_a.tolist()) - set(samples.id_b.tolist()))
    if absent:
        raise ValueError(f"anchor(s) {absent} to leave out are in no measurement of these flights")
    if config.untranslated:
        samples = untranslated(samples)
    hit = involves(samples, exclude_anchors) if exclude_anchors else np.zeros(len(samples), bool)
    in_flights = lambda names: np.isin(samples.flight, names)  # noqa: E731
    train_set = samples.select(in_flights(split.train) & ~hit)
    validation_set = samples.select(in_flights(split.validation) & ~hit)
    test_set = samples.select(in_flights(split.test) & (hit if exclude_anchors else True))
    score = None
    if config.select_by == "rmse_3d" and not exclude_anchors and config.restarts > 1:
        from rig.data.importer import load_any

        flight_dir = paths.data_dir() / "flights" if flight_dir is None else Path(flight_dir)
        recordings = [load_any(flight_dir / name) for name in split.validation]
        score = lambda net: closed_loop_rmse(recordings, net)  # noqa: E731
    net, info = train(train_set, validation_set, config, progress, score)
    # it corrects only the anchors it learnt (the C estimator leaves the others alone),
    # and says where it learnt them (`rig evaluate` reports a flight's share outside)
    net = replace(net, anchors=np.union1d(train_set.id_a, train_set.id_b).astype(int).tolist(),
                  region=TrainedRegion.from_features(train_set.features, train_set.id_a, train_set.id_b))
    report = {"split": asdict(split), "exclude_anchors": exclude_anchors, "anchors": net.anchors,
              "samples": {"train": len(train_set), "validation": len(validation_set), "test": len(test_set)},
              "validation": residual_stats(net, validation_set), "test": residual_stats(net, test_set),
              "training": {k: v for k, v in info.items() if k != "history"}, "history": info["history"]}
    return net, report


def provenance_path(model_path: Path) -> Path:
    return model_path.with_name(model_path.stem + ".provenance.json")


def trained_on(model_path: Path) -> set[str]:
    """The names of the flights a `rig train` output trained on, from its provenance."""
    try:
        return set(json.loads(provenance_path(model_path).read_text())["split"]["train"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{model_path}: no readable provenance with its training flights ({exc})") from exc


def load_or_build_dataset(flights: list[Path], cache: Path | None, progress=None,
                          features_from: str = "estimate") -> tuple[Samples, dict]:
    """The samples of `flights`, from `cache` when it holds exactly these flights with
    features from the same tag pose; otherwise built, and written there."""
    from rig.bias.dataset import build_dataset

    names = sorted(Path(f).name for f in flights)
    meta = {"flights": names, "features_from": features_from}
    cached = _cached_dataset(cache, meta) if cache is not None else None
    if cached is not None:
        return cached
    samples, latency = build_dataset(flights, progress=progress, features_from=features_from)
    if cache is not None:
        _write_dataset(cache, samples, {**meta, "latency_s": latency})
    return samples, latency


def _cached_dataset(cache: Path, meta: dict) -> tuple[Samples, dict] | None:
    """The cache's samples if its sidecar (`cache` with .json) names `meta`; None when it
    does not, or when either file is damaged (a cache is rebuilt, never an error)."""
    sidecar = cache.with_suffix(".json")
    if not (cache.exists() and sidecar.exists()):
        return None
    try:
        cached = json.loads(sidecar.read_text())
        if not all(cached.get(k) == v for k, v in meta.items()):
            return None
        samples = Samples.load(cache)
        log.info("dataset from cache %s", cache)
        return samples, cached["latency_s"]
    except DAMAGED_CACHE as exc:
        log.warning("dataset cache %s is unreadable (%s: %s): building it again", cache, type(exc).__name__, exc)
        return None


def _write_dataset(cache: Path, samples: Samples, meta: dict) -> None:
    """Samples, then their sidecar, each written whole (a partial file, then a rename): an
    interrupted write leaves no sidecar that names a damaged archive."""
    sidecar = cache.with_suffix(".json")
    cache.parent.mkdir(parents=True, exist_ok=True)
    sidecar.unlink(missing_ok=True)
    partial = cache.with_name(cache.name + ".partial")
    with open(partial, "wb") as out:
        samples.save(out)
    partial.replace(cache)
    partial = sidecar.with_name(sidecar.name + ".partial")
    partial.write_text(json.dumps(meta) + "\n")
    partial.replace(sidecar)


def run_training(flights: list[Path], out: Path, *, test_prefixes: list[str] | None = None,
                 all_flights: bool = False, exclude_anchors: list[int] = (), config: TrainConfig = TrainConfig(),
                 dataset_cache: Path | None = None, command: list[str] | None = None,
                 progress=None, features_from: str = "estimate", minus_link_bias: bool = False) -> dict:
    """Build the dataset, split by flight, train, write OUT (model JSON) and its provenance.
    With `all_flights`, no flight is held out for testing: every flight but the
    validation ones trains (how transfer is measured instead: benchmarks/bias_validation.py).
    With `minus_link_bias`, the labels are what the calibrated link bias leaves of each
    error (the simulator's `learned_bias` beside `link_bias`); a restart is then chosen
    by its validation TDOA error, since a correction of a part of the error is not
    scored in closed loop."""
    torch = import_torch()
    samples, latency = load_or_build_dataset(flights, dataset_cache, progress, features_from)
    labels = {}
    if minus_link_bias:
        from rig.bias.calibrate import samples_link_bias
        from rig.sim.effects import calibrated_link_bias

        coeffs = np.array(calibrated_link_bias())
        samples = replace(samples, label=samples.label - samples_link_bias(samples, flights, latency, coeffs))
        config = replace(config, select_by="mse")
        labels = {"labels": "measured - true TDOA - calibrated link_bias", "link_bias_coeffs_m": coeffs.tolist()}
    names = sorted(set(samples.flight.tolist()))
    test = [n for n in names if any(n.startswith(p) for p in test_prefixes)] if test_prefixes else None
    if test_prefixes and not test:
        raise ValueError(f"no flight name starts with {test_prefixes}")
    split = split_flights(names, config.seed, [] if all_flights else test)
    net, report = fit(samples, split, config, exclude_anchors, progress,
                      flight_dir=Path(flights[0]).parent if flights else None)
    out.parent.mkdir(parents=True, exist_ok=True)
    net.save(out)
    provenance = {"model": out.name, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                  "command": command or [], "data_dir": str(Path(flights[0]).parent) if flights else "",
                  "flights": names, "ground_truth_latency_s": latency, "torch": torch.__version__,
                  "mkl_cbwr": os.environ.get("MKL_CBWR"), "cpu": cpu_identity(),
                  "features": config.features, "features_from": features_from, **labels, **report}
    write_text_whole(provenance_path(out), json.dumps(provenance, indent=2) + "\n")
    return provenance
