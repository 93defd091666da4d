"""Proof of the diagnosis on concealed effects: each catalog effect injected, at a
per-sample size at or below the noise (checked here, so it is invisible in a residual
plot), into (a) a simulated flight and (b) a real shared flight, compared with the
untouched flight as control (real flights carry real effects). The tool must name the
effect, locate it (anchor, axis), recover its parameters within the stated tolerance
and fit better with it than without. Plus harder cases: two effects at once, an effect
in part of the flight, look-alikes. Effects this data cannot identify are marked as
expected failures with the reason (strict: they fail the suite once they pass).

The cases, their checks and the fixtures' helpers, shared by the diagnosis tests."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rig.data.recording import Recording
from rig.diagnosis import compare, imu_spectrum
from rig.diagnosis.channels import Problem
from rig.diagnosis.mismatch import locate
from rig.diagnosis.robust import mad_scale
from rig.diagnosis.terms import ORDER
from rig.sim.simulate import Predictor, SimConfig, inject

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


def findings(result) -> dict[tuple, dict]:
    """Every fit a diagnosis reports: its findings and the fits beyond their physical
    bound it leaves not explained (a concealed effect moves either)."""
    return keyed(compare.every_fit(result.to_json()))


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


REAL_SLACK = 1.5


def vector_close(key: str, tol: float):
    return lambda got, want, slack=1.0: np.allclose(got[key], want[key], atol=tol * slack)


def scalar_close(key: str, rel: float):
    return lambda got, want, slack=1.0: abs(got[key] - want[key]) <= rel * slack * abs(want[key])


def axis_close(key: str, axis: int, tol: float):
    """Only `axis` of a vector judged: the others are not injected, and a real flight
    names its own on them."""
    return lambda got, want, slack=1.0: abs(got[key][axis] - want[key][axis]) < tol * slack


CASES = {
    "time_offset": ({"seconds": 0.06}, scalar_close("seconds", 0.35)),
    "clock_drift": ({"ppm": 2000.0}, scalar_close("ppm", 0.25)),
    "anchor_delay": ({"anchor": 5, "meters": 0.12}, scalar_close("meters", 0.25)),
    "anchor_position": ({"anchor": 3, "offset_m": [0.2, 0.2, 0.0]}, vector_close("offset_m", 0.06)),
    "antenna_pattern": ({"anchor": 2, "coeffs_m": [0.3, 0.2, 0.0]}, vector_close("coeffs_m", 0.15)),
    # its mean shift (fraction × mean excess) over the region found, less the control's there
    "nlos": ({"anchor": 6, "fraction": 0.5, "mean_excess_m": 0.3, "region": {"min": [-5, 0, -1], "max": [5, 5, 5]}},
             lambda got, want, slack=1.0: 0.05 <= got["mean_shift_m"] <= 0.3),
    "multipath_floor": ({"height_m": 0.6, "std_m": 0.2},
                        lambda got, want, slack=1.0: 0.25 <= got["height_m"] <= 1.0 and 0.1 <= got["std_m"] <= 0.35),
    "imu_accel_bias": ({"bias_mps2": [0.0, 0.15, 0.0]}, vector_close("bias_mps2", 0.03)),
    "imu_gyro_bias": ({"bias_rps": [0.0, 0.0, 0.02]}, vector_close("bias_rps", 0.004)),
    "imu_accel_scale": ({"scale": [1.0, 1.0, 1.03]}, axis_close("scale", 2, 0.01)),
    "imu_gyro_scale": ({"scale": [1.0, 1.0, 1.1]}, axis_close("scale", 2, 0.03)),
    # 0.8 × the y axis' vibration RMS: 0.2 m/s² on the suite's real flight, in flight only
    "imu_vibration_rectification": ({"gain": [0.0, -0.8, 0.0]}, vector_close("gain", 0.2)),
    # sideways: a vertical lever arm in near-level flight is the tag raised, which TDOA
    # reads as delays of the ceiling anchors against the floor ones (not identifiable)
    "lever_arm": ({"offset_m": [0.08, 0.0, 0.0]}, vector_close("offset_m", 0.03)),
}


IMU_VECTOR = {"imu_accel_bias": "bias_mps2", "imu_gyro_bias": "bias_rps", "imu_accel_scale": "scale",
              "imu_gyro_scale": "scale", "imu_vibration_rectification": "gain"}


def injected_axes(name: str, params: dict) -> list[str] | None:
    """The axes an injected IMU effect moves off neutral, which its finding must
    locate (None for the other effects)."""
    if name not in IMU_VECTOR:
        return None
    return [axis for axis, value in zip("xyz", params[IMU_VECTOR[name]]) if value != compare.neutral(name)]


SIM_FLIGHT = {"antenna_pattern": {"center": [1.5, 1.5], "radius": 2.5, "z_amplitude": 0.8}}


SIM_SHAKING = {"imu_vibration_rectification": [{"effect": "imu_vibration", "params": {"accel_std": [1.0, 1.0, 0.0]}}]}


NOT_ON_SIM: dict[str, str] = {}


def sim_case(survey: Path, name: str, effects: list[dict]) -> SimConfig:
    """The simulated flight of `name`'s case, with `effects` injected."""
    return sim_config(survey, SIM_SHAKING.get(name, []) + effects, SIM_FLIGHT.get(name))


