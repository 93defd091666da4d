"""Proof of the diagnosis on concealed effects: each catalog effect injected, at a
per-sample size at or below the noise (checked here, so it is invisible in a residual
plot), into (a) a simulated flight and (b) a real shared flight, compared with the
untouched flight as control (real flights carry real effects). The tool must name the
effect, locate it (anchor, axis), recover its parameters within the stated tolerance
and fit better with it than without. Plus harder cases: two effects at once, an effect
in part of the flight, look-alikes. Effects this data cannot identify are marked as
expected failures with the reason (strict: they fail the suite once they pass)."""

from __future__ import annotations

import json
import re
import subprocess
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import RIG
from scipy.spatial.transform import Rotation

from rig.data.importer import load_any
from rig.data.paths import default_recording
from rig.data.recording import Recording, Vec3Series
from rig.diagnosis import compare, imu_spectrum
from rig.diagnosis.alternatives import in_place_estimates
from rig.diagnosis.candidates import Candidate, candidates
from rig.diagnosis.channels import Channel, Problem
from rig.diagnosis.confined import confine_in_time
from rig.diagnosis.diagnose import (
    diagnose,
    identifiability,
    lever_arm_cross_talk,
    nlos_identifiability,
    unnamed_estimates,
    vibration_spread,
)
from rig.diagnosis.floor_error import ON_GROUND_M
from rig.diagnosis.mismatch import locate
from rig.diagnosis.report import describe
from rig.diagnosis.report import write as write_report
from rig.diagnosis.robust import delay_centre, irls, mad_scale, robust_rms
from rig.diagnosis.selection import fresh_terms, select
from rig.diagnosis.terms import ORDER, Term, estimate_terms, free_offset_terms
from rig.sim import effects as fx
from rig.sim.simulate import Predictor, SimConfig, inject, simulate

NOISE = [{"effect": "tdoa_noise", "params": {"std_m": 0.15}},
         {"effect": "imu_noise", "params": {"accel_std": 0.5, "gyro_std": 0.05}},
         {"effect": "outliers", "params": {"fraction": 0.03, "mean_excess_m": 1.0}}]
REAL_FLIGHT = "0426-traj1"


def sim_config(survey: Path, effects: list[dict], flight: dict | None = None) -> SimConfig:
    """A circle with a vertical sine and a yaw swing (so thrust and yaw rate vary);
    `flight` changes the circle (trajectory parameters)."""
    return SimConfig(trajectory="circle-sine", survey=str(survey), duration=40.0, seed=3,
                     trajectory_params={"yaw_amplitude": 1.0, "yaw_omega": 0.5, **(flight or {})},
                     effects=NOISE + effects)


@pytest.fixture(scope="module")
def survey(data_dir: Path) -> Path:
    return data_dir / "surveys" / "anchor_0425.txt"


@pytest.fixture(scope="module")
def sim_diagnosis(survey):
    return diagnose(simulate(sim_config(survey, [])))


@pytest.fixture(scope="module")
def sim_control(sim_diagnosis):
    return findings(sim_diagnosis)


@pytest.fixture(scope="module")
def real(data_dir: Path):
    rec = load_any(data_dir / "flights" / REAL_FLIGHT)
    return rec, Predictor(rec)


@pytest.fixture(scope="module")
def real_diagnosis(real):
    return diagnose(real[0])


@pytest.fixture(scope="module")
def real_control(real_diagnosis):
    return findings(real_diagnosis)


def findings(result) -> dict[tuple, dict]:
    return keyed(result.to_json()["findings"])


def unnamed(result) -> dict[tuple, dict]:
    """The simplest effects a diagnosis does not name, as it estimates them."""
    return keyed(result.to_json()["unnamed_estimates"])


def in_place(result) -> list[dict]:
    """Each look-alike a diagnosis estimates in a named effect's place."""
    return [u.to_json() for u in result.in_place]


def keyed(listed: list[dict]) -> dict[tuple, dict]:
    """Findings (or anything else keyed like them) by (effect, anchors)."""
    return {compare.key(f): f for f in listed}


def concealed(rec, effect: dict, predictor: Predictor | None = None) -> None:
    """The injected effect changes no channel by more than that channel's per-sample
    noise (robust σ of recorded − simulated, raw samples), in RMS."""
    predictor = predictor or Predictor(rec)
    changed = inject(rec, [effect], seed=1, predictor=predictor)
    base = Problem(rec, predictor)
    for name, series in (("accel", "accel"), ("gyro", "gyro")):
        before, after = getattr(rec, series).xyz, getattr(changed, series).xyz
        true = predictor.accel_true if name == "accel" else predictor.gyro_true
        for axis in range(3):
            noise = mad_scale(before[:, axis] - true[:, axis])
            effect_rms = np.sqrt(np.mean((after[:, axis] - before[:, axis]) ** 2))
            assert effect_rms <= noise, f"{effect} is not concealed on {name} {axis}: {effect_rms} > {noise}"
    rows = base.tdoa_rows
    if effect["effect"] in ("time_offset", "clock_drift"):
        moved = Predictor(changed).tdoa([]).value[rows] - predictor.tdoa([]).value[rows]
    else:
        moved = changed.tdoa.distance_diff[rows] - rec.tdoa.distance_diff[rows]
    noise = mad_scale(rec.tdoa.distance_diff[rows] - predictor.tdoa([]).value[rows])
    effect_rms = np.sqrt(np.mean(moved ** 2))
    assert effect_rms <= noise, f"{effect} is not concealed on TDOA: {effect_rms:.3f} > {noise:.3f} m"


# (effect, tolerance check on (found params, injected params) after subtracting the control)
# Tolerances are for simulated flights; on a real flight, whose own effects the fit
# shares the data with, they are REAL_SLACK times wider.
REAL_SLACK = 1.5


def _vector_close(key: str, tol: float):
    return lambda got, want, slack=1.0: np.allclose(got[key], want[key], atol=tol * slack)


def _scalar_close(key: str, rel: float):
    return lambda got, want, slack=1.0: abs(got[key] - want[key]) <= rel * slack * abs(want[key])


CASES = {
    "time_offset": ({"seconds": 0.06}, _scalar_close("seconds", 0.35)),
    "clock_drift": ({"ppm": 2000.0}, _scalar_close("ppm", 0.25)),
    "anchor_delay": ({"anchor": 5, "meters": 0.12}, _scalar_close("meters", 0.25)),
    "anchor_position": ({"anchor": 3, "offset_m": [0.2, 0.2, 0.0]}, _vector_close("offset_m", 0.06)),
    "antenna_pattern": ({"anchor": 2, "coeffs_m": [0.3, 0.2, 0.0]}, _vector_close("coeffs_m", 0.15)),
    # its mean shift (fraction × mean excess) over the region found, less the control's there
    "nlos": ({"anchor": 6, "fraction": 0.5, "mean_excess_m": 0.3, "region": {"min": [-5, 0, -1], "max": [5, 5, 5]}},
             lambda got, want, slack=1.0: 0.05 <= got["mean_shift_m"] <= 0.3),
    "multipath_floor": ({"height_m": 0.6, "std_m": 0.2},
                        lambda got, want, slack=1.0: 0.25 <= got["height_m"] <= 1.0 and 0.1 <= got["std_m"] <= 0.35),
    "imu_accel_bias": ({"bias_mps2": [0.0, 0.15, 0.0]}, _vector_close("bias_mps2", 0.03)),
    "imu_gyro_bias": ({"bias_rps": [0.0, 0.0, 0.02]}, _vector_close("bias_rps", 0.004)),
    "imu_accel_scale": ({"scale": [1.0, 1.0, 1.03]}, lambda got, want, slack=1.0: abs(got["scale"][2] - 1.03) < 0.01 * slack),
    "imu_gyro_scale": ({"scale": [1.0, 1.0, 1.1]}, lambda got, want, slack=1.0: abs(got["scale"][2] - 1.1) < 0.03 * slack),
    # 0.8 × the y axis' vibration RMS: 0.2 m/s² on the suite's real flight, in flight only
    "imu_vibration_rectification": ({"gain": [0.0, -0.8, 0.0]}, _vector_close("gain", 0.2)),
    # sideways: a vertical lever arm in near-level flight is the tag raised, which TDOA
    # reads as delays of the ceiling anchors against the floor ones (not identifiable)
    "lever_arm": ({"offset_m": [0.08, 0.0, 0.0]}, _vector_close("offset_m", 0.03)),
}
IMU_VECTOR = {"imu_accel_bias": "bias_mps2", "imu_gyro_bias": "bias_rps", "imu_accel_scale": "scale",
              "imu_gyro_scale": "scale", "imu_vibration_rectification": "gain"}


