"""Anchor delays as a calibration of their installation: found in a flight's TDOA
errors, removed from its labels, kept per installation, and applied by the model only
to a recording of that installation."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from rig.bias.dataset import Samples
from rig.bias.delays import flight_delays, installations, undelayed
from rig.estimator.bias_net import ANCHORS, BiasNet, Installation, identity_probe_net

SURVEY = """anchorAnt0,-3.0,-4.0,0.2
anchorAnt1,-3.0,4.0,2.9
anchorAnt2,4.0,4.0,0.2
anchor0_1,-3.0,-4.0,0.3
anchor0_2,-2.9,-4.1,0.1
anchor0_3,-2.9,-3.9,0.1
anchor1_1,-3.0,4.0,2.8
anchor1_2,-2.9,3.9,3.0
anchor1_3,-2.9,4.1,3.0
anchor2_1,4.0,4.0,0.3
anchor2_2,4.1,4.1,0.1
anchor2_3,4.1,3.9,0.1
"""


def _samples(delays: dict[str, list[float]], rng: np.random.Generator, n: int = 2000) -> tuple[Samples, np.ndarray]:
    """Flights of three anchors whose TDOA errors are their delays' differences, a
    pattern that is no delay (zero mean on every pair) and noise; also the pattern."""
    parts, patterns = [], []
    for name, d in delays.items():
        ia = rng.integers(0, 3, n)
        ib = (ia + 1 + rng.integers(0, 2, n)) % 3
        pattern = 0.1 * np.sin(np.linspace(0, 40 * np.pi, n))
        label = np.asarray(d)[ib] - np.asarray(d)[ia] + pattern + rng.normal(0, 0.02, n)
        parts.append(Samples(np.zeros((n, 14), np.float32), label, np.full(n, name), ia, ib, np.arange(n) * 0.01))
        patterns.append(pattern)
    return Samples.concatenate(parts), np.concatenate(patterns)


def test_a_flights_delays_are_found_up_to_their_mean_and_removed(rng=np.random.default_rng(3)) -> None:
    samples, pattern = _samples({"0101-a": [0.1, -0.05, 0.2], "0101-b": [0.0, 0.0, 0.0]}, rng)
    found = flight_delays(samples)
    # TDOA sees differences only: the delays less their mean, NaN for anchors never measured
    np.testing.assert_allclose(found["0101-a"][:3], np.array([0.1, -0.05, 0.2]) - 0.25 / 3, atol=0.005)
    assert np.isnan(found["0101-a"][3:]).all()
    np.testing.assert_allclose(found["0101-b"][:3], 0.0, atol=0.005)
    left = undelayed(samples, found).label
    assert np.std(left - pattern) < 0.025             # what is left is the pattern and the noise
    assert np.std(samples.label - pattern) > 0.1


def test_each_installation_keeps_the_median_of_its_flights(tmp_path, rng=np.random.default_rng(4)) -> None:
    (tmp_path / "flights").mkdir()
    (tmp_path / "surveys").mkdir()
    (tmp_path / "surveys" / "anchor_0101.txt").write_text(SURVEY)
    (tmp_path / "surveys" / "anchor_0102.txt").write_text(SURVEY.replace("anchorAnt2,4.0,4.0,0.2", "anchorAnt2,4.0,4.0,0.25"))
    delays = {"0101-a": [0.1, -0.1, 0.0], "0101-b": [0.12, -0.1, -0.02], "0101-c": [0.3, -0.1, -0.2],
              "0102-a": [-0.1, 0.0, 0.1]}
    samples, _ = _samples(delays, rng)
    found = installations(flight_delays(samples), tmp_path / "flights")
    assert len(found) == 2
    first = next(i for i in found if abs(i.anchors[2][2] - 0.2) < 1e-9)
    expected = np.median([np.array(d) - np.mean(d) for k, d in delays.items() if k.startswith("0101")], axis=0)
    np.testing.assert_allclose([first.delays[k] for k in range(3)], expected, atol=0.01)


def _anchors(positions: dict[int, list[float]]) -> list:
    return [SimpleNamespace(id=k, position=tuple(p)) for k, p in positions.items()]


def test_a_model_applies_an_installations_delays_only_to_that_installation(tmp_path) -> None:
    here = {0: [-3.0, -4.0, 0.2], 1: [-3.0, 4.0, 2.9], 2: [4.0, 4.0, 0.2]}
    room = Installation(here, {0: 0.05, 1: -0.1, 2: 0.05})
    net = replace(identity_probe_net(0, form="link"), installations=[room])
    assert net.for_installation(_anchors(here)).offsets(np.arange(3)).tolist() == [0.05, -0.1, 0.05]
    # a millimetre elsewhere is another survey, another installation: the network alone
    moved = {**here, 2: [4.0, 4.001, 0.2]}
    assert net.for_installation(_anchors(moved)).anchor_offset is None
    assert net.for_installation(_anchors({0: here[0], 1: here[1]})).anchor_offset is None
    # the file keeps them, and the board gets them as the link form's anchor offsets
    net.save(tmp_path / "m.json")
    again = BiasNet.load(tmp_path / "m.json")
    assert json.loads((tmp_path / "m.json").read_text())["installations"][0]["delays_m"] == {"0": 0.05, "1": -0.1, "2": 0.05}
    packed = again.for_installation(_anchors(here)).pack()
    assert np.allclose(packed["link"]["anchor_offset"][0][:3], [0.05, -0.1, 0.05])
    assert not packed["link"]["anchor_offset"][0][3:ANCHORS].any()


def test_a_delay_beyond_an_antenna_delay_is_refused() -> None:
    with pytest.raises(ValueError, match="within"):
        Installation({0: [0, 0, 0]}, {0: 0.5})
    with pytest.raises(ValueError, match="its own anchors"):
        Installation({0: [0, 0, 0]}, {1: 0.1})
