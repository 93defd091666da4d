"""The blocked-anchor weighting (anchor_bias_c): each anchor's range bias tracked from
the innovations, and the measurements of an anchor whose bias no position error
explains made less certain, where the anchor is paired with four others or more."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rigtest import run_rig, simulate_exact

from rig.estimator import metrics
from rig.estimator.evaluate import (StartPose, anchor_discounts, estimator_config, evaluate, replay, start_time,
                                    started, truth_pose_at)
from rig.estimator.native import default_params

DELAY_M = 0.4      # an obstacle's excess path on every link to one anchor


def flight(survey: Path, mode: str, delayed: bool):
    effects = [{"effect": "tdoa_noise", "params": {"std_m": 0.05}}]
    if delayed:
        effects.append({"effect": "anchor_delay", "params": {"anchor": 3, "meters": DELAY_M}})
    return simulate_exact(survey, duration=60.0, seed=5, uwb_mode=mode, effects=effects)


@pytest.fixture(scope="module")
def blocked_tdoa3(survey_0425: Path):
    return flight(survey_0425, "TDOA3", delayed=True)


def positions(rec, **params) -> np.ndarray:
    return replay(rec, *estimator_config(use_nn=False, **params)).position


def test_the_shipped_estimator_weights_blocked_anchors() -> None:
    assert default_params().anchor_bias_c == pytest.approx(0.15)


def test_a_blocked_anchor_paired_with_all_others_is_down_weighted(blocked_tdoa3) -> None:
    weighted = evaluate(blocked_tdoa3, use_nn=False)
    unweighted = evaluate(blocked_tdoa3, use_nn=False, anchor_bias_c=0.0)
    assert weighted["rmse_3d"] < 0.6 * unweighted["rmse_3d"]
    # counted: the blocked anchor's pairs, and its neighbours' (the fit gives them part of its
    # excess, and a weight just under 0.5)
    assert weighted["tdoa_anchor_weighted"] > 0.25 * weighted["tdoa_accepted"]
    assert unweighted["tdoa_anchor_weighted"] == 0


def test_tracking_alone_changes_no_estimate(blocked_tdoa3) -> None:
    """At a scale no bias reaches, every weight is 1: the tracking itself must not touch
    the update, so the estimates are those of the estimator without it, bit for bit."""
    np.testing.assert_array_equal(positions(blocked_tdoa3, anchor_bias_c=1e9),
                                  positions(blocked_tdoa3, anchor_bias_c=0.0))


def test_an_anchor_of_the_tdoa2_ring_is_never_weighted(survey_0425: Path) -> None:
    """In TDOA2 each anchor is paired with its two neighbours only: its measurements are a
    quarter of the geometry, and their split between anchors is barely redundant."""
    ring = flight(survey_0425, "TDOA2", delayed=True)
    np.testing.assert_array_equal(positions(ring), positions(ring, anchor_bias_c=0.0))
    assert evaluate(ring, use_nn=False)["tdoa_anchor_weighted"] == 0


def test_a_clean_flight_loses_nothing(survey_0425: Path) -> None:
    clean = flight(survey_0425, "TDOA3", delayed=False)
    weighted, unweighted = evaluate(clean, use_nn=False), evaluate(clean, use_nn=False, anchor_bias_c=0.0)
    assert abs(weighted["rmse_3d"] - unweighted["rmse_3d"]) < 0.002
    assert weighted["tdoa_anchor_weighted"] == 0


def test_a_position_error_is_not_read_as_a_blocked_anchor(survey_0425: Path) -> None:
    """Started 0.6 m off, the filter's innovations read as biases of the anchors, u_k . dp:
    what the weight is decided by has that part removed, so the filter comes back as fast
    as without the weighting (weighting every anchor off, it would not come back at all)."""
    clean = flight(survey_0425, "TDOA3", delayed=False)
    t0 = start_time(clean)
    off = StartPose(tuple(float(v) for v in truth_pose_at(clean, t0)[0] + [0.5, -0.3, 0.2]))

    def first_seconds_error(**params) -> float:
        run = replay(clean, *estimator_config(use_nn=False, **params), start_pose=off)
        first = run.t < t0 + 3.0
        return float(np.mean(np.linalg.norm(
            run.position[first] - metrics.interpolate_positions(clean.truth, run.t[first]), axis=1)))

    assert first_seconds_error() < 1.1 * first_seconds_error(anchor_bias_c=0.0)


def test_rig_evaluate_weights_blocked_anchors_unless_told_not_to(tmp_path: Path, blocked_tdoa3) -> None:
    from rig.data.recording import write_recording

    write_recording(blocked_tdoa3, tmp_path / "blocked.mcap")
    weighted = run_rig("evaluate", str(tmp_path / "blocked.mcap"), "--no-nn", "--json", str(tmp_path / "w.json"),
                       check=True)
    unweighted = run_rig("evaluate", str(tmp_path / "blocked.mcap"), "--no-nn", "--no-anchor-weighting",
                         "--json", str(tmp_path / "u.json"), check=True)
    w, u = (json.loads((tmp_path / name).read_text()) for name in ("w.json", "u.json"))
    assert "blocked-anchor weighting" in weighted.stdout and "blocked-anchor weighting" not in unweighted.stdout
    assert u["config"]["params"]["anchor_bias_c"] == 0.0 < w["config"]["params"]["anchor_bias_c"]
    assert w["rmse_3d"] < 0.6 * u["rmse_3d"]
    assert max(w["anchor_discounted"], key=w["anchor_discounted"].get) == "3" and "anchor 3" in weighted.stdout
    assert "anchor_discounted" not in u


def test_which_anchors_are_discounted_and_for_how_long(blocked_tdoa3, survey_0425: Path) -> None:
    """The blocked anchor is discounted for most of the flight; the TDOA2 ring and the
    estimator without the weighting discount none."""
    shares = anchor_discounts(blocked_tdoa3, *estimator_config(use_nn=False))
    assert set(shares) == {str(a.id) for a in blocked_tdoa3.anchors}
    assert shares["3"] > 0.5 and shares["3"] == max(shares.values())
    assert not any(anchor_discounts(blocked_tdoa3, *estimator_config(use_nn=False, anchor_bias_c=0.0)).values())
    ring = flight(survey_0425, "TDOA2", delayed=True)
    assert not any(anchor_discounts(ring, *estimator_config(use_nn=False)).values())


def test_a_replay_read_in_pieces_is_the_same_run(blocked_tdoa3) -> None:
    """anchor_discounts replays the recording in pieces to read the anchors' weights
    between them: the estimates must be those of one replay, bit for bit."""
    config = estimator_config(use_nn=False)
    est, events, _ = started(blocked_tdoa3, *config)
    cuts = np.linspace(0, len(events), 37).astype(int)
    pieces = np.concatenate([est.replay(events[a:b]) for a, b in zip(cuts[:-1], cuts[1:])])
    np.testing.assert_array_equal(pieces["pos"], replay(blocked_tdoa3, *config).outputs["pos"])


def stress_benchmark():
    import sys

    from rigtest import ROOT
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import blocked_anchor_stress

    return blocked_anchor_stress


def test_the_stress_benchmarks_steady_block_lengthens_one_anchors_ranges(survey_0425: Path) -> None:
    """benchmarks/blocked_anchor_stress.py's block: every range of the anchor longer by
    the excess while the tag is in the anchor's half (anywhere, whole), nothing else."""
    bench = stress_benchmark()
    rec = flight(survey_0425, "TDOA3", delayed=False)
    truth_y = np.interp(rec.tdoa.t, rec.truth.t, rec.truth.position[:, 1])
    half = truth_y <= bench.BLOCKED[0]["max"][1]
    sign = (rec.tdoa.id_b == 0).astype(float) - (rec.tdoa.id_a == 0)
    assert 0.2 < np.mean(half) < 0.8 and np.count_nonzero(sign)
    for whole, where in ((False, half), (True, np.ones_like(half))):
        change = bench.steady_block(rec, 0, 0.4, whole).tdoa.distance_diff - rec.tdoa.distance_diff
        np.testing.assert_allclose(change, 0.4 * sign * where, atol=1e-9)
    # two anchors blocked together: a pair of both reads both excesses, which cancel
    sign_7 = (rec.tdoa.id_b == 7).astype(float) - (rec.tdoa.id_a == 7)
    change = bench.steady_block(rec, (0, 7), 0.4, whole=True).tdoa.distance_diff - rec.tdoa.distance_diff
    np.testing.assert_allclose(change, 0.4 * (sign + sign_7), atol=1e-9)
    with pytest.raises(ValueError, match="whole flight only"):
        bench.steady_block(rec, (0, 7), 0.4)


def test_a_floor_anchor_blocked_throughout_a_real_flight_is_down_weighted(data_dir: Path) -> None:
    """What the weighting is for, on a real TDOA3 flight of a clear room: floor anchor 0
    made 0.8 m long throughout (session 84: 0.545 -> 0.350 m without correction). A
    ceiling anchor blocked so is its known limit (docs/reference/estimator.md)."""
    from rig.data.importer import load_any

    rec = stress_benchmark().steady_block(load_any(data_dir / "flights" / "0425-traj13"), 0, 0.8, whole=True)
    weighted = evaluate(rec, use_nn=False)
    unweighted = evaluate(rec, use_nn=False, anchor_bias_c=0.0)
    assert weighted["rmse_3d"] < unweighted["rmse_3d"] - 0.1
    assert weighted["tdoa_anchor_weighted"] > 0.5 * weighted["tdoa_accepted"]
