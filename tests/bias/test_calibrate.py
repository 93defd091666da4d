"""`rig calibrate`: the link-bias model fitted to flights with ground truth recovers
what a simulation put in, flags what no link can physically be, and writes effects a
simulation config takes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rigtest import run_rig

from rig.bias.calibrate import calibrate, flight_rows, samples_link_bias
from rig.bias.dataset import flight_samples
from rig.data.recording import write_recording
from rig.sim.effects import LINK_BOUND_M, LINK_TERMS, effects_from_json
from rig.sim.simulate import SimConfig, simulate

COEFFS = [-0.45, 0.05, 0.2, -0.2, -0.4, 0.1]


def simulated_rows(survey: Path, coeffs: list[float], delays: dict[int, float], seed: int, name: str):
    effects = [{"effect": "link_bias", "params": {"coeffs_m": coeffs}},
               {"effect": "tdoa_noise", "params": {"std_m": 0.05}}]
    effects += [{"effect": "anchor_delay", "params": {"anchor": k, "meters": m}} for k, m in delays.items()]
    rec = simulate(SimConfig(trajectory="circle-sine", duration=20.0, survey=str(survey), seed=seed,
                             effects=effects))
    return flight_rows(rec, name, latency=0.0)


def test_calibration_recovers_the_simulated_link_bias_under_flight_to_flight_delays(survey_0425: Path) -> None:
    """Two flights whose anchor delays differ by centimetres, as real flights' do: the
    shared coefficients come back, and each flight's delays with them."""
    flights = [simulated_rows(survey_0425, COEFFS, {0: 0.08, 3: -0.05}, seed=1, name="a"),
               simulated_rows(survey_0425, COEFFS, {0: -0.04, 5: 0.06}, seed=2, name="b")]
    result = calibrate(flights, bootstrap=3)
    fitted = [result["terms"][name]["value_m"] for name in LINK_TERMS]
    # the distance term: a circle at one height spans a narrow range of distances
    np.testing.assert_allclose(fitted, COEFFS, atol=0.05)
    assert result["within_bounds"]
    delays_b = result["delays_by_flight_m"]["b"]
    assert delays_b["5"] - delays_b["1"] == pytest.approx(0.06, abs=0.02)
    std = result["tdoa_error_std_m"]
    assert std["after_link"] < 0.06 < std["after_delays"] < std["before"]
    effects = effects_from_json(result["effects"])            # a simulation config takes them as they are
    assert effects[0].name == "link_bias" and len(effects) == 1 + len(result["delays_by_flight_m"]["a"])


def test_the_link_bias_of_a_flights_samples_is_what_the_simulator_put_in(survey_0425: Path, tmp_path: Path) -> None:
    """`rig train --minus-link-bias` subtracts exactly the simulator's link bias: on a
    flight with nothing else in its TDOA, nothing is left of the labels."""
    rec = simulate(SimConfig(trajectory="circle-sine", duration=8.0, survey=str(survey_0425), seed=4,
                             effects=[{"effect": "link_bias", "params": {"coeffs_m": COEFFS}}]))
    write_recording(rec, tmp_path / "sim.mcap")
    samples = flight_samples(rec, "sim.mcap", latency=0.0, features_from="truth")
    bias = samples_link_bias(samples, [tmp_path / "sim.mcap"], {"sim.mcap": 0.0}, np.array(COEFFS))
    assert np.std(samples.label) > 0.05, "the link bias is there to remove"
    np.testing.assert_allclose(bias, samples.label, atol=2e-3)      # the truth interpolated at 100 Hz


def test_a_coefficient_beyond_what_a_link_can_physically_have_is_flagged(survey_0425: Path) -> None:
    coeffs = [0.0, 0.0, 0.0, 0.0, 2.5 * LINK_BOUND_M, 0.0]
    result = calibrate([simulated_rows(survey_0425, coeffs, {}, seed=3, name="a")], bootstrap=0)
    assert not result["within_bounds"]
    assert [n for n, t in result["terms"].items() if not t["within_bound"]] == ["tag_zonal"]


@pytest.mark.slow
def test_rig_calibrate_fits_a_real_flight_and_writes_its_effects(tmp_path: Path) -> None:
    out = tmp_path / "link.json"
    done = run_rig("calibrate", "--flights", "0426-traj1", "--bootstrap", "2", "--out", str(out))
    assert done.returncode == 0, done.stderr
    result = json.loads(out.read_text())
    assert result["flights"] == ["0426-traj1"] and set(result["terms"]) == set(LINK_TERMS)
    std = result["tdoa_error_std_m"]
    assert std["after_link"] < std["after_delays"] < std["before"]
    assert "anchor_zonal" in done.stdout and f"wrote {out}" in done.stdout
    effects_from_json(result["effects"])
    bad = run_rig("calibrate", "--flights", "nosuchflight", "--out", str(out))
    assert bad.returncode == 2 and "no flight" in bad.stderr