def own_sim_control(name: str) -> bool:
    """Whether `name`'s case flies its own simulated flight, so has its own control."""
    return name in SIM_FLIGHT or name in SIM_SHAKING


NOT_ON_REAL: dict[str, str] = {}


def mark(name: str, known: dict) -> list:
    return [pytest.mark.xfail(strict=True, reason=known[name])] if name in known else []


def check_case(found: dict, control: dict, name: str, params: dict, check, real: bool = False,
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
        check_cancelled(control[key], name, params, check, real)
        return
    assert key in found, f"{name} not named; found {sorted(found)}"
    got = compare.change(name, list(key[1]), found[key], control.get(key), samples,
                         (control_unnamed or {}).get(key), control_samples=control_samples,
                         control_in_place=control_in_place).change
    got = got or dict(found[key]["params"])
    check_unidentified(found[key], got, params)
    assert check(got, params, REAL_SLACK if real else 1.0), f"{name}: got {got}, injected {params}"
    assert found[key]["fit_after"] < found[key]["fit_before"]
    expected = injected_axes(name, params)
    if expected is not None:         # on a real flight, the axes of the flight's own biases come too
        located = found[key]["where"]["axes"]
        assert set(expected) <= set(located) if real else located == expected
    if "anchor" in params:
        assert found[key]["where"]["anchors"] == [params["anchor"]]
    if "region" in params:
        check_region(found[key]["params"], params, samples)


NLOS_LOCATED = 0.5      # of the samples in the region found, at least this share inside the injected one


def check_region(got: dict, params: dict, samples: compare.TdoaSamples | None) -> None:
    """An NLOS is located where most of the samples its region holds (the tag inside,
    the anchor in the pair) are inside the injected region."""
    assert samples is not None, "an NLOS is judged over the injected recording's TDOA samples"
    found = samples.inside(params["anchor"], got["region"])
    share = float(np.mean(samples.inside(params["anchor"], params["region"])[found])) if found.any() else 0.0
    assert share >= NLOS_LOCATED, f"nlos: {share:.0%} of the region found {got['region']} is in the injected one"


CANCELLABLE = compare.CANCELLABLE


def check_cancelled(own: dict, name: str, params: dict, check, real: bool) -> None:
    got = compare.change(name, [], None, own).change
    assert check(got, params, REAL_SLACK if real else 1.0), \
        f"{name}: not named, its control's {own['params']} not cancelled by the injected {params}"
    assert own["fit_after"] < own["fit_before"]


UNIDENTIFIED_SE = 2.0      # a component the tool says it cannot identify: within this many standard errors


def check_unidentified(finding: dict, got: dict, params: dict) -> None:
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


def clock_started_earlier(rec: Recording, seconds: float) -> Recording:
    """The same flight on a clock that started `seconds` earlier (0422-log00 flies at
    82–132 s of its recording's clock)."""
    return replace(rec, **{name: replace(getattr(rec, name), t=getattr(rec, name).t + seconds)
                           for name in ("accel", "gyro", "tdoa", "truth")})


def found_by_shape(found: dict[tuple, dict]) -> bool:
    """Whether the diagnosis found an NLOS by the shape of its residuals."""
    return any(f["where"].get("found_by", "").startswith("shape") for f in found.values())


def simplest_tdoa(result) -> dict[tuple, tuple]:
    """The simplest (rank 0) TDOA findings: their parameters and evidence."""
    return {key: (f["params"], f["evidence"]) for key, f in findings(result).items()
            if ORDER.get(f["effect"]) == ("tdoa", 0)}


ON_THE_FLOOR = {"effect": "on_ground_delay", "params": {"height_m": 0.1, "meters": {"0": 0.4, "3": -0.3}}}


def on_ground(problem: Problem) -> dict[str, float]:
    return locate(problem, {"tdoa": problem.channel("tdoa").residual})["tdoa_on_ground_m"]


def means_spread(series) -> np.ndarray:
    """Per axis, the spread of 10 ms means of a series' fast part."""
    return imu_spectrum.means_spread(*imu_spectrum.fast_part(series), 0.01)


def band_spectrum(series) -> tuple[np.ndarray, np.ndarray]:
    spec = imu_spectrum.spectrum(series)
    band = imu_spectrum.fit_band(spec)
    return spec.freq[band], spec.power[:, band].mean(axis=0)


def log_distance(a: tuple, b: tuple) -> float:
    return float(np.mean(np.abs(np.log10(a[1] / np.interp(a[0], *b)))))
