"""Bias-network training: a learnable simulated bias is recovered, the split is by
flight, and the shipped model is reproduced by a fresh training."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rig import native
from rig.bias_dataset import Samples
from rig.evaluate import DEFAULT_MODEL
from rig.train import TrainConfig, provenance_path, run_training, split_flights, train


def synthetic_samples(n_flights: int, per_flight: int, seed: int) -> Samples:
    """Features of random tag positions in a real-sized room; the bias is a smooth function
    of the elevation of the tag in anchor A's frame (an antenna pattern) plus noise."""
    rng = np.random.default_rng(seed)
    anchors = np.array([[-3, -4, 0.2], [-3, 4, 3.0], [4, 4, 0.2], [4, -4, 3.0]], float)
    level = np.tile(np.eye(3), (1, 1, 1))
    parts = []
    for k in range(n_flights):
        n = per_flight
        tag = rng.uniform([-2, -2, 0.5], [2, 2, 2.5], (n, 3))
        ia = rng.integers(0, 4, n)
        ib = (ia + 1 + rng.integers(0, 3, n)) % 4
        rots = np.repeat(level, n, axis=0)
        feats = native.features_batch(tag, rots, anchors[ia], rots, anchors[ib], rots)
        bias = 0.3 * np.sin(2 * feats[:, 10]) + 0.1 * np.cos(feats[:, 6])
        label = bias + rng.normal(0, 0.05, n)
        parts.append(Samples(feats, label, np.full(n, f"sim{k}"), ia, ib, np.arange(n) * 0.02))
    return Samples.concatenate(parts)


def test_training_recovers_a_known_learnable_bias() -> None:
    data = synthetic_samples(6, 3000, seed=1)
    train_set = data.select(np.isin(data.flight, ["sim0", "sim1", "sim2", "sim3"]))
    val_set = data.select(data.flight == "sim4")
    test_set = data.select(data.flight == "sim5")
    net, _ = train(train_set, val_set, TrainConfig(max_epochs=40))
    residual = test_set.label - net.quantized().predict(test_set.features)
    assert test_set.label.std() > 0.15
    assert residual.std() < 0.07  # noise is 0.05: the bias itself is learned


def test_same_seed_same_network_other_seed_other_network() -> None:
    data = synthetic_samples(2, 1000, seed=2)
    train_set, val_set = data.select(data.flight == "sim0"), data.select(data.flight == "sim1")
    first, _ = train(train_set, val_set, TrainConfig(max_epochs=3, seed=5))
    second, _ = train(train_set, val_set, TrainConfig(max_epochs=3, seed=5))
    other, _ = train(train_set, val_set, TrainConfig(max_epochs=3, seed=6))
    x = val_set.features[:50]
    assert second.predict(x) == pytest.approx(first.predict(x), abs=1e-9)
    assert np.abs(other.predict(x) - first.predict(x)).max() > 1e-4


def test_split_is_by_flight_and_seeded() -> None:
    names = [f"f{k}" for k in range(35)]
    split = split_flights(names, seed=0)
    assert (len(split.train), len(split.validation), len(split.test)) == (24, 5, 6)
    assert not set(split.train) & set(split.validation) | set(split.train) & set(split.test)
    assert split == split_flights(names, seed=0) and split != split_flights(names, seed=1)
    held = split_flights(names, seed=0, test=["f0", "f1"])
    assert held.test == ["f0", "f1"] and "f0" not in held.train + held.validation


def test_fresh_training_reproduces_the_shipped_model(tmp_path: Path, data_dir: Path) -> None:
    shipped = json.loads(provenance_path(DEFAULT_MODEL).read_text())
    flights = sorted((data_dir / "flights").iterdir())
    assert [f.name for f in flights] == shipped["flights"]
    prov = run_training(flights, tmp_path / "bias_net.json", config=TrainConfig(seed=0))
    assert prov["split"] == shipped["split"]
    assert prov["validation"]["after"]["std"] == pytest.approx(shipped["validation"]["after"]["std"], abs=0.003)
    assert prov["validation"]["after"]["std"] < prov["validation"]["before"]["std"] - 0.02
    assert prov["test"]["after_int8"]["std"] == pytest.approx(prov["test"]["after"]["std"], abs=0.001)