def injected_axes(name: str, params: dict) -> list[str] | None:
    """The axes an injected IMU effect moves off neutral, which its finding must
    locate (None for the other effects)."""
    if name not in IMU_VECTOR:
        return None
    return [axis for axis, value in zip("xyz", params[IMU_VECTOR[name]]) if value != compare.neutral(name)]


# An antenna pattern needs the anchor seen from a wide range of angles: over the few
# tens of degrees the suite's circle spans it reads as a displaced anchor (see
# test_a_pattern_seen_in_a_narrow_cone_reads_as_a_displaced_anchor). Its case flies a
# wider circle that passes within a metre of the anchor (2).
SIM_FLIGHT = {"antenna_pattern": {"center": [1.5, 1.5], "radius": 2.5, "z_amplitude": 0.8}}
# A rectification needs shaking that comes and goes: over the suite's white noise, one
# size all flight, it is a constant bias. Its case's airframe shakes sideways with the
# rotors (twice the sensor's noise in flight, none on the ground), like the real
# flights that shook.
SIM_SHAKING = {"imu_vibration_rectification": [{"effect": "imu_vibration", "params": {"accel_std": [1.0, 1.0, 0.0]}}]}
NOT_ON_SIM: dict[str, str] = {}


def sim_case(survey: Path, name: str, effects: list[dict]) -> SimConfig:
    """The simulated flight of `name`'s case, with `effects` injected."""
    return sim_config(survey, SIM_SHAKING.get(name, []) + effects, SIM_FLIGHT.get(name))


def own_sim_control(name: str) -> bool:
    """Whether `name`'s case flies its own simulated flight, so has its own control."""
    return name in SIM_FLIGHT or name in SIM_SHAKING


NOT_ON_REAL: dict[str, str] = {}


def _mark(name: str, known: dict) -> list:
    return [pytest.mark.xfail(strict=True, reason=known[name])] if name in known else []


def _check(found: dict, control: dict, name: str, params: dict, check, real: bool = False,
           samples: compare.TdoaSamples | None = None, control_unnamed: dict | None = None,
           control_samples: compare.TdoaSamples | None = None, control_in_place: Sequence[dict] = ()) -> None:
    """The injected effect named, located and measured: on a real flight, as its
    change from the control recording (rig.diagnosis.compare, as `rig diagnose --control`; an
    NLOS's over both recordings' TDOA `samples` and `control_samples`; one the control does not
    name, from its estimate there, `control_unnamed`, keyed like the findings; one
    reported in a look-alike's place, from the control's estimate in that place,
    `control_in_place`)."""
    key = (name, (params["anchor"],) if "anchor" in params else ())
    if key not in found and key in control and name in CANCELLABLE:
        _check_cancelled(control[key], name, params, check, real)
        return
    assert key in found, f"{name} not named; found {sorted(found)}"
    got = compare.change(name, list(key[1]), found[key], control.get(key), samples,
                         (control_unnamed or {}).get(key), control_samples=control_samples,
                         control_in_place=control_in_place).change
    got = got or dict(found[key]["params"])
    _check_unidentified(found[key], got, params)
    assert check(got, params, REAL_SLACK if real else 1.0), f"{name}: got {got}, injected {params}"
    assert found[key]["fit_after"] < found[key]["fit_before"]
    expected = injected_axes(name, params)
    if expected is not None:         # on a real flight, the axes of the flight's own biases come too
        located = found[key]["where"]["axes"]
        assert set(expected) <= set(located) if real else located == expected
    if "anchor" in params:
        assert found[key]["where"]["anchors"] == [params["anchor"]]
    if "region" in params:
        _check_region(found[key]["params"], params, samples)


NLOS_LOCATED = 0.5      # of the samples in the region found, at least this share inside the injected one


def _check_region(got: dict, params: dict, samples: compare.TdoaSamples | None) -> None:
    """An NLOS is located where most of the samples its region holds (the tag inside,
    the anchor in the pair) are inside the injected region."""
    assert samples is not None, "an NLOS is judged over the injected recording's TDOA samples"
    found = samples.inside(params["anchor"], got["region"])
    share = float(np.mean(samples.inside(params["anchor"], params["region"])[found])) if found.any() else 0.0
    assert share >= NLOS_LOCATED, f"nlos: {share:.0%} of the region found {got['region']} is in the injected one"


# A global clock effect the injection cancels: the real flight's own (its control's
# finding) plus the injected one adds up to about none, which the tool rightly does not
# name. Compared with the control, the injection then changed it from the control's
# value to the neutral one. Not to the injected flight's estimate of it below its bar,
# which `rig diagnose --control` reports as the change (`recording_unnamed`): that the
# estimate moved by the injected amount while the sum did not cancel is not naming it
# (0425-traj1's drift, 1814 ± 558 ppm unnamed).
CANCELLABLE = compare.CANCELLABLE


def _check_cancelled(own: dict, name: str, params: dict, check, real: bool) -> None:
    got = compare.change(name, [], None, own).change
    assert check(got, params, REAL_SLACK if real else 1.0), \
        f"{name}: not named, its control's {own['params']} not cancelled by the injected {params}"
    assert own["fit_after"] < own["fit_before"]


UNIDENTIFIED_SE = 2.0      # a component the tool says it cannot identify: within this many standard errors


def _check_unidentified(finding: dict, got: dict, params: dict) -> None:
    """Components of a vector parameter that the tool reports as not identified by the
    trajectory (their standard error is most of their prior's) must agree with the
    injected value within their standard error, and are then taken as recovered; at
    least one component must be identified. Identified ones face the tolerance."""
    for label in finding.get("not_identified", []):
        field, _, index = label.partition("[")
        assert index, f"a whole parameter is not identified: {label}"
        i = int(index.rstrip("]"))
        std_err = finding["std_err"][field][i]
        assert abs(got[field][i] - params[field][i]) <= UNIDENTIFIED_SE * std_err, \
            f"{label}: got {got[field][i]:.3f} ± {std_err:.3f}, injected {params[field][i]}"
        got[field] = [params[field][i] if j == i else v for j, v in enumerate(got[field])]
    for field, value in params.items():
        if isinstance(value, list):
            named = [label for label in finding.get("not_identified", []) if label.startswith(f"{field}[")]
            assert len(named) < len(value), f"no component of {field} is identified"


@pytest.mark.parametrize("name", [pytest.param(n, marks=_mark(n, NOT_ON_SIM)) for n in CASES])
def test_a_concealed_effect_in_a_simulated_flight_is_named_located_and_measured(name, survey, sim_diagnosis) -> None:
    params, check = CASES[name]
    effect = {"effect": name, "params": params}
    rec = simulate(sim_case(survey, name, [effect]))
    untouched = simulate(sim_case(survey, name, []))
    concealed(untouched, effect)
    control = diagnose(untouched) if own_sim_control(name) else sim_diagnosis
    assert all(k[0] != name for k in findings(control))
    diagnosis = diagnose(rec)
    _check(findings(diagnosis), findings(control), name, params, check, samples=compare.TdoaSamples.of(diagnosis),
           control_unnamed=unnamed(control), control_samples=compare.TdoaSamples.of(control),
           control_in_place=in_place(control))


@pytest.mark.parametrize("name", [pytest.param(n, marks=_mark(n, NOT_ON_REAL)) for n in CASES])
def test_a_concealed_effect_in_a_real_flight_is_found_against_its_control(name, real, real_diagnosis) -> None:
    params, check = CASES[name]
    rec, predictor = real
    effect = {"effect": name, "params": params}
    concealed(rec, effect, predictor)
    injected = inject(rec, [effect], seed=1, predictor=predictor)
    diagnosis = diagnose(injected)
    _check(findings(diagnosis), findings(real_diagnosis), name, params, check, real=True,
           samples=compare.TdoaSamples.of(diagnosis), control_unnamed=unnamed(real_diagnosis),
           control_samples=compare.TdoaSamples.of(real_diagnosis), control_in_place=in_place(real_diagnosis))


