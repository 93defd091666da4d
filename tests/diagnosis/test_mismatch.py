"""Where the untouched simulation and a recording differ (rig.diagnosis.mismatch): an effect
injected into a simulated flight shows on its anchor and its anchor pairs, in its
region of space and at its viewing angles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from diagnosis_cases import sim_config

from rig.diagnosis.channels import Problem
from rig.diagnosis.mismatch import ANGLE_BIN_DEG, locate
from rig.sim import effects as fx
from rig.sim.simulate import simulate

pytestmark = pytest.mark.slow        # left out of `make test-fast`

LOCATED_M = 0.08       # a robust mean within this of the injected size (TDOA noise 0.15 m, 3 % outliers)


def _located(survey: Path, effect: str, params: dict) -> tuple[Problem, dict]:
    problem = Problem(simulate(sim_config(survey, [{"effect": effect, "params": params}])))
    return problem, locate(problem, {"tdoa": problem.channel("tdoa").residual})


def test_a_delay_shows_on_its_anchor_and_on_every_pair_with_it(survey_0425: Path) -> None:
    """Anchor 7: the ring's pair (7, 0) is recorded the other way round."""
    _, where = _located(survey_0425, "anchor_delay", {"anchor": 7, "meters": 0.3})
    per_anchor = where["tdoa_per_anchor_m"]
    assert max(per_anchor, key=lambda k: abs(per_anchor[k])) == "7"
    assert {"0-7", "6-7"} <= set(where["tdoa_per_pair_m"])
    for pair, c in where["tdoa_per_pair_m"].items():
        a, b = map(int, pair.split("-"))
        want = 0.3 if b == 7 else 0.0                           # the later anchor's range against the earlier's
        assert abs(c["mean_m"] - want) < LOCATED_M, f"pair {pair}: {c['mean_m']:+.3f} m, want {want:+.1f}"


def test_an_nlos_shows_in_its_region_on_its_anchor(survey_0425: Path) -> None:
    region = {"min": [-9.0, -9.0, -9.0], "max": [0.0, 9.0, 9.0]}
    _, where = _located(survey_0425, "nlos", {"anchor": 6, "fraction": 1.0, "mean_excess_m": 0.5, "region": region})
    cells = [c for c in where["tdoa_per_region"] if "anchor" in c]
    inside = [c for c in cells if c["region"]["max"][0] <= 0.0]
    outside = [c for c in cells if c["region"]["min"][0] >= 0.0]
    assert inside and outside
    assert all(c["anchor"] == 6 and c["anchor_mean_m"] > 0.2 for c in inside), inside
    assert all(abs(c["anchor_mean_m"]) < LOCATED_M for c in outside), outside
    worst = where["tdoa_per_region"][0]
    assert worst["region"]["max"][0] <= 0.0, "the largest mismatch is in the NLOS region"


def test_a_pattern_shows_at_the_viewing_angles_it_biases(survey_0425: Path) -> None:
    coeffs = np.array([0.0, 0.6, 0.0])
    problem, where = _located(survey_0425, "antenna_pattern", {"anchor": 2, "coeffs_m": coeffs.tolist()})
    azimuth, elevation = fx.viewing_angles(problem.predictor.tdoa([]), problem.predictor.world([]), 2)
    azimuth, elevation = azimuth[problem.tdoa_rows], elevation[problem.tdoa_rows]
    seen = problem.anchor_sign(2) != 0
    bins = where["tdoa_per_viewing_angle"]["2"]
    assert len(bins) >= 2
    for b in bins:
        rows = seen & _within(np.degrees(azimuth), b["azimuth_deg"]) & _within(np.degrees(elevation),
                                                                             b["elevation_deg"])
        assert rows.sum() == b["samples"]
        want = float(np.mean(fx.pattern_basis(azimuth[rows], elevation[rows]) @ coeffs))
        assert abs(b["mean_m"] - want) < LOCATED_M, f"{b}: want {want:+.3f} m"
    assert np.ptp([b["mean_m"] for b in bins]) > 0.2, "the bins tell the angles apart"
    assert all(b["azimuth_deg"][1] - b["azimuth_deg"][0] == ANGLE_BIN_DEG for b in bins)


def _within(values: np.ndarray, span: list[float]) -> np.ndarray:
    return (values >= span[0]) & (values < span[1])
