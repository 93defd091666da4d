"""The sizes below which a trajectory cannot show an effect or tell it from its
look-alikes (rig.diagnosis.identifiability), on columns whose answer is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from rig.diagnosis.identifiability import assess

pytestmark = pytest.mark.slow        # left out of `make test-fast`

BAR = 10.0          # half a chi-square an effect must remove to be named


def _orthogonal(v: np.ndarray, to: np.ndarray) -> np.ndarray:
    return v - to * (to @ v) / (to @ to)


def test_only_what_the_look_alike_cannot_fit_tells_an_effect_from_it() -> None:
    """A column that is twice its look-alike's plus a small part of its own: it shows
    at the size where its whole column removes BAR, and is told apart only where its
    own part does (½ a² ε² |u|² = BAR)."""
    rng = np.random.default_rng(0)
    alike = rng.normal(size=400)
    own = _orthogonal(rng.normal(size=400), alike)
    eps = 0.05
    column = 2.0 * alike + eps * own
    result = assess("anchor_position", [3], "offset_m", column[:, None], {"anchor_delay": alike[:, None]}, BAR, 1.0)
    assert result.smallest_seen == pytest.approx(np.sqrt(2 * BAR / (column @ column)), rel=1e-3)
    assert result.smallest_told_apart == pytest.approx(np.sqrt(2 * BAR / (eps ** 2 * (own @ own))), rel=1e-3)
    assert result.told_apart == (result.smallest_told_apart <= 1.0)
    assert result.to_json()["anchors"] == [3] and result.to_json()["unit"] == "m"


def test_an_effect_its_look_alike_fits_whole_is_never_told_apart() -> None:
    alike = np.random.default_rng(1).normal(size=(300, 1))
    result = assess("antenna_pattern", [2], "coeffs_m", 0.5 * alike, {"anchor_delay": alike}, BAR, 1.0)
    assert result.smallest_seen is not None
    assert result.smallest_told_apart is None and not result.told_apart
    assert result.to_json()["smallest_told_apart"] is None            # JSON null, not NaN or Infinity


def test_a_vector_is_told_apart_first_along_the_direction_it_shows_best() -> None:
    """Two components with orthogonal columns, the second three times the first's:
    the best direction is the second's, and every direction is told apart from the
    size at which the first's is."""
    rng = np.random.default_rng(2)
    a = rng.normal(size=500)
    u = _orthogonal(rng.normal(size=500), a)
    b = 3.0 * u * np.linalg.norm(a) / np.linalg.norm(u)
    result = assess("lever_arm", [], "offset_m", np.stack([a, b], axis=1), {}, BAR, 0.5)
    assert result.smallest_told_apart == pytest.approx(np.sqrt(2 * BAR / (b @ b)), rel=1e-3)
    assert result.every_direction == pytest.approx(np.sqrt(2 * BAR / (a @ a)), rel=1e-3)
    assert np.abs(result.direction) == pytest.approx([0.0, 1.0], abs=1e-3)
    assert result.smallest_seen == result.smallest_told_apart           # no look-alike: seen is told apart