def test_a_gyro_scale_is_not_shrunk_by_the_ground_truths_attitude_noise(survey) -> None:
    """Errors in variables: motion-capture attitude noise (1° per pose here) makes the
    ground truth's rates noisy; a scale regressed on them comes out shrunk (1.16 for
    1.3 on this slowly yawing flight), one regressed on the gyroscope does not."""
    flight = {"yaw_amplitude": 0.06, "yaw_omega": 1.0}
    rec = simulate(sim_config(survey, [{"effect": "imu_gyro_scale", "params": {"scale": [1.0, 1.0, 1.3]}}], flight))
    wobble = Rotation.from_rotvec(np.random.default_rng(0).normal(0.0, 0.02, (len(rec.truth.t), 3)))
    noisy_truth = replace(rec.truth, quaternion=(wobble * Rotation.from_quat(rec.truth.quaternion)).as_quat())
    noisy = replace(rec, truth=noisy_truth)
    assert Problem(noisy).gyro_block_s == 0.5        # the slow swing, averaged over the most of that noise
    found = findings(diagnose(noisy))
    assert abs(found[("imu_gyro_scale", ())]["params"]["scale"][2] - 1.3) < 0.04


def test_a_yaw_wobble_is_kept_in_short_gyroscope_blocks(survey, monkeypatch) -> None:
    """A flight that holds its heading still wobbles about it at the attitude
    controller's pace (here 1 Hz): 0.5 s blocks average that out, and with it the
    signal a gyroscope scale is measured on. The diagnosis compares this flight in
    0.2 s blocks, where its 10 % z scale is measured to under half the standard error."""
    flight = {"yaw_amplitude": 0.05, "yaw_omega": 6.0}
    rec = simulate(sim_config(survey, [{"effect": "imu_gyro_scale", "params": {"scale": [1.0, 1.0, 1.1]}}], flight))
    assert Problem(rec).gyro_block_s == 0.2
    short = findings(diagnose(rec))[("imu_gyro_scale", ())]
    assert abs(short["params"]["scale"][2] - 1.1) < 0.03
    monkeypatch.setattr("rig.diagnosis.channels.GYRO_BLOCKS_S", (0.5,))
    long = findings(diagnose(rec))[("imu_gyro_scale", ())]
    assert short["std_err"]["scale"][2] < 0.5 * long["std_err"]["scale"][2]


def test_a_gyroscope_axis_that_does_not_rotate_carries_no_scale(survey) -> None:
    """On a level circle without yaw the z rate is the gyroscope's noise alone: a scale
    regressed on the recorded rate would explain that noise by itself (z 2.36, named
    on d107c30). With an exact ground truth the regressor is the predicted rate, and
    a z scale is not named on that flight, untouched or with one injected."""
    level = {"z_amplitude": 0.0, "yaw_amplitude": 0.0}
    for effects in ([], [{"effect": "imu_gyro_scale", "params": {"scale": [1.0, 1.0, 1.1]}}]):
        found = findings(diagnose(simulate(sim_config(survey, effects, level))))
        assert ("imu_gyro_scale", ()) not in found


@pytest.mark.parametrize("trajectory, params, mode", [("smooth-random", {}, "TDOA2"), ("circle", {"omega": 0.4}, "TDOA2"),
                                                      ("circle-sine", {"yaw_amplitude": 1.0}, "TDOA3")])
def test_an_untouched_simulated_flight_names_nothing(survey, trajectory, params, mode) -> None:
    """No false alarms: flights of other shapes and UWB modes than the suite's, with its
    noise and outliers and nothing else, name no effect."""
    config = SimConfig(trajectory=trajectory, survey=str(survey), duration=40.0, seed=5, trajectory_params=params,
                       uwb_mode=mode, effects=NOISE)
    assert findings(diagnose(simulate(config))) == {}


def test_two_effects_at_once_are_both_found(survey) -> None:
    both = [{"effect": "anchor_delay", "params": {"anchor": 1, "meters": -0.1}},
            {"effect": "time_offset", "params": {"seconds": 0.05}}]
    found = findings(diagnose(simulate(sim_config(survey, both))))
    assert abs(found[("anchor_delay", (1,))]["params"]["meters"] + 0.1) < 0.025
    assert abs(found[("time_offset", ())]["params"]["seconds"] - 0.05) < 0.015


def test_an_effect_in_part_of_the_flight_is_confined_in_time(survey) -> None:
    partial = {"effect": "anchor_delay", "params": {"anchor": 4, "meters": 0.15, "during": [15.0, 30.0]}}
    found = findings(diagnose(simulate(sim_config(survey, [partial]))))
    got = found[("anchor_delay", (4,))]
    start, end = got["params"]["during"]
    assert abs(start - 15.0) < 3.0 and abs(end - 30.0) < 3.0
    assert abs(got["params"]["meters"] - 0.15) < 0.04
    assert abs(got["params"]["outside_m"]) < 0.03, "its own (zero) delay elsewhere, relative to the others"


def test_a_bias_of_a_place_the_tag_returns_to_is_not_confined_in_time() -> None:
    """An anchor's ranges that read long while the tag hovers in one place (15–30 s)
    and again whenever its circle passes there read so because of the place (an
    antenna's pattern, a reflection), not the time: no window is kept. By time alone
    the hover is a window; the same excess only while hovering, and not on the passes,
    is one of the time and keeps it."""
    t = np.arange(0.0, 60.0, 0.02)
    angle = 2 * np.pi * t / 20.0
    positions = np.stack([np.sqrt(2) * np.cos(angle), np.sqrt(2) * np.sin(angle), np.ones_like(t)], axis=1)
    hover = (t >= 12.0) & (t < 30.0)            # three tenths of the flight
    positions[hover] = [1.0, 1.0, 1.0]          # on the circle, which passes there at 2.5 s and 42.5 s
    at_place = np.linalg.norm(positions - [1.0, 1.0, 1.0], axis=1) < 0.2
    noise = np.random.default_rng(0).normal(size=len(t))

    def window(excess: np.ndarray, tag_positions: np.ndarray | None) -> list | None:
        channel = Channel("tdoa", t, noise + 2.0 * excess, np.ones(len(t)))
        term = Term(Candidate("anchor_delay", "tdoa", "meters", 1, {"anchor": 0}), np.ones((len(t), 1)))
        confine_in_time(channel, [term], tag_positions)
        return term.extra.get("during")

    assert window(at_place, None) is not None
    assert window(at_place, positions) is None
    start, end = window(hover, positions)
    assert abs(start - 12.0) < 1.0 and abs(end - 30.0) < 1.0


def test_time_offset_and_clock_drift_are_told_apart(survey) -> None:
    drift = findings(diagnose(simulate(sim_config(survey, [{"effect": "clock_drift", "params": {"ppm": 2000.0}}]))))
    offset = findings(diagnose(simulate(sim_config(survey, [{"effect": "time_offset", "params": {"seconds": 0.06}}]))))
    assert ("clock_drift", ()) in drift and ("time_offset", ()) not in drift
    assert ("time_offset", ()) in offset and ("clock_drift", ()) not in offset


@pytest.mark.parametrize("effect", [{"effect": "clock_drift", "params": {"ppm": 2000.0}},
                                    {"effect": "anchor_position", "params": {"anchor": 3, "offset_m": [0.2, 0.2, 0.0]}},
                                    {"effect": "imu_vibration_rectification", "params": {"gain": [0.0, -0.8, 0.0]}}],
                         ids=["a drift (simplest)", "a displacement (richer)", "a rectification (IMU, richer)"])
def test_an_effect_left_unnamed_is_estimated_as_it_would_be_named(survey, effect: dict) -> None:
    """`unnamed_estimates`: a control that does not name an effect still has its own
    below the bar, and a comparison starts from there. Taken out of the named
    effects, an effect a flight names is estimated at the value and standard error
    it was named with; every parametric candidate of its channel not named has an
    estimate."""
    problem = Problem(simulate(sim_case(survey, effect["effect"], [effect])))
    pool = candidates(problem)
    name = next(c.channel for c in pool if c.effect == effect["effect"])
    as_recorded = problem.channel(name)
    named, channel, _ = select(problem, as_recorded, pool)
    term = next(t for t in named if t.candidate.effect == effect["effect"])
    left_out = unnamed_estimates(problem, channel, as_recorded, [t for t in named if t is not term], pool)
    named_keys = {t.key for t in named} - {term.key}
    assert len(left_out) == sum(c.channel == name and c.effect != "nlos" and c.key not in named_keys for c in pool)
    estimate = next(u for u in left_out if u.effect == term.candidate.effect and u.anchors == term.candidate.anchors)
    c = term.candidate
    assert np.ravel(estimate.params[c.param]) == pytest.approx(c.value(term.estimate), abs=1e-5)
    assert np.ravel(estimate.params[c.param]) == pytest.approx(np.ravel(effect["params"][c.param]),
                                                               rel=0.25, abs=0.06)
    assert np.ravel(estimate.std_err[c.param]) == pytest.approx(term.std_err * c.value_slope(term.estimate), rel=1e-3)


