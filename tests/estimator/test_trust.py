"""The correction trust: the estimator applies the share of the bias correction that the
flight's own measurements support (trust_prior_n), in [0, 1]."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import run_rig, simulate_exact

from rig.estimator import native
from rig.estimator.bias_net import ANCHORS, BiasNet, identity_probe_net
from rig.estimator.evaluate import FULL_TRUST, build_events, evaluate, make_estimator, start_time, truth_pose_at

DELAY_M = 0.3


def offsets_net(anchor: int, meters: float) -> BiasNet:
    """A link-form model that corrects one anchor's range by a constant, nothing else."""
    offsets = np.zeros(ANCHORS)
    offsets[anchor] = meters
    return replace(identity_probe_net(0, gain=0.0, form="link"), anchor_offset=offsets)


@pytest.fixture(scope="module")
def delayed_flight(survey_0425: Path):
    """A simulated flight whose anchor 3 reads DELAY_M long, with white TDOA noise."""
    return simulate_exact(survey_0425, duration=90.0, seed=5,
                          effects=[{"effect": "anchor_delay", "params": {"anchor": 3, "meters": DELAY_M}},
                                   {"effect": "tdoa_noise", "params": {"std_m": 0.05}}])


def test_a_correction_the_flight_bears_out_is_applied_whole(delayed_flight) -> None:
    right = evaluate(delayed_flight, model=offsets_net(3, DELAY_M))
    without = evaluate(delayed_flight, use_nn=False)
    assert right["correction_trust"] > 0.9
    assert right["rmse_3d"] < 0.5 * without["rmse_3d"]


def test_a_correction_the_flight_contradicts_is_withdrawn(delayed_flight) -> None:
    opposite = offsets_net(3, -DELAY_M)              # the delay corrected the wrong way
    trusted = evaluate(delayed_flight, model=opposite)
    whole = evaluate(delayed_flight, model=opposite, full_trust=True)
    assert trusted["correction_trust"] < 0.1
    assert whole["correction_trust"] == 1.0
    assert trusted["rmse_3d"] < whole["rmse_3d"] - 0.05


def test_a_correction_on_the_wrong_anchor_is_applied_in_part(delayed_flight) -> None:
    """A constant on another anchor is partly a shift of the position, which the
    measurements cannot tell from the truth: the trust falls but not to zero."""
    wrong = offsets_net(5, DELAY_M)
    trusted = evaluate(delayed_flight, model=wrong)
    whole = evaluate(delayed_flight, model=wrong, full_trust=True)
    assert 0.0 < trusted["correction_trust"] < 0.8
    assert trusted["rmse_3d"] < whole["rmse_3d"] - 0.02


def test_without_a_prior_the_whole_correction_is_applied_bit_for_bit_as_before(delayed_flight) -> None:
    """trust_prior_n < 0 is the estimator before the trust: w is exactly 1, so the
    corrected measurement is the same float operation."""
    net = offsets_net(5, DELAY_M)
    first = evaluate(delayed_flight, model=net, trust_prior_n=FULL_TRUST)
    second = evaluate(delayed_flight, model=net, full_trust=True)
    assert first["rmse_3d"] == second["rmse_3d"] and first["config"]["params"]["trust_prior_n"] < 0


def test_the_trust_starts_whole_and_stays_within_zero_and_one(delayed_flight) -> None:
    est = native.Estimator(native.default_params())
    assert est.correction_trust() == 1.0             # no measurement yet
    for meters in (-3.0, 3.0):                       # far too much, either sign
        result = evaluate(delayed_flight, model=offsets_net(3, meters))
        assert 0.0 <= result["correction_trust"] <= 1.0


def test_rig_evaluate_reports_the_share_applied_and_full_trust_applies_all(tmp_path: Path) -> None:
    trusted = run_rig("evaluate", "--json", str(tmp_path / "trusted.json"), check=True)
    whole = run_rig("evaluate", "--full-trust", "--json", str(tmp_path / "whole.json"), check=True)
    t, w = (json.loads((tmp_path / f"{name}.json").read_text()) for name in ("trusted", "whole"))
    assert 0.0 <= t["correction_trust"] <= 1.0 and t["config"]["params"]["trust_prior_n"] > 0
    assert f"applied at {t['correction_trust']:.0%}" in trusted.stdout
    assert w["correction_trust"] == 1.0 and w["config"]["params"]["trust_prior_n"] < 0
    assert "applied whole (--full-trust)" in whole.stdout


def _replay_with(rec, net: BiasNet, events_filter=None):
    """An estimator that replayed `rec` with `net` correcting, and its outputs."""
    est = make_estimator(rec, native.default_params(), net)
    t0 = start_time(rec)
    pos, quat = truth_pose_at(rec, t0)
    est.reset(0, pos, quat)
    events = build_events(rec, t0)
    return est, est.replay(events if events_filter is None else events_filter(events)), events


def test_a_new_flight_starts_at_full_trust(delayed_flight) -> None:
    est, _, _ = _replay_with(delayed_flight, offsets_net(3, -DELAY_M))
    assert est.correction_trust() < 0.1
    est.reset(0, [0.0, 0.0, 0.0])                    # the start of another flight
    assert est.correction_trust() == 1.0


def test_a_divergence_reset_keeps_what_the_flight_showed(delayed_flight) -> None:
    """Half the flight with a contradicted correction, then IMU alone, 30 times too strong,
    until the state diverges and is reset: the trust is the one before the reset."""
    half = lambda events: events[events["t_us"] < events["t_us"][-1] // 2]   # noqa: E731
    est, _, events = _replay_with(delayed_flight, offsets_net(3, -DELAY_M), half)
    before = est.correction_trust()
    rest = events[(events["t_us"] >= events["t_us"][-1] // 2) & (events["kind"] != native.EV_TDOA)].copy()
    rest["v"][rest["kind"] == native.EV_ACCEL] *= 30.0
    out = est.replay(rest)
    assert out["counters"][-1]["resets"] >= 1
    assert before < 0.5 and est.correction_trust() == before


def test_a_state_blown_to_infinity_does_not_poison_the_flights_trust(delayed_flight) -> None:
    """A burst of absurd accelerations drives the state to inf or NaN until the divergence
    reset; the measurements compared with it meanwhile must not enter the sums, or the
    trust would be stuck for the rest of the flight."""
    def burst(events):
        t = events["t_us"]
        inside = (t > t[-1] // 3) & (t < t[-1] // 3 + 200_000) & (events["kind"] == native.EV_ACCEL)
        events = events.copy()
        events["v"][inside] = 1e30
        return events
    est, out, _ = _replay_with(delayed_flight, offsets_net(3, -DELAY_M), burst)
    assert out["counters"][-1]["resets"] >= 1
    assert est.correction_trust() < 0.1
