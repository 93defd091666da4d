"""The floor multipath's steps (rig.diagnosis.floor_error.floor_multipath) on noise drawn with
known steps, and the effect that simulates them (rig.sim.effects.MultipathFloor)."""

from __future__ import annotations

from dataclasses import replace

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rig.diagnosis.findings import Finding
from rig.diagnosis.floor_error import ON_GROUND_M, floor_multipath, local_noise
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


def _take_offs(pairs: int, per_pair: int, rng) -> tuple[SimpleNamespace, np.ndarray]:
    """A problem's TDOA rows as local_noise reads them, and the tag's heights: `pairs`
    anchor pairs heard at random (as in TDOA3) over a minute in which the tag sits on
    the floor for 10 s, climbs to 1.5 m in 5 s, flies there and comes down again."""
    n = pairs * per_pair
    t = np.sort(rng.uniform(0.0, 60.0, n))
    heights = np.interp(t, [0.0, 10.0, 15.0, 45.0, 50.0, 60.0], [0.02, 0.02, 1.5, 1.5, 0.02, 0.02])
    pair = rng.permutation(np.repeat(np.arange(pairs), per_pair))
    tdoa = SimpleNamespace(id_a=pair // 8, id_b=pair % 8 + 8, t=t)
    problem = SimpleNamespace(rec=SimpleNamespace(tdoa=tdoa), tdoa_rows=np.arange(n),
                              tag_positions=lambda: np.column_stack([np.zeros(n), np.zeros(n), heights]))
    return problem, heights


def test_the_step_of_a_tag_on_the_floor_is_not_read_as_noise_near_it() -> None:
    """Ranges 1.5 m longer with the tag below ON_GROUND_M (on_ground_delay, not
    modelled here) and white noise elsewhere: the running median is taken within each
    regime, so no floor multipath shows above it. Windows straddling the step would
    read half the step as noise in the first and last airborne samples of each pair."""
    rng = np.random.default_rng(8)
    problem, heights = _take_offs(28, 60, rng)
    residual = rng.normal(0.0, 0.1, len(heights)) + 1.5 * (heights < ON_GROUND_M)
    noise = local_noise(problem, residual)
    airborne = heights >= ON_GROUND_M
    assert np.std(noise[airborne]) == pytest.approx(0.1, rel=0.1)
    assert floor_multipath(noise, heights, BAR) is None


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