def test_a_look_alike_is_estimated_in_a_named_effects_place_named_too_or_not(survey) -> None:
    """`in_place_estimates`: a z bias of 0.2 m/s² named, its look-alike the z scale in
    its place reads 1 + 0.2 / g (the flight's mean z specific force), as a recording
    that cannot tell the two apart reports it; and the same where the scale is named
    too (taken out on those axes, not fitted twice)."""
    bias = {"effect": "imu_accel_bias", "params": {"bias_mps2": [0.0, 0.0, 0.2]}}
    problem = Problem(simulate(sim_config(survey, [bias])))
    pool, as_recorded = candidates(problem), problem.channel("accel")
    named, channel, _ = select(problem, as_recorded, pool)
    fresh = fresh_terms(pool, "accel")
    assert [t.candidate.effect for t in named] == ["imu_accel_bias"]
    estimates = in_place_estimates(channel.z, named, fresh, as_recorded.z)
    scale = next(e for e in estimates if e.replaces is named[0]).term
    assert scale.candidate.effect == "imu_accel_scale" and len(estimates) == 1
    assert scale.estimate[2] == pytest.approx(0.2 / 9.81, abs=1e-3)        # the scale's fit is about one
    both = [*named, next(t for t in fresh if t.candidate.effect == "imu_accel_scale")]
    also_named = next(e for e in in_place_estimates(channel.z, both, fresh, as_recorded.z) if e.replaces is named[0])
    assert also_named.term.estimate == pytest.approx(scale.estimate, abs=1e-9)


def _clock_started_earlier(rec: Recording, seconds: float) -> Recording:
    """The same flight on a clock that started `seconds` earlier (0422-log00 flies at
    82–132 s of its recording's clock)."""
    return replace(rec, **{name: replace(getattr(rec, name), t=getattr(rec, name).t + seconds)
                           for name in ("accel", "gyro", "tdoa", "truth")})


def test_a_flight_that_cannot_tell_a_drift_from_an_offset_names_the_offset(survey) -> None:
    """Far from t = 0 of the recording's clock a drift is an offset that grows little
    over the flight (1000 ppm is 60–100 ms at 60–100 s): neither is supported given
    the other, and the drift goes first, so the timing is named as the offset, as on
    the flight's control and on every other run. Before, of the two the one that added
    less went, which was the offset here (the drift came out as 655 ppm). The drift is
    reported in the offset's place too (alternative_to), as good an explanation."""
    rec = _clock_started_earlier(simulate(sim_config(survey, [])), 60.0)
    drift = {"effect": "clock_drift", "params": {"ppm": 1000.0}}
    diagnosis = diagnose(inject(rec, [drift], seed=1, predictor=Predictor(rec)))
    found = findings(diagnosis)
    assert "alternative_to" not in found[("time_offset", ())]
    assert 0.06 < found[("time_offset", ())]["params"]["seconds"] < 0.1, "the drift's delay over the flight"
    # the drift is reported too, in the offset's place, and not simulated; measured about
    # a free offset, as a named drift is, its growth over the 40 s flight is 40 ms
    alternative = found[("clock_drift", ())]
    assert alternative["alternative_to"] == {"effect": "time_offset"}
    assert alternative["std_err"]["ppm"] < 300.0
    assert abs(alternative["params"]["ppm"] - 1000.0) < 2.5 * alternative["std_err"]["ppm"]
    assert [e.name for e in diagnosis.model if e.name in ("time_offset", "clock_drift")] == ["time_offset"]


def test_a_drift_is_measured_about_a_free_time_offset_named_or_not(survey) -> None:
    """A flight with an offset and a drift where only the drift is named (of two
    look-alikes of equal rank, the offset can go unnamed on one run and not on
    another): the drift's estimate must not take the offset over the flight's mean
    time too (here 3740 ppm instead of 1650 ± 210)."""
    both = [{"effect": "time_offset", "params": {"seconds": 0.05}}, {"effect": "clock_drift", "params": {"ppm": 2000.0}}]
    problem = Problem(simulate(sim_config(survey, both)))
    pool = [Term(c, c.columns) for c in candidates(problem) if c.channel == "tdoa"]
    drift = [t for t in pool if t.candidate.effect == "clock_drift"]
    z = problem.channel("tdoa").z
    estimate_terms(z, drift, nuisance=free_offset_terms(drift, pool))
    assert abs(drift[0].estimate[0] - 2000.0) < 500.0
    estimate_terms(z, drift)
    assert drift[0].estimate[0] > 3000.0, "without the free offset the drift takes it (the test can fail)"


def test_a_richer_effect_is_measured_given_every_simplest_one_named_or_not(survey) -> None:
    """A displaced anchor on a flight with a time offset: whether the offset is named
    (a rank-0 effect can be named on one run and not on another, as on a flight and
    its control) must not move the displacement, which is measured given every
    simplest candidate, named or not."""
    effects = [{"effect": "time_offset", "params": {"seconds": 0.05}},
               {"effect": "anchor_position", "params": {"anchor": 3, "offset_m": [0.2, 0.2, 0.0]}}]
    problem = Problem(simulate(sim_config(survey, effects)))
    pool = [Term(c, c.columns) for c in candidates(problem) if c.channel == "tdoa"]
    offset, = (t for t in pool if t.key == "time_offset")
    displaced, = (t for t in pool if t.key == "anchor_position:3")
    simplest = [t for t in pool if t.key in ("time_offset", "clock_drift", "lever_arm")]
    z = problem.channel("tdoa").z
    estimate_terms(z, [displaced, offset], simplest_unnamed=simplest)
    with_offset = displaced.estimate.copy()
    estimate_terms(z, [displaced], simplest_unnamed=simplest)
    np.testing.assert_allclose(displaced.estimate, with_offset, atol=1e-9)
    assert np.allclose(displaced.estimate, [0.2, 0.2, 0.0], atol=0.06)
    estimate_terms(z, [displaced])
    assert np.abs(displaced.estimate - with_offset).max() > 0.01, "without the offset it moves (the test can fail)"


def test_a_displacement_along_the_line_of_sight_reads_as_a_delay(survey) -> None:
    """Not identifiable from a small flight area: documented, and the tool says delay."""
    rec = simulate(sim_config(survey, []))
    anchor = next(a for a in rec.anchors if a.id == 3)
    line_of_sight = np.array(anchor.position) - rec.truth.position.mean(axis=0)
    offset = (0.15 * line_of_sight / np.linalg.norm(line_of_sight)).tolist()      # away from the flight
    found = findings(diagnose(simulate(sim_config(survey, [
        {"effect": "anchor_position", "params": {"anchor": 3, "offset_m": offset}}]))))
    assert ("anchor_delay", (3,)) in found and ("anchor_position", (3,)) not in found
    assert 0.08 < found[("anchor_delay", (3,))]["params"]["meters"] < 0.2


def _found_by_shape(found: dict[tuple, dict]) -> bool:
    """Whether the diagnosis found an NLOS by the shape of its residuals."""
    return any(f["where"].get("found_by", "").startswith("shape") for f in found.values())


def _simplest_tdoa(result) -> dict[tuple, tuple]:
    """The simplest (rank 0) TDOA findings: their parameters and evidence."""
    return {key: (f["params"], f["evidence"]) for key, f in findings(result).items()
            if ORDER.get(f["effect"]) == ("tdoa", 0)}


def test_nlos_found_by_its_shape_leaves_the_simplest_effects_as_they_were(real, real_diagnosis, real_control,
                                                                            monkeypatch) -> None:
    """NLOS is the richest explanation: the excess its shape takes out of the TDOA
    channel re-judges the displacements and patterns; the timing, the delays and the
    lever arm named on the channel as recorded stay, with the evidence they were
    named on, and are measured there (on 0422-log03 the shapes of four anchors used
    to drop the flight's own lever arm and time offset). The shapes may add one; on
    this flight they add none, so these are the same with and without the shapes."""
    assert _found_by_shape(real_control)
    monkeypatch.setattr("rig.diagnosis.selection.nlos_shapes", lambda *args: [])
    assert _simplest_tdoa(diagnose(real[0])) == _simplest_tdoa(real_diagnosis)


