"""Where a bias model was trained (rig.estimator.trained_region): the cells of each
anchor's relative positions in training, carried in the model file, and `rig evaluate`'s
share of a flight's corrections made outside them, on a real flight."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rigtest import run_rig

from rig.bias.dataset import flight_samples
from rig.data.importer import load_any
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet, identity_probe_net
from rig.estimator.evaluate import evaluate
from rig.estimator.trained_region import CELL_M, TrainedRegion, outside_share


def _circle(radius: float, n: int = 400, height: float = 1.5) -> np.ndarray:
    angle = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.full(n, height)])


def _region_of(tag: np.ndarray, anchors: dict[int, np.ndarray]) -> TrainedRegion:
    """The region of measurements between every pair of `anchors` along `tag`."""
    ids = sorted(anchors)
    pairs = [(a, b) for a in ids for b in ids if a < b]
    features = np.zeros((len(tag) * len(pairs), 14))
    id_a = np.repeat([a for a, _ in pairs], len(tag))
    id_b = np.repeat([b for _, b in pairs], len(tag))
    features[:, 0:3] = np.array([anchors[k] for k in id_a]) - np.tile(tag, (len(pairs), 1))
    features[:, 3:6] = np.array([anchors[k] for k in id_b]) - np.tile(tag, (len(pairs), 1))
    return TrainedRegion.from_features(features, id_a, id_b)


ANCHORS = {0: np.array([-4.0, -4.0, 0.2]), 1: np.array([4.0, -4.0, 3.0]), 2: np.array([0.0, 4.0, 0.2])}


def test_the_training_circle_is_inside_and_the_rooms_centre_and_another_anchor_are_not() -> None:
    region = _region_of(_circle(1.5), ANCHORS)
    ring = _circle(1.5, 97)
    assert region.inside(ANCHORS[1] - ring, np.ones(len(ring), int)).all()
    near = _circle(1.5 + 0.6 * CELL_M, 97)
    assert region.inside(ANCHORS[1] - near, np.ones(len(near), int)).all(), "a neighbouring cell is inside"
    centre = _circle(0.1, 20)
    assert not region.inside(ANCHORS[1] - centre, np.ones(len(centre), int)).any()
    assert not region.inside(ANCHORS[1] - ring, np.full(len(ring), 5)).any(), "an anchor it never saw"


def test_the_share_outside_counts_a_measurement_with_either_link_outside() -> None:
    region = _region_of(_circle(1.5), ANCHORS)
    on, off = _circle(1.5, 50), _circle(0.1, 50)
    tag = np.vstack([on, off])
    a, b = np.tile(ANCHORS[0], (100, 1)), np.tile(ANCHORS[2], (100, 1))
    assert outside_share(region, a - tag, b - tag, np.zeros(100, int), np.full(100, 2)) == pytest.approx(0.5)
    assert outside_share(region, a[:50] - on, b[:50] - on, np.zeros(50, int), np.full(50, 7)) == 1.0
    assert outside_share(region, on[:0], on[:0], np.zeros(0, int), np.zeros(0, int)) == 0.0


def test_the_region_travels_with_the_model_file_and_a_malformed_one_is_refused(tmp_path: Path) -> None:
    net = identity_probe_net(0, form="link")
    net.region = _region_of(_circle(1.5), ANCHORS)
    net.save(tmp_path / "m.json")
    back = BiasNet.load(tmp_path / "m.json")
    ring = ANCHORS[0] - _circle(1.5, 31)
    assert back.region.inside(ring, np.zeros(31, int)).all()
    assert {k: v.tolist() for k, v in back.region.cells.items()} == {k: v.tolist() for k, v in net.region.cells.items()}
    assert back.quantized().region is back.region
    obj = json.loads((tmp_path / "m.json").read_text())
    obj["trained_region"] = {"cells": [1, 2]}
    with pytest.raises(ValueError, match="trained_region"):
        BiasNet.from_json(obj)
    with pytest.raises(ValueError, match="positive"):
        TrainedRegion({}, 0.0)


def test_rig_evaluate_reports_the_share_of_a_real_flight_outside_where_its_model_was_trained(
        tmp_path: Path, data_dir: Path) -> None:
    flight = data_dir / "flights" / "0425-traj1"
    rec = load_any(flight)
    own = flight_samples(rec, flight.name)
    net = BiasNet.load(DEFAULT_NETWORK)
    net.region = TrainedRegion.from_features(own.features, own.id_a, own.id_b)
    assert evaluate(rec, model=net)["outside_trained_region"] < 0.02, "trained on this very flight"
    away = own.features.copy()
    away[:, 0:6] += 3.0          # the same flight three metres away in every axis
    net.region = TrainedRegion.from_features(away, own.id_a, own.id_b)
    net.save(tmp_path / "elsewhere.json")
    proc = run_rig("evaluate", str(flight), "--model", str(tmp_path / "elsewhere.json"),
                   "--json", str(tmp_path / "result.json"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "result.json").read_text())["outside_trained_region"] == 1.0
    assert "100.0% of the measurements corrected with the tag outside" in proc.stdout
    assert "outside_trained_region" not in evaluate(rec, use_nn=False)
