"""The floor multipath's steps (rig.diagnosis.floor_error.floor_multipath) on noise drawn with
known steps, and the effect that simulates them (rig.sim.effects.MultipathFloor)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rig.diagnosis.findings import Finding
from rig.diagnosis.floor_error import floor_multipath
from rig.diagnosis.wording import describe
from rig.sim.effects import TdoaBatch, make_effect

pytestmark = pytest.mark.slow        # left out of `make test-fast`

BAR = 12.0          # what the diagnosis asks of the two parameters of a step
SAMPLES = 40000


def _noise(heights: np.ndarray, steps: list[tuple[float, float]], base: float, rng) -> np.ndarray:
    """Gaussian noise of `base`, plus each step's (height, std) below its height."""
    std = np.sqrt(base ** 2 + sum(s ** 2 * (heights < h) for h, s in steps))
    return rng.normal(0.0, 1.0, len(heights)) * std


def test_a_second_step_nearer_the_floor_is_told_from_the_flights_own() -> None:
    """A flight's own 0.05 m below 1.0 m and 0.2 m added below 0.6 m: one step reads
    below 1.0 m at a fraction of the 0.2; two read both."""
    rng = np.random.default_rng(5)
    heights = rng.uniform(0.2, 2.0, SAMPLES)
    floor = floor_multipath(_noise(heights, [(1.0, 0.08), (0.6, 0.2)], 0.1, rng), heights, BAR)
    assert (floor["height_m"], floor["upper_height_m"]) == (0.6, 1.0)
    assert floor["std_m"] == pytest.approx(0.2, abs=0.02)
    assert floor["upper_std_m"] == pytest.approx(0.08, abs=0.02)
    below = heights < 1.0
    assert floor["low"].tolist() == below.tolist()
    assert floor["sigma_rows"][heights < 0.6] == pytest.approx(np.sqrt(0.1 ** 2 + 0.08 ** 2 + 0.2 ** 2), rel=0.05)


def test_one_step_stays_one_step() -> None:
    rng = np.random.default_rng(6)
    heights = rng.uniform(0.2, 2.0, SAMPLES)
    floor = floor_multipath(_noise(heights, [(0.6, 0.2)], 0.1, rng), heights, BAR)
    assert floor["height_m"] == 0.6 and "upper_height_m" not in floor
    assert floor["std_m"] == pytest.approx(0.2, abs=0.02)
    assert floor_multipath(_noise(heights, [], 0.1, rng), heights, BAR) is None


def test_the_effect_adds_both_steps_noise_below_each_height() -> None:
    effect = make_effect("multipath_floor", {"height_m": 0.6, "std_m": 0.2, "upper_height_m": 1.0, "upper_std_m": 0.08})
    assert effect.params() == {"height_m": 0.6, "std_m": 0.2, "upper_height_m": 1.0, "upper_std_m": 0.08}
    heights = np.repeat([0.3, 0.8, 1.5], SAMPLES)
    n = len(heights)
    positions = np.column_stack([np.zeros(n), np.zeros(n), heights])
    batch = TdoaBatch(np.arange(n) * 0.01, np.zeros(n, int), np.ones(n, int), positions, Rotation.identity(n),
                      np.zeros(n))
    effect.apply_tdoa(batch, None, np.random.default_rng(7))
    spread = [np.std(batch.value[heights == h]) for h in (0.3, 0.8, 1.5)]
    assert spread == pytest.approx([np.hypot(0.2, 0.08), 0.08, 0.0], abs=0.005)
    with pytest.raises(ValueError, match="upper_height_m must be a height above height_m"):
        make_effect("multipath_floor", {"height_m": 0.6, "std_m": 0.2, "upper_height_m": 0.5})


def test_a_floor_with_two_steps_is_said_with_both() -> None:
    two = Finding("multipath_floor", "tdoa", [], {"height_m": 0.6, "std_m": 0.2, "upper_height_m": 1.0,
                                                  "upper_std_m": 0.05}, 50.0, 0.0, -0.1, {})
    assert describe(two) == ("below 0.6 m the TDOA noise grows by 0.200 m, on top of 0.050 m below 1.0 m "
                             "(floor multipath)")
    one = replace(two, params={"height_m": 0.6, "std_m": 0.2})
    assert describe(one) == "below 0.6 m the TDOA noise grows by 0.200 m (floor multipath)"