def test_a_timing_effect_that_pays_only_once_the_nlos_shapes_are_out_is_named(data_dir: Path) -> None:
    """The shapes may add a simplest effect: on 0425-traj17 the flight's own time
    offset (−180 ms) less an injected +60 ms pays only once the NLOS found by its
    shape is out of the TDOA channel, and the injected offset is then found against
    the untouched flight (missed while only the richer effects were named again
    after the shapes)."""
    rec = load_any(data_dir / "flights" / "0425-traj17")
    params, check = CASES["time_offset"]
    injected = inject(rec, [{"effect": "time_offset", "params": params}], seed=1, predictor=Predictor(rec))
    diagnosis = findings(diagnose(injected))
    assert _found_by_shape(diagnosis)
    control = diagnose(rec)
    _check(diagnosis, findings(control), "time_offset", params, check, real=True, control_unnamed=unnamed(control),
           control_in_place=in_place(control))


def test_ranges_that_read_long_with_the_tag_on_the_floor_are_located_on_their_anchor(real) -> None:
    """An excess of 0.3 m on anchor 3's ranges while the tag sits on the floor (below
    0.2 m) shows on anchor 3 alone in the mismatch's on-ground location, against the
    untouched flight (whose floor anchors read metres longer there than its ceiling
    ones)."""
    rec, predictor = real
    on_floor = {"min": [-10.0, -10.0, -10.0], "max": [10.0, 10.0, ON_GROUND_M]}
    excess = {"effect": "nlos", "params": {"anchor": 3, "fraction": 1.0, "mean_excess_m": 0.3, "region": on_floor}}
    injected = inject(rec, [excess], seed=1, predictor=predictor)
    before, after = (_on_ground(Problem(r, predictor)) for r in (rec, injected))
    moved = {k: after[k] - before[k] for k in before}
    assert 0.2 <= moved.pop("3") <= 0.35, moved
    assert all(abs(v) < 0.05 for v in moved.values()), moved


ON_THE_FLOOR = {"effect": "on_ground_delay", "params": {"height_m": 0.1, "meters": {"0": 0.4, "3": -0.3}}}


@pytest.mark.parametrize("height,fade", [(0.1, 0.0), (0.05, 0.1)], ids=["step", "fade"])
def test_ranges_that_read_long_on_the_floor_are_modelled_per_anchor(survey, height, fade) -> None:
    """Injected on the simulated flight's few seconds on the floor, the ranges' change
    is named, measured per anchor (relative to the anchors' centre, as TDOA sees it)
    with its shape (a step, or as on most real flights a fade: all of it below
    0.05 m, none above 0.15 m), and the model re-simulates the samples it touches
    down to the noise (the untouched flight names nothing:
    test_an_untouched_simulated_flight_names_nothing). The selection names
    look-alikes of anchors 0 and 3 from those seconds too (see docs/diagnosis.md); in
    the model, fitted with the floor's error, they are small."""
    floor = {"effect": "on_ground_delay", "params": {**ON_THE_FLOOR["params"], "height_m": height, "fade_m": fade}}
    result = diagnose(simulate(sim_config(survey, [floor])))
    found = findings(result)
    assert ("on_ground_delay", tuple(range(8))) in found, sorted(found)
    got = found[("on_ground_delay", tuple(range(8)))]
    assert (got["params"]["height_m"], got["params"]["fade_m"]) == (height, fade), "its shape, where it is"
    words = describe(next(f for f in result.findings if f.effect == "on_ground_delay"))
    assert f"below {height} m" in words and ("fading out" in words) == (fade > 0), words
    want = np.zeros(8)
    want[[0, 3]] = 0.4, -0.3
    measured = np.array([got["params"]["meters"][str(k)] for k in range(8)])
    np.testing.assert_allclose(measured, want - delay_centre(want), atol=0.08)
    untouched = Problem(simulate(sim_config(survey, [])))
    noise_only = robust_rms(untouched.residual_before["tdoa"], untouched.scales["tdoa"])
    assert got["fit_after"] < 1.05 * noise_only < got["fit_before"], "the model leaves the noise on the floor"


def test_ranges_that_read_long_on_the_floor_of_a_real_flight_are_measured_against_its_control(real,
                                                                                              real_control) -> None:
    """The same on the real flight, whose own floor error (metres, see
    test_ranges_that_read_long_with_the_tag_on_the_floor_are_located_on_their_anchor)
    its control carries: the injection adds to the control's values on its anchors."""
    rec, predictor = real
    found = findings(diagnose(inject(rec, [ON_THE_FLOOR], seed=1, predictor=predictor)))
    key = ("on_ground_delay", tuple(range(8)))
    added = np.array([found[key]["params"]["meters"][str(k)] - real_control[key]["params"]["meters"][str(k)]
                      for k in range(8)])
    want = np.zeros(8)
    want[[0, 3]] = 0.4, -0.3
    np.testing.assert_allclose(added - np.median(added), want - np.median(want), atol=0.1 * REAL_SLACK)


def _on_ground(problem: Problem) -> dict[str, float]:
    return locate(problem, {"tdoa": problem.channel("tdoa").residual})["tdoa_on_ground_m"]


def test_a_pattern_seen_in_a_narrow_cone_reads_as_a_displaced_anchor(survey) -> None:
    """Not identifiable from the suite's circle, whose viewing angles of anchor 2 span a
    few tens of degrees: documented, and the tool names the displaced anchor."""
    params = CASES["antenna_pattern"][0]
    found = findings(diagnose(simulate(sim_config(survey, [{"effect": "antenna_pattern", "params": params}]))))
    assert ("anchor_position", (2,)) in found and ("antenna_pattern", (2,)) not in found


def test_a_pattern_is_told_from_a_delay_and_a_displacement_only_where_the_anchor_is_seen_widely(survey) -> None:
    """What the report says a trajectory can tell apart agrees with what the diagnosis
    does: on the wider circle that passes near anchor 2, a pattern there is told from
    its delay and displacement at a size under the concealed case's (named there);
    over the suite's circle only beyond any size a pattern can physically have (the
    case then reads as a displacement, above)."""
    pattern = {}
    for label, flight in (("wide", SIM_FLIGHT["antenna_pattern"]), ("narrow", None)):
        found = identifiability(candidates(Problem(simulate(sim_config(survey, [], flight)))))
        pattern[label] = next(i for i in found if i.effect == "antenna_pattern" and i.anchors == [2])
        assert pattern[label].look_alikes == ["anchor_delay", "anchor_position"]
    injected = float(np.linalg.norm(CASES["antenna_pattern"][0]["coeffs_m"]))
    assert pattern["wide"].told_apart and pattern["wide"].smallest_told_apart < injected
    assert not pattern["narrow"].told_apart and pattern["narrow"].smallest_told_apart > pattern["narrow"].bound
    assert pattern["narrow"].smallest_seen < injected        # it shows: as its look-alikes


def test_an_excess_over_all_of_an_anchors_ranges_is_never_told_from_its_delay(survey) -> None:
    """The mean-shift NLOS against every parametric candidate: over half the room it is
    told apart at a size under the concealed case's mean shift (0.15 m); over the
    whole room it is the anchor's delay, told apart at no size."""
    problem = Problem(simulate(sim_config(survey, [])))
    pool = candidates(problem)
    params = CASES["nlos"][0]
    half = nlos_identifiability(problem, pool, params["anchor"], fx.Region.from_json(params["region"]))
    everywhere = nlos_identifiability(problem, pool, params["anchor"], fx.Region.from_json(None))
    assert half.smallest_told_apart < params["fraction"] * params["mean_excess_m"]
    assert half.smallest_seen < half.smallest_told_apart and half.unit == "m"
    assert everywhere.smallest_seen is not None and everywhere.smallest_told_apart is None


