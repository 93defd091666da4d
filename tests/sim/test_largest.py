"""How much a per-anchor effect changes its anchor's ranges over a flight, and where
most (`largest`: what `rig diagnose` reports for a displacement or a pattern, whatever
its parameters): checked against the simulator's own code for the effect."""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import FULL_PRECISION

from rig.sim.effects import make_effect
from rig.sim.effects.base import ranges
from rig.sim.simulate import Predictor, SimConfig, simulate

ANCHOR = 3


@pytest.fixture(scope="module")
def flight(survey_0425: Path):
    rec = simulate(SimConfig(trajectory="circle-sine", duration=8.0, survey=str(survey_0425),
                             resolution=dict(FULL_PRECISION), effects=[]))
    predictor = Predictor(rec)
    return predictor.tdoa([]), predictor.world([])


def _on_anchor(tdoa) -> tuple[np.ndarray, np.ndarray]:
    """The rows with ANCHOR, and +1 where it is anchor B (its range counts positively)."""
    rows = np.flatnonzero((tdoa.id_a == ANCHOR) | (tdoa.id_b == ANCHOR))
    return rows, np.where(tdoa.id_b[rows] == ANCHOR, 1.0, -1.0)


def test_a_displacement_changes_its_anchors_ranges_as_moving_it_does(flight) -> None:
    tdoa, world = flight
    effect = make_effect("anchor_position", {"anchor": ANCHOR, "offset_m": [0.06, -0.08, 0.05]})
    moved = copy.deepcopy(world)
    effect.apply_world(moved)
    rows, _ = _on_anchor(tdoa)
    ids = np.full(len(rows), ANCHOR)
    change = ranges(tdoa.tag_position[rows], moved, ids) - ranges(tdoa.tag_position[rows], world, ids)
    where = effect.largest(tdoa, world, np.arange(len(tdoa.t)))
    assert where["anchors"] == [ANCHOR] and list(where["spread_m"]) == [str(ANCHOR)]
    assert where["spread_m"][str(ANCHOR)] == pytest.approx(np.std(change), abs=2e-4)     # first order
    assert where["largest"]["sign"] in ("long", "short")


def test_a_pattern_changes_its_anchors_ranges_as_the_simulator_applies_it(flight) -> None:
    tdoa, world = flight
    effect = make_effect("antenna_pattern", {"anchor": ANCHOR, "coeffs_m": [0.2, -0.1, 0.05]})
    applied = replace(tdoa, value=np.zeros(len(tdoa.t)))
    effect.apply_tdoa(applied, world, None)
    rows, sign = _on_anchor(tdoa)
    link = sign * applied.value[rows]          # each row's change of the anchor's own range
    where = effect.largest(tdoa, world, np.arange(len(tdoa.t)))
    assert where["spread_m"][str(ANCHOR)] == pytest.approx(np.std(link), abs=1e-4)      # rounded to 0.1 mm
    far = np.abs(link - link.mean()) >= np.quantile(np.abs(link - link.mean()), 0.9)
    assert where["largest"]["sign"] == ("long" if link[far].mean() > link.mean() else "short")
