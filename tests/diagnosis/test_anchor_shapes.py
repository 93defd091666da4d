"""benchmarks/anchor_shapes.py on a made-up flight: a displaced anchor and one anchor's
own link-bias gain, made by geometry and by the simulator's LinkBias with tilted
anchors, are each found by the model that has them, and each model's counts say so;
and lever_arm_loads.py's summary, whose flights anchor_shapes.py reads."""

from __future__ import annotations

import sys

import numpy as np
from rigtest import ROOT
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(ROOT / "benchmarks"))
import anchor_shapes  # noqa: E402  - the benchmark's fits
import lever_arm_loads  # noqa: E402

from rig.sim.effects import link  # noqa: E402

ANCHORS = {k: np.array([sx * 4.0, sy * 4.0, z]) for k, (sx, sy, z) in
           enumerate([(1, 1, 0.2), (-1, 1, 0.2), (-1, -1, 0.2), (1, -1, 0.2),
                      (1, 1, 2.8), (-1, 1, 2.8), (-1, -1, 2.8), (1, -1, 2.8)])}
# tilted and turned as the shared flights' anchors are, the ceiling ones upside down
FRAMES = {k: Rotation.from_euler("xyz", [180.0 * (p[2] > 1.5), 25.0, 45.0 * k], degrees=True).as_matrix()
          for k, p in ANCHORS.items()}
COEFFS = np.asarray(link.calibrated_link_bias())


def _flight(moved: dict[int, np.ndarray] = {}, gain: dict[int, float] = {}) -> lever_arm_loads.FlightLinks:
    """A tag circling at changing heights, every TDOA's error made by anchors standing
    `moved` from their survey and anchors whose links carry `gain` × the calibrated bias."""
    rng = np.random.default_rng(0)
    n = 6000
    phase = np.linspace(0, 6 * np.pi, n)
    position = np.column_stack([1.5 * np.cos(phase), 1.5 * np.sin(phase), 1.2 + 0.5 * np.sin(0.37 * phase)])
    rotation = Rotation.from_euler("xyz", rng.normal(0, 0.05, (n, 3)))
    id_a = rng.integers(0, 8, n)
    id_b = (id_a + rng.integers(1, 8, n)) % 8

    def range_bias(ids: np.ndarray) -> np.ndarray:
        true = np.array([ANCHORS[int(k)] + moved.get(int(k), 0.0) for k in ids])
        surveyed = np.array([ANCHORS[int(k)] for k in ids])
        frames = np.array([FRAMES[int(k)] for k in ids])
        beta = link.LinkBias(COEFFS).link_values(position, rotation, surveyed, frames)
        own = np.array([gain.get(int(k), 0.0) for k in ids])
        return np.linalg.norm(true - position, axis=1) - np.linalg.norm(surveyed - position, axis=1) + own * beta

    error = range_bias(id_b) - range_bias(id_a)
    return lever_arm_loads.FlightLinks(error, position, rotation, id_a, id_b, ANCHORS, FRAMES, np.arange(n) * 0.01)


def test_a_displaced_anchor_is_found_by_the_displacements_and_not_by_the_gains() -> None:
    shapes = anchor_shapes.flight_shapes(_flight(moved={2: np.array([0.05, -0.04, 0.03])}), COEFFS)
    assert shapes["displaced"]["residual_std_m"] < 1e-3 < shapes["anchor_gain"]["residual_std_m"]
    sizes = shapes["displaced"]["displacement_m"]
    assert abs(sizes[2] - np.linalg.norm([0.05, -0.04, 0.03])) < 0.01
    assert max(sizes[:2] + sizes[3:]) < 0.01 and shapes["displaced"]["displacements_beyond"] == 0


def test_one_anchors_own_gain_is_found_by_the_gains_within_bound() -> None:
    shapes = anchor_shapes.flight_shapes(_flight(gain={3: 0.6}), COEFFS)
    fitted = shapes["anchor_gain"]
    assert fitted["residual_std_m"] < 1e-3 < shapes["base"]["residual_std_m"]
    assert abs(fitted["anchor_gain"][3] - 0.6) < 0.02 and fitted["anchor_gains_beyond"] == 0


def test_the_summary_counts_what_lies_beyond_the_bounds() -> None:
    far = anchor_shapes.flight_shapes(_flight(gain={3: 6.0, 5: -0.2}), COEFFS)
    near = anchor_shapes.flight_shapes(_flight(gain={1: 0.5}), COEFFS)
    overall = anchor_shapes.summary({"far": far, "near": near})
    assert overall["anchor_gain"]["anchor_gains_beyond"] == "2 of 16"
    assert overall["displaced"]["displacements_beyond"].endswith("of 16")
    assert set(overall) == set(anchor_shapes.MODELS)


def test_the_gains_agreement_is_the_share_of_flights_on_the_medians_side() -> None:
    agreement = anchor_shapes.gain_agreement(np.array([[1.0, -2.0], [2.0, 3.0], [-1.0, -1.0]]))
    assert agreement == {"anchor_gain_median": [1.0, -1.0], "anchor_gain_sign_agreement": [0.67, 0.67]}


def test_the_lever_arm_summary_counts_components_beyond_the_airframe_per_model() -> None:
    def flight(z: float, x: float) -> dict:
        return {"base": {"lever": [x, 0.0, z]}, "link": {"lever": [x, 0.0, z], "link": [1.0 + z]},
                "link+kind": {"lever": [x, 0.0, 0.0], "link": [1.0], "kind": [z, -z]}}
    overall = lever_arm_loads.summary({"0425-a": flight(-0.3, 0.1), "0425-b": flight(0.1, 0.2), "0426-a": flight(0.5, 0.0)})
    assert overall["base"] == {"flights": 3, "z_beyond": 2, "horizontal_beyond": 1}
    assert overall["link"]["link_gain_range"] == [0.7, 1.5]
    assert overall["link+kind"]["z_beyond"] == 0
    assert overall["link+kind"]["kind_median_by_day"] == {"0425": [-0.1, 0.1], "0426": [0.5, -0.5]}


def test_displacements_the_same_on_every_flight_of_a_day_are_foretold_by_the_others() -> None:
    same = {"displacement_vectors_m": [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], "displacement_se_m": [0.0, 0.0]}
    results = {"0425-a": {"displaced": same}, "0425-b": {"displaced": same},
               "0426-a": {"displaced": {"displacement_vectors_m": [[1.0, 0.0, 0.0]], "displacement_se_m": [0.5]}},
               "0426-b": {"displaced": {"displacement_vectors_m": [[-1.0, 0.0, 0.0]], "displacement_se_m": [0.5]}},
               "0422-a": {"displaced": same}}
    # 0426: each flight against the other's opposite leaves 4 times its own square; its
    # noise, 0.25 of its own and 0.25 of the other's, would have left 0.5
    assert anchor_shapes.displacement_stability(results) == {"0425": {"left": 0.0, "left_by_their_noise": 0.0},
                                                             "0426": {"left": 4.0, "left_by_their_noise": 0.5}}