def test_a_flight_that_cannot_tell_a_z_scale_from_a_z_bias_says_both(survey) -> None:
    """A level circle at a constant speed asks the same thrust all flight: an
    accelerometer z scale is a z bias there. One of the two is named (the model
    simulates it) and the other is reported in its place on z, with its value, so
    either compares with a control recording; where the thrust varies (the suite's
    flight) the scale is named itself."""
    level = {"z_amplitude": 0.0, "yaw_amplitude": 0.0}
    scale = {"effect": "imu_accel_scale", "params": {"scale": [1.0, 1.0, 1.03]}}
    diagnosis = diagnose(simulate(sim_config(survey, [scale], level)))
    found = findings(diagnosis)
    bias, scaled = found[("imu_accel_bias", ())], found[("imu_accel_scale", ())]
    assert abs(bias["params"]["bias_mps2"][2] - 0.03 * 9.81) < 0.03
    assert abs(scaled["params"]["scale"][2] - 1.03) < 0.005
    named, alternative = (bias, scaled) if "alternative_to" in scaled else (scaled, bias)
    assert alternative["alternative_to"] == {"effect": named["effect"], "axes": ["z"]}
    assert alternative["fit_after"] < alternative["fit_before"]
    simulated = [e.name for e in diagnosis.model]
    assert named["effect"] in simulated and alternative["effect"] not in simulated, "one of the two, not both"
    varying = findings(diagnose(simulate(sim_config(survey, [scale]))))
    assert "alternative_to" not in varying[("imu_accel_scale", ())]


def test_cli_writes_the_report_contract(tmp_path: Path, survey) -> None:
    recording = tmp_path / "sim.mcap"
    subprocess.run([*RIG, "simulate", "--trajectory", "circle-sine", "--survey", str(survey), "--duration", "20",
                    "-o", str(recording)], check=True, capture_output=True)
    injected = tmp_path / "injected.mcap"
    subprocess.run([*RIG, "inject", str(recording), "--effects",
                    '[{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.3}}]', "-o", str(injected)],
                   check=True, capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(injected), "--out", str(tmp_path / "d")], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    evidence = [f["evidence"] for f in report["findings"]]
    assert evidence == sorted(evidence, reverse=True)
    for f in report["findings"]:
        assert {"effect", "channel", "params", "evidence", "fit_before", "fit_after", "where"} <= set(f)
    delay = next(f for f in report["findings"] if f["effect"] == "anchor_delay" and f["anchors"] == [2])
    assert abs(delay["params"]["meters"] - 0.3) < 0.05
    markdown = (tmp_path / "d" / "report.md").read_text()
    assert "anchor_delay" in markdown and "![" in markdown
    assert report["mismatch"]["tdoa_per_pair_m"] and "## Where they differ" in markdown
    assert "(mismatch_regions.png)" in markdown
    assert re.search(r"\*\*Anchors\*\*, how long each one's ranges read, largest first: 2: \+0\.[23]", markdown)
    for image in (tmp_path / "d").glob("*.png"):
        assert image.stat().st_size > 1000
    written = json.loads((tmp_path / "d" / "model.json").read_text())
    assert len(written["vibration_rms_mps2"]) == 3 and min(written["vibration_rms_mps2"]) > 0   # for combine-models
    model = written["effects"]
    # the model fits the named effects jointly; a finding is estimated given the simpler
    # explanations only: the two agree where no richer look-alike shares the signal
    fitted = next(e for e in model if e["effect"] == "anchor_delay" and e["params"]["anchor"] == 2)
    assert fitted["params"]["meters"] == pytest.approx(delay["params"]["meters"], abs=0.01)


def test_the_report_says_what_the_real_flight_cannot_tell_apart(tmp_path: Path, real_diagnosis) -> None:
    """On the real circles an anchor's pattern over the few tens of degrees they see of
    it is a delay and a displacement (the concealed pattern is found against its
    control only because the flight names a pattern of its own there), while a
    displacement of the concealed case's size is told from a delay: report.json says
    so for every candidate, and report.md in words."""
    report = write_report(real_diagnosis, tmp_path, "0426-traj1")
    items = keyed(report["identifiability"])
    assert {(c.effect, tuple(c.fixed.values())) for c in candidates(real_diagnosis.problem)} == set(items)
    for item in items.values():
        assert {"param", "unit", "look_alikes", "smallest_seen", "smallest_told_apart",
                "told_apart_in_every_direction", "direction", "bound", "told_apart"} <= set(item)
        assert item["smallest_seen"] <= item["smallest_told_apart"] <= item["told_apart_in_every_direction"]
    assert not any(items[("antenna_pattern", (k,))]["told_apart"] for k in range(8))
    displaced = float(np.linalg.norm(CASES["anchor_position"][0]["offset_m"]))
    assert items[("anchor_position", (3,))]["smallest_told_apart"] < displaced
    assert items[("anchor_delay", (5,))]["smallest_told_apart"] < CASES["anchor_delay"][0]["meters"]
    markdown = (tmp_path / "report.md").read_text()
    assert "## What this flight can tell apart" in markdown
    assert re.search(r"cannot tell apart from their look-alikes, at any size they can physically have: "
                     r"antenna_pattern on anchors 0, 1, 2, 3, 4, 5, 6, 7 \(told apart from [0-9.]+ m on", markdown)


def test_the_lever_arms_cross_talk_is_how_the_fitted_delays_move_with_it(real_diagnosis) -> None:
    """On the real flight: the ranges a lever arm of [2, −1, 1] cm moves, fitted with the
    delays alone (the lever arm held at none, that much short of its own), move the
    delays as reported (about their mean) by minus the cross talk times it: the share
    that `rig diagnose --control` shows is what the joint fit does."""
    pool = candidates(real_diagnosis.problem)
    cross_talk = lever_arm_cross_talk(pool)
    delays = [c for c in pool if c.effect == "anchor_delay"]
    lever = next(c for c in pool if c.effect == "lever_arm")
    assert sorted(cross_talk) == sorted(c.fixed["anchor"] for c in delays)
    moved = np.array([0.02, -0.01, 0.01])
    x = np.hstack([c.columns for c in delays])
    fitted = irls(lever.columns @ moved, x, np.array([c.prior for c in delays]))
    predicted = -np.array([cross_talk[c.fixed["anchor"]] for c in delays]) @ moved
    assert np.abs(predicted).max() > 0.002                   # the flight's geometry couples them
    assert fitted - fitted.mean() == pytest.approx(predicted, abs=2e-4)
    reported = real_diagnosis.to_json()["lever_arm_cross_talk"]
    assert [item["anchor"] for item in reported] == [c.fixed["anchor"] for c in delays]


def test_cli_diagnoses_against_a_control_recording(tmp_path: Path, survey) -> None:
    """`rig diagnose REC --control CONTROL`: the control's own report in DIR/control/,
    and each effect's change from it: a delay the control already has, grown on the
    recording, is reported as its growth; a time offset named on the recording only,
    from the control's own estimate of it below its bar; an NLOS added over half of
    the room (a list of effects too long for a file name, given inline), from the
    control's estimate in the region found."""
    simulated, control, recording = (tmp_path / name for name in ("sim.mcap", "control.mcap", "rec.mcap"))
    subprocess.run([*RIG, "simulate", "--trajectory", "circle-sine", "--survey", str(survey), "--duration", "20",
                    "-o", str(simulated)], check=True, capture_output=True)
    for source, target, effects in (
            (simulated, control, [{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.3}}]),
            (control, recording, [{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.15}},
                                  {"effect": "anchor_delay", "params": {"anchor": 6, "meters": -0.25}},
                                  {"effect": "time_offset", "params": {"seconds": 0.05}},
                                  {"effect": "nlos", "params": CASES["nlos"][0] | {"anchor": 4}}])):
        subprocess.run([*RIG, "inject", str(source), "--effects", json.dumps(effects), "-o", str(target)],
                       check=True, capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(control), "--out", str(tmp_path / "d")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    own = json.loads((tmp_path / "d" / "control" / "report.json").read_text())
    assert own["recording"] == str(control) and "against_control" not in own
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert report["against_control"]["recording"] == str(control)
    assert report["against_control"]["same_flight"] and "does not look like" not in proc.stderr   # injected: same truth
    listed = keyed(report["against_control"]["changes"])
    grown = listed[("anchor_delay", (2,))]
    assert grown["named_in"] == "both" and grown["change"]["meters"] == pytest.approx(0.15, abs=0.04)
    assert grown["recording"]["meters"] - grown["control"]["meters"] == pytest.approx(grown["change"]["meters"])
    added = listed[("anchor_delay", (6,))]
    assert added["change"]["meters"] == pytest.approx(-0.25, abs=0.04)
    late = listed[("time_offset", ())]            # on the recording only: from the control's own, unnamed
    below_bar = keyed(own["unnamed_estimates"])[("time_offset", ())]
    assert late["named_in"] == "recording" and late["control_unnamed"] == below_bar["params"]
    assert late["change"]["seconds"] == pytest.approx(late["recording"]["seconds"] - below_bar["params"]["seconds"])
    assert late["change"]["seconds"] == pytest.approx(0.05, rel=0.35)
    excess = listed[("nlos", (4,))]
    assert excess["named_in"] == "recording" and CASES["nlos"][1](excess["change"], None)
    assert grown["size"] == pytest.approx(abs(grown["change"]["meters"]))
    assert 0 < grown["told_apart_from"] < grown["size"]       # a delay of 0.15 m over 20 s: well beyond the noise
    assert "against the control: anchor_delay [2] named on both" in proc.stdout
    markdown = (tmp_path / "d" / "report.md").read_text()
    assert "## Against the control recording" in markdown and "| told apart from |" in markdown
    other = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(default_recording()),
                            "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert other.returncode == 0, other.stderr                  # another flight: compared, and said so
    assert "does not look like a control recording of the same flight" in other.stderr
    against = json.loads((tmp_path / "o" / "report.json").read_text())["against_control"]
    assert not against["same_flight"] and "m from the recording's (median)" in against["how_it_differs"]
    assert "The control does not look like the same flight" in (tmp_path / "o" / "report.md").read_text()
    missing = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(tmp_path / "none.mcap"),
                              "--out", str(tmp_path / "e")], capture_output=True, text=True)
    assert missing.returncode == 2 and "none.mcap does not exist" in missing.stderr
    assert not (tmp_path / "e").exists()          # neither diagnosed: both are read first


