"""The box scan both NLOS finders use, on synthetic residuals whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from rig.diagnosis.confined import find_region, nlos_shape
from rig.diagnosis.region_scan import GRID_BINS, BoxScan

N = 3000


def _positions(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2, 2, N), rng.normal(0, 1, N), rng.uniform(0.3, 1.8, N)])


def test_box_sums_are_the_sums_over_the_samples_each_box_holds() -> None:
    positions = _positions(1)
    values = np.random.default_rng(2).normal(size=N)
    scan = BoxScan(positions, 0.05, 0.9)
    assert 0 < len(scan.n_in) < (GRID_BINS * (GRID_BINS + 1) // 2) ** 2      # some boxes are too small or large
    sums, total = scan.sums(values)
    assert np.isclose(total, values.sum())
    for b in np.random.default_rng(3).choice(len(sums), 25, replace=False):
        score = np.full(len(sums), -np.inf)
        score[b] = 1.0
        inside = scan.best(score).contains(positions)
        assert inside.sum() == scan.n_in[b]
        assert np.isclose(values[inside].sum(), sums[b])
        assert 0.05 * N <= inside.sum() <= 0.9 * N


def test_no_box_scores_no_region() -> None:
    scan = BoxScan(_positions(1), 0.05, 0.9)
    assert scan.best(np.full(len(scan.n_in), -np.inf)) is None


def test_ranges_that_read_long_in_part_of_the_room_are_found_there() -> None:
    positions = _positions(4)
    rng = np.random.default_rng(5)
    shifted = (positions[:, 0] > 0.5) & (positions[:, 1] > 0.0)          # about a fifth of the samples
    s = rng.normal(size=N) + 0.6 * shifted
    region = find_region(positions, s, np.ones(N, bool))
    assert region is not None
    found = region.contains(positions)
    assert (found & shifted).sum() / (found | shifted).sum() > 0.7


def test_only_the_samples_of_the_anchor_count() -> None:
    positions = _positions(6)
    s = np.random.default_rng(7).normal(size=N)
    involved = positions[:, 0] < 0.0
    s[~involved] += 5.0                  # another anchor's ranges: not this one's region
    region = find_region(positions, s, involved)
    assert region is None or region.high[0] <= 0.0


def test_an_nlos_shape_keeps_its_mean_shift_within_the_physical_excess() -> None:
    """A small mean shift over a much wider spread inside the region reads, by moments,
    as a rare excess of metres; held at the bound, the fraction grows to keep the shift."""
    rng = np.random.default_rng(0)
    outside = rng.normal(0.0, 0.1, 2000)
    inside = rng.normal(0.0, 0.6, 2000)
    shift = 0.03
    free = nlos_shape(inside, outside, shift)
    held = nlos_shape(inside, outside, shift, largest_excess=1.0)
    assert free[1] > 1.0
    assert held[1] == 1.0 and held[0] * held[1] == pytest.approx(shift)
    wide = nlos_shape(inside, outside, 1.4, largest_excess=1.0)        # a shift beyond the bound stays beyond
    assert wide == (1.0, 1.4)