def test_a_direction_between_the_best_and_the_worst_is_told_apart_in_between() -> None:
    """Along a component the size is that component's alone; along the diagonal of two
    orthogonal columns, √(2 BAR / ½(|a|² + |b|²)), between the best and the worst."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=500)
    b = 2.0 * _orthogonal(rng.normal(size=500), a)
    result = assess("lever_arm", [], "offset_m", np.stack([a, b], axis=1), {}, BAR, 0.5)
    assert result.told_apart_along([0.3, 0.0]) == pytest.approx(result.every_direction, rel=1e-3)
    assert result.told_apart_along([0.0, -2.0]) == pytest.approx(result.smallest_told_apart, rel=1e-3)
    assert result.told_apart_along([1.0, 1.0]) == pytest.approx(np.sqrt(4 * BAR / (a @ a + b @ b)), rel=1e-3)
    assert result.told_apart_along([0.0, 0.0]) is None
    whole = assess("antenna_pattern", [2], "coeffs_m", a[:, None], {"anchor_delay": a[:, None]}, BAR, 1.0)
    assert whole.told_apart_along(0.3) is None


def test_an_effect_named_axis_by_axis_is_told_apart_at_the_bar_of_the_axes_it_moves() -> None:
    """Three orthogonal columns of equal norm, no look-alike: along one axis the size
    where it removes the bar of one axis, along the diagonal that of three; without
    `axis_bars`, the bar of three everywhere."""
    q = np.linalg.qr(np.random.default_rng(1).normal(size=(300, 3)))[0] * 4.0
    bars = (10.0, 12.0, 14.0)
    result = assess("imu_gyro_scale", [], "scale", q, {}, bars[-1], 0.5, bars)
    whole = assess("imu_gyro_scale", [], "scale", q, {}, bars[-1], 0.5)
    assert result.told_apart_along([0.0, 0.0, 0.1]) == pytest.approx(np.sqrt(2 * 10.0 / 16.0), rel=1e-3)
    assert result.told_apart_along([0.1, 0.1, 0.1]) == pytest.approx(np.sqrt(2 * 14.0 / 16.0), rel=1e-3)
    assert whole.told_apart_along([0.0, 0.0, 0.1]) == pytest.approx(np.sqrt(2 * 14.0 / 16.0), rel=1e-3)
    assert result.smallest_told_apart < whole.smallest_told_apart
    assert result.every_direction == whole.every_direction


@pytest.mark.parametrize("effect, param, seed", [("antenna_pattern", "coeffs_m", 4), ("imu_accel_scale", "scale", 5)])
def test_sizes_are_as_the_bound_measures_them(effect: str, param: str, seed: int) -> None:
    """A pattern's size is peak to peak, an IMU scale's its largest axis: over a dense
    sample of amounts, the smallest size whose ½ aᵀGa reaches the bar in some direction
    and the size from which it does in every direction match, and told_apart_along
    and size agree with them along any direction."""
    from rig.diagnosis.diagnose import bound_measure

    measure = bound_measure(effect, param)
    columns = np.random.default_rng(seed).normal(size=(200, 3)) * [1.0, 0.3, 2.0]
    result = assess(effect, [], param, columns, {}, BAR, 1.0, measure=measure)
    gram = columns.T @ columns
    u = np.random.default_rng(6).normal(size=(40_000, 3))
    u /= np.array([measure(v) for v in u])[:, None]                   # each of size 1
    shown = np.einsum("ni,ij,nj->n", u, gram, u)
    assert result.smallest_told_apart == pytest.approx(np.sqrt(2 * BAR / shown.max()), rel=2e-3)
    assert result.smallest_told_apart <= np.sqrt(2 * BAR / shown.max()) * (1 + 1e-4)   # none beats it
    assert result.every_direction == pytest.approx(np.sqrt(2 * BAR / shown.min()), rel=2e-3)
    assert result.every_direction >= np.sqrt(2 * BAR / shown.min()) * (1 - 1e-4)
    best = np.array(result.direction)
    assert result.told_apart_along(best) == pytest.approx(result.smallest_told_apart, rel=1e-3)
    assert result.size(0.5 * best / measure(best)) == pytest.approx(0.5)
    euclidean = assess(effect, [], param, columns, {}, BAR, 1.0)
    assert euclidean.smallest_told_apart != pytest.approx(result.smallest_told_apart, rel=1e-2)


def test_an_effect_named_axis_by_axis_is_told_apart_first_on_the_axes_that_pay_least() -> None:
    """With a bar per number of axes moved, the smallest size is the least over every
    set of axes of the size at which that set's best amount reaches its bar; an IMU
    scale measured by its largest axis reaches its largest form on the set's corners."""
    from itertools import combinations

    from rig.diagnosis.diagnose import bound_measure

    measure = bound_measure("imu_accel_scale", "scale")
    columns = np.random.default_rng(7).normal(size=(200, 3)) * [1.0, 0.8, 1.2]
    bars = (10.0, 11.0, 30.0)
    result = assess("imu_accel_scale", [], "scale", columns, {}, bars[-1], 0.15, bars, measure)
    gram, u = columns.T @ columns, np.random.default_rng(8).normal(size=(20_000, 3))
    sizes = []
    for k, bar in enumerate(bars, 1):
        for axes in combinations(range(3), k):
            on = np.zeros_like(u)
            on[:, axes] = u[:, axes]
            on /= np.abs(on).max(axis=1)[:, None]                      # largest axis 1
            sizes.append(np.sqrt(2 * bar / np.einsum("ni,ij,nj->n", on, gram, on).max()))
    assert result.smallest_told_apart == pytest.approx(min(sizes), rel=2e-3)
    assert result.told_apart_along(result.direction) == pytest.approx(result.smallest_told_apart, rel=1e-3)