def test_the_report_shows_a_rectification_against_the_vibration(tmp_path: Path, real) -> None:
    """A rectification named on the real flight gets its plot: each named axis' block
    residual against its vibration RMS, before and after, linked from report.md."""
    rec, predictor = real
    injected = inject(rec, [{"effect": "imu_vibration_rectification", "params": {"gain": [0.0, -0.8, 0.0]}}],
                      seed=1, predictor=predictor)
    diagnosis = diagnose(injected)
    rectified = next(f for f in diagnosis.findings if f.effect == "imu_vibration_rectification")
    assert "y" in rectified.where["axes"]
    level = diagnosis.problem.vibration().reshape(-1, 3)
    assert level.shape == diagnosis.residual_before["accel"].reshape(-1, 3).shape and np.all(level > 0)
    write_report(diagnosis, tmp_path, "injected 0426-traj1")
    assert "](accel_vibration.png)" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "accel_vibration.png").stat().st_size > 1000


def test_bad_effects_are_refused_clearly(tmp_path: Path) -> None:
    proc = subprocess.run([*RIG, "inject", "recordings/default.mcap", "--effects",
                           '[{"effect": "warp_drive", "params": {}}]', "-o", str(tmp_path / "x.mcap")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown effect 'warp_drive'" in proc.stderr
    assert not (tmp_path / "x.mcap").exists()
    proc = subprocess.run([*RIG, "inject", "recordings/default.mcap", "--effects",
                           '[{"effect": "learned_bias", "params": {"network": "no/such/net.json"}}]',
                           "-o", str(tmp_path / "x.mcap")], capture_output=True, text=True)
    assert proc.returncode == 2 and "no bias network at no/such/net.json" in proc.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_the_fitted_model_carries_the_per_sample_noise(survey) -> None:
    """model.json simulates data like the recording: its noise is per sample (not the
    block means the IMU channels are compared on)."""
    model = fx.params_by_name(diagnose(simulate(sim_config(survey, []))).to_json()["model"])
    assert model["tdoa_noise"]["std_m"] == pytest.approx(0.15, rel=0.1)
    assert np.array(model["imu_noise"]["accel_std"]) == pytest.approx(0.5, rel=0.1)
    assert "imu_lowpass" not in model            # white noise: its spectrum does not roll off
    assert "imu_resonance" not in model          # nor peak


def test_the_imu_noise_level_is_the_rms_less_glitches() -> None:
    """The model's IMU noise has the readings' RMS around their running mean, not a
    robust spread, which heavy-tailed shaking exceeds (Student's t with 3 degrees of
    freedom: RMS 1.7 times the robust σ); two readings at the sensor's full range
    (±16 g) in 40 s move it by under 3 %."""
    t = np.arange(0.0, 40.0, 0.001)
    rng = np.random.default_rng(0)
    shaken = rng.normal(0.0, 1.0, (len(t), 3)) * [1.0, 0.5, 0.2]       # each axis its own
    assert vibration_spread(Vec3Series(t, shaken)) == pytest.approx([1.0, 0.5, 0.2], rel=0.02)
    heavy = rng.standard_t(3, (len(t), 3)) * 0.5
    assert vibration_spread(Vec3Series(t, heavy)) == pytest.approx(heavy.std(axis=0), rel=0.05)
    assert np.all(vibration_spread(Vec3Series(t, heavy)) > 1.4 * np.array([mad_scale(v) for v in heavy.T]))
    spiked = heavy.copy()
    spiked[100], spiked[20000] = 157.0, -157.0
    assert vibration_spread(Vec3Series(t, spiked)) == pytest.approx(vibration_spread(Vec3Series(t, heavy)), rel=0.03)


def test_a_low_pass_on_the_imu_is_in_the_model_with_the_white_noise_before_it(survey) -> None:
    """A flight whose IMU readings went through the flight controller's low-pass (the
    Crazyflie's defaults, 30 and 80 Hz), with more noise on some axes than on others:
    model.json has the filter's corners and the white noise before it, axis by axis,
    and the filter alone makes no finding."""
    lowpass = {"effect": "imu_lowpass", "params": {"accel_hz": 30.0, "gyro_hz": 80.0}}
    uneven = {"effect": "imu_noise", "params": {"accel_std": [0.0, 0.5, 1.0], "gyro_std": [0.1, 0.0, 0.0]}}
    result = diagnose(simulate(sim_config(survey, [uneven, lowpass]))).to_json()
    model = fx.params_by_name(result["model"])
    assert model["imu_lowpass"]["accel_hz"] == pytest.approx(30.0, rel=0.1)
    assert model["imu_lowpass"]["gyro_hz"] == pytest.approx(80.0, rel=0.1)
    # on top of the suite's 0.5 m/s² and 0.05 rad/s on every axis
    assert model["imu_noise"]["accel_std"] == pytest.approx(np.hypot(0.5, [0.0, 0.5, 1.0]), rel=0.1)
    assert model["imu_noise"]["gyro_std"] == pytest.approx(np.hypot(0.05, [0.1, 0.0, 0.0]), rel=0.1)
    assert "imu_resonance" not in model
    assert result["findings"] == []


def test_the_airframes_slow_shaking_is_in_the_model_as_a_resonance(survey) -> None:
    """A gyroscope that shakes at 7 Hz on x and y (white noise through a peak, like
    the real flights' attitude wobble), behind the low-pass: model.json has the peak's
    frequency within 10 % and its size per axis within 15 %, the white noise apart,
    and the shaking makes no finding."""
    lowpass = {"effect": "imu_lowpass", "params": {"accel_hz": 30.0, "gyro_hz": 80.0}}
    wobble = {"effect": "imu_resonance", "params": {"gyro_std": [0.1, 0.08, 0.0], "gyro_hz": 7.0, "gyro_q": 3.0}}
    result = diagnose(simulate(sim_config(survey, [wobble, lowpass]))).to_json()
    model = fx.params_by_name(result["model"])
    peak = model["imu_resonance"]
    assert peak["gyro_hz"] == pytest.approx(7.0, rel=0.1) and peak["accel_hz"] == 0.0
    assert peak["gyro_std"] == pytest.approx([0.1, 0.08, 0.0], abs=0.015)
    assert np.array(model["imu_noise"]["gyro_std"]) == pytest.approx(0.05, rel=0.2)
    assert result["findings"] == []


def test_the_cli_says_the_imu_was_low_pass_filtered_and_shook(tmp_path: Path, survey) -> None:
    """`rig diagnose` names the low-pass and the noise's peak on its console too, and
    model.json carries them, so `rig simulate` can fly the model."""
    config = tmp_path / "sim.json"
    config.write_text(json.dumps({"trajectory": "circle-sine", "duration": 20.0, "survey": str(survey), "effects": [
        {"effect": "imu_noise", "params": {"accel_std": 0.5, "gyro_std": 0.05}},
        {"effect": "imu_resonance", "params": {"gyro_std": [0.1, 0.1, 0.0], "gyro_hz": 7.0, "gyro_q": 3.0}},
        {"effect": "imu_lowpass", "params": {"accel_hz": 30.0, "gyro_hz": 80.0}}]}))
    subprocess.run([*RIG, "simulate", "--config", str(config), "-o", str(tmp_path / "sim.mcap")], check=True,
                   capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(tmp_path / "sim.mcap"), "--out", str(tmp_path / "d")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    said = re.search(r"IMU readings low-pass filtered before logging: (\d+) Hz \(accelerometer\)", proc.stdout)
    assert said and 27 <= int(said.group(1)) <= 33, proc.stdout
    peak = re.search(r"IMU noise peaks at ([\d.]+) Hz \(gyroscope\)", proc.stdout)
    assert peak and 6.3 <= float(peak.group(1)) <= 7.7, proc.stdout
    model = json.loads((tmp_path / "d" / "model.json").read_text())["effects"]
    lowpass = next(e["params"] for e in model if e["effect"] == "imu_lowpass")
    assert lowpass["accel_hz"] == pytest.approx(30.0, rel=0.1)
    assert any(e["effect"] == "imu_resonance" for e in model)
    config.write_text(json.dumps({"trajectory": "circle-sine", "duration": 5.0, "survey": str(survey),
                                  "effects": model}))
    subprocess.run([*RIG, "simulate", "--config", str(config), "-o", str(tmp_path / "again.mcap")], check=True,
                   capture_output=True)


def test_a_real_flights_model_has_its_noise_spectrum(tmp_path: Path, real, real_diagnosis) -> None:
    """The real flight's IMU readings roll off above a few tens of Hz (the firmware's
    filter): its model carries the low-pass, and a simulation of the flight from the
    model's noise has the recorded spectrum (log spectral distance, 10 Hz to 0.45 ×
    the sample rate, under a third of what white noise of the recorded spread gives;
    under 10 % of the power above 100 Hz, where white noise has most of it) and each
    axis's recorded spread. The report says so and plots the spectra."""
    rec, _ = real
    write_report(real_diagnosis, tmp_path, REAL_FLIGHT)
    markdown = (tmp_path / "report.md").read_text()
    assert "low-pass filtered before they were logged" in markdown and "](imu_spectrum.png)" in markdown
    assert (tmp_path / "imu_spectrum.png").stat().st_size > 1000
    model = {e["effect"]: e for e in real_diagnosis.to_json()["model"]}
    assert 25.0 <= model["imu_lowpass"]["params"]["accel_hz"] <= 60.0
    assert 30.0 <= model["imu_lowpass"]["params"]["gyro_hz"] <= 100.0
    white = [{"effect": "imu_noise", "params": {"accel_std": vibration_spread(rec.accel).tolist(),
                                                "gyro_std": vibration_spread(rec.gyro).tolist()}}]
    config = SimConfig(trajectory="recording", recording=str(rec.metadata["source"]), seed=1)
    assert model["imu_resonance"]["params"]["gyro_hz"] == pytest.approx(7.0, abs=2.0)     # the attitude wobble
    modelled = simulate(replace(config, effects=[model["imu_noise"], model["imu_resonance"], model["imu_lowpass"]]))
    unfiltered = simulate(replace(config, effects=white))
    clean = simulate(replace(config, effects=[model["imu_lowpass"]]))
    for sensor in ("accel", "gyro"):
        recorded = _band_spectrum(getattr(rec, sensor))
        fitted, flat = _band_spectrum(getattr(modelled, sensor)), _band_spectrum(getattr(unfiltered, sensor))
        assert _log_distance(fitted, recorded) < _log_distance(flat, recorded) / 3, sensor
        assert imu_spectrum.share_above(*fitted, 100.0) < 0.1 < 0.5 < imu_spectrum.share_above(*flat, 100.0), sensor
        # each axis its own size: this flight's accelerometer shakes 0.41-0.52 m/s², its gyroscope
        # 0.013-0.078 rad/s (the noise the model adds, through its filter: the ground truth's rates are noisy)
        noise = Vec3Series(clean.accel.t, getattr(modelled, sensor).xyz - getattr(clean, sensor).xyz)
        assert vibration_spread(noise) == pytest.approx(vibration_spread(getattr(rec, sensor)), rel=0.1), sensor
        # what a 100 Hz estimator takes in (10 ms means), axis by axis: with the gyroscope's 7 Hz wobble
        # in the model within 10 % of the recording's (0.80-0.85 of it without)
        assert _means_spread(noise) == pytest.approx(_means_spread(getattr(rec, sensor)), rel=0.1), sensor


def _means_spread(series) -> np.ndarray:
    """Per axis, the spread of 10 ms means of a series' fast part."""
    return imu_spectrum.means_spread(*imu_spectrum.fast_part(series), 0.01)


def _band_spectrum(series) -> tuple[np.ndarray, np.ndarray]:
    spec = imu_spectrum.spectrum(series)
    band = imu_spectrum.fit_band(spec)
    return spec.freq[band], spec.power[:, band].mean(axis=0)


def _log_distance(a: tuple, b: tuple) -> float:
    return float(np.mean(np.abs(np.log10(a[1] / np.interp(a[0], *b)))))


def test_corrupt_ranges_and_a_ground_truth_glitch_are_left_out_not_chased(survey, sim_control) -> None:
    """Ranges off by 100 m and the motion capture turning the drone's attitude half
    round for 0.4 s (a marker swap; 0425-traj9 has such a glitch, read as a yaw rate of
    10 rad/s) are left out and counted, and no effect is named to explain them (an
    accelerometer scale of [−0.02, 0.22, 1.0] was). So are samples that cannot be
    used at all: not finite, or a range from an anchor the anchor set lacks."""
    rec = simulate(sim_config(survey, []))
    ranges = rec.tdoa.distance_diff.copy()
    ranges[1000:1040:4] += 100.0
    ranges[2000:2007] = np.nan
    id_b = rec.tdoa.id_b.copy()
    id_b[3000:3003] = 42
    accel = rec.accel.xyz.copy()
    accel[20000:20005, 1] = np.inf
    quaternion = rec.truth.quaternion.copy()
    flipped = (rec.truth.t > 20.0) & (rec.truth.t < 20.4)
    quaternion[flipped] = (Rotation.from_euler("z", np.pi) * Rotation.from_quat(quaternion[flipped])).as_quat()
    glitched = replace(rec, tdoa=replace(rec.tdoa, distance_diff=ranges, id_b=id_b),
                       accel=replace(rec.accel, xyz=accel), truth=replace(rec.truth, quaternion=quaternion))
    result = diagnose(glitched).to_json()
    assert result["channels"]["tdoa"]["gross_errors_left_out"] == 10
    assert [result["channels"][name]["unusable_left_out"] for name in ("tdoa", "accel", "gyro")] == [10, 5, 0]
    assert result["unknown_anchors"] == [42]
    assert result["channels"]["gyro"]["gross_errors_left_out"] >= 3         # a block mean of each axis
    assert set(keyed(result["findings"])) == set(sim_control), "the same flight, untouched, names these"


def test_a_scale_regressed_on_the_recording_reports_its_value_and_error_in_the_scales_unit() -> None:
    """recorded − predicted = θ · (w · recorded + (1 − w) · predicted): the scale is
    1 + θ / (1 − w θ) (on the recording alone 1 / (1 − θ)), and a standard error of θ
    is carried by that map's slope; any other parameter is neutral + θ."""
    theta = np.array([0.05, -0.1, 0.0])
    on_recording = Candidate("imu_gyro_scale", "gyro", "scale", 3, neutral=1.0, recorded_weight=1.0)
    assert np.allclose(on_recording.value(theta), 1.0 / (1.0 - theta))
    assert np.allclose(on_recording.make(theta).params()["scale"], 1.0 / (1.0 - theta))
    weights = np.array([0.0, 0.5, 1.0])
    mixed = Candidate("imu_gyro_scale", "gyro", "scale", 3, neutral=1.0, recorded_weight=weights)
    for s in (0.9, 1.1):    # noise-free: the fitted θ of a scale s maps back to s
        assert np.allclose(mixed.value((s - 1.0) / (weights * s + 1.0 - weights)), s)
    h = 1e-6
    for candidate in (on_recording, mixed):
        numeric = (candidate.value(theta + h) - candidate.value(theta - h)) / (2 * h)
        assert np.allclose(candidate.value_slope(theta), numeric, rtol=1e-6)
    plain = Candidate("imu_gyro_bias", "gyro", "bias_rps", 3)
    assert np.allclose(plain.value(theta), theta) and np.allclose(plain.value_slope(theta), 1.0)
