"""What a recording adds to its control (rig.diagnosis.compare, `rig diagnose --control`), on
findings written out by hand; the concealed-effect tests judge every real case
through it (tests/test_diagnose.py), the CLI test runs it end to end."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rig.data.paths import default_recording
from rig.data.recording import read_recording
from rig.diagnosis.compare import TdoaSamples, by_size, change, changes, flight_difference
from rig.diagnosis.identifiability import assess
from rig.diagnosis.report import change_text

pytestmark = pytest.mark.slow        # left out of `make test-fast`


def _finding(effect: str, params: dict, evidence: float = 50.0, std_err: dict | None = None, **extra) -> dict:
    return {"effect": effect, "params": params, "evidence": evidence, "std_err": std_err or {}, **extra}


def test_a_change_is_the_recordings_parameters_less_the_controls() -> None:
    delay = change("anchor_delay", [5],
                   _finding("anchor_delay", {"anchor": 5, "meters": 0.30}, std_err={"meters": 0.02}),
                   _finding("anchor_delay", {"anchor": 5, "meters": 0.18}))
    assert delay.named_in == "both" and delay.change["anchor"] == 5
    assert delay.change["meters"] == pytest.approx(0.12)
    assert delay.std_errs == pytest.approx(6.0)
    scale = change("imu_accel_scale", [], _finding("imu_accel_scale", {"scale": [1.0, 1.01, 1.04]},
                                                   std_err={"scale": [0.01, 0.01, 0.01]}),
                   _finding("imu_accel_scale", {"scale": [1.0, 1.01, 1.01]}))
    assert scale.change["scale"] == pytest.approx([1.0, 1.0, 1.03])        # a scale's change stays a scale
    assert scale.std_errs == pytest.approx(3.0)                            # measured from one, not zero


def test_against_the_same_flight_a_change_is_measured_in_independent_samples_standard_errors() -> None:
    """Two recordings of one flight share its slow TDOA error: their change is measured
    in `std_err_independent`; against another flight, in `std_err`, which counts it."""
    recording = [_finding("anchor_delay", {"anchor": 5, "meters": 0.30}, std_err={"meters": 0.08},
                          std_err_independent={"meters": 0.02})]
    control = [_finding("anchor_delay", {"anchor": 5, "meters": 0.18})]
    assert changes(recording, control)[0].std_errs == pytest.approx(1.5)
    assert changes(recording, control, same_flight=True)[0].std_errs == pytest.approx(6.0)
    older = [_finding("anchor_delay", {"anchor": 5, "meters": 0.30}, std_err={"meters": 0.08})]
    assert changes(older, control, same_flight=True)[0].std_errs == pytest.approx(1.5)    # a report without it


def test_a_delay_confined_to_a_window_on_one_recording_is_compared_outside_it() -> None:
    confined = {"anchor": 2, "meters": 0.5, "during": [10.0, 20.0], "outside_m": 0.1}
    got = change("anchor_delay", [2], _finding("anchor_delay", confined),
                 _finding("anchor_delay", {"anchor": 2, "meters": 0.04}))
    assert got.change == {"anchor": 2, "meters": pytest.approx(0.06)}


def test_a_clock_effect_the_recording_cancels_changed_to_neutral() -> None:
    """Named on the control only: the recording's own plus the added one is about none."""
    offset = change("time_offset", [], None, _finding("time_offset", {"seconds": -0.05}))
    assert offset.named_in == "control" and offset.change == {"seconds": pytest.approx(0.05)}
    gone = change("anchor_position", [3], None, _finding("anchor_position", {"anchor": 3, "offset_m": [0.1, 0, 0]}))
    assert gone.named_in == "control" and gone.change is None


def test_an_effect_the_control_does_not_name_changes_from_its_estimate_there() -> None:
    """The flight's own drift, −1100 ppm below the control's bar, plus an added 2000
    reads +900 ppm named: a change of 2000 from the control's estimate. Without one
    (an effect not among the estimated), from neutral."""
    drift = _finding("clock_drift", {"ppm": 900.0})
    got = change("clock_drift", [], drift, None, control_unnamed=_finding("clock_drift", {"ppm": -1100.0}))
    assert got.named_in == "recording" and got.change == {"ppm": pytest.approx(2000.0)}
    assert got.to_json()["control_unnamed"] == {"ppm": -1100.0}
    assert change("clock_drift", [], drift, None).change == {"ppm": 900.0}
    listed = changes([drift], [], control_unnamed=[{"effect": "clock_drift", "params": {"ppm": -1100.0}}])
    assert listed[0].change == {"ppm": pytest.approx(2000.0)}
    named_on_both = change("clock_drift", [], drift, _finding("clock_drift", {"ppm": 100.0}),
                           control_unnamed=_finding("clock_drift", {"ppm": -1100.0}))
    assert named_on_both.change == {"ppm": pytest.approx(800.0)} and named_on_both.control_unnamed is None


def test_an_imu_effect_the_control_does_not_name_changes_from_its_estimate_on_the_named_axes() -> None:
    """The flight's own x rectification, −0.6 below the control's bar, rides on an
    added y −0.8: the recording names x −0.64 and y −0.86, a change of about none on
    x. A gyroscope scale named on z only (x, y not named: neutral) changes from the
    control's estimate on z and not at all on x and y, whatever it reads there."""
    rectification = _finding("imu_vibration_rectification", {"gain": [-0.64, -0.86, 0.25]})
    own = _finding("imu_vibration_rectification", {"gain": [-0.60, -0.05, 0.22]})
    got = change("imu_vibration_rectification", [], rectification, None, control_unnamed=own)
    assert got.change["gain"] == pytest.approx([-0.04, -0.81, 0.03])
    scale = _finding("imu_gyro_scale", {"scale": [1.0, 1.0, 1.11]}, not_named_axes=["x", "y"])
    own_scale = _finding("imu_gyro_scale", {"scale": [0.95, 1.04, 1.01]})
    got = change("imu_gyro_scale", [], scale, None, control_unnamed=own_scale)
    assert got.change["scale"] == pytest.approx([1.0, 1.0, 1.10])
    assert got.to_json()["control_unnamed"] == {"scale": [1.0, 1.0, 1.01]}      # as compared
    back = change("imu_gyro_scale", [], None, scale, recording_unnamed=own_scale)
    assert back.change["scale"] == pytest.approx([1.0, 1.0, 0.90])


def test_an_effect_in_a_look_alikes_place_on_one_recording_changes_from_the_others_estimate_in_that_place() -> None:
    """0422-log00's control names a z scale of 0.89 jointly with a z bias of 0.98
    (its flight tells the two apart); with 1.03 injected the recording names the bias
    and the scale in its place on z, 1.020. Against the control's joint 0.89 that is
    a change of 0.13; against the control's scale in its bias's place on z, 0.990, it
    is 0.03. The axes the recording's does not take are neutral on both sides."""
    instead = {"effect": "imu_accel_bias", "axes": ["z"]}
    in_bias_place = _finding("imu_accel_scale", {"scale": [1.0, 1.0, 1.02]}, alternative_to=instead)
    joint = _finding("imu_accel_scale", {"scale": [1.10, 0.87, 0.89]})
    own_in_place = [{"effect": "imu_accel_scale", "params": {"scale": [0.95, 0.90, 0.99]},
                     "in_place_of": {"effect": "imu_accel_bias", "axes": ["x", "y", "z"]}},
                    {"effect": "imu_accel_bias", "params": {"bias_mps2": [0.03, -0.06, -0.09]},
                     "in_place_of": {"effect": "imu_accel_scale", "axes": ["x", "y", "z"]}}]
    got = change("imu_accel_scale", [], in_bias_place, joint, control_in_place=own_in_place)
    assert got.named_in == "both" and got.change["scale"] == pytest.approx([1.0, 1.0, 1.03])
    assert got.to_json()["control_in_place"] == {"scale": [1.0, 1.0, 0.99]}
    assert change("imu_accel_scale", [], in_bias_place, joint).change["scale"][2] == pytest.approx(1.13)
    unnamed_there = change("imu_accel_scale", [], in_bias_place, None, control_in_place=own_in_place)
    assert unnamed_there.named_in == "recording" and unnamed_there.change["scale"][2] == pytest.approx(1.03)
    both_in_place = change("imu_accel_scale", [], in_bias_place, _finding("imu_accel_scale", {"scale": [1.0, 1.0, 0.99]},
                                                                        alternative_to=instead),
                           control_in_place=[{**own_in_place[0], "params": {"scale": [1.0, 1.0, 0.5]}}])
    assert both_in_place.change["scale"][2] == pytest.approx(1.03) and both_in_place.control_in_place is None
    reverse = changes([joint], [in_bias_place], recording_in_place=own_in_place)      # the other way round
    assert reverse[0].change["scale"] == pytest.approx([1.0, 1.0, 0.97])


def test_an_effect_named_on_the_control_only_changes_to_the_recordings_estimate_of_it() -> None:
    """The control's offset, −50 ms, plus an added +60 ms is +10 ms, below the
    recording's bar: a change of +60 ms to its estimate there; without one, a clock
    effect's change is to neutral, and any other effect's is none."""
    own = _finding("time_offset", {"seconds": -0.05})
    got = change("time_offset", [], None, own, recording_unnamed=_finding("time_offset", {"seconds": 0.01}))
    assert got.named_in == "control" and got.change == {"seconds": pytest.approx(0.06)}
    assert got.to_json()["recording_unnamed"] == {"seconds": 0.01}
    assert got.std_errs is None                      # the recording's estimate carries no standard error
    measured = change("time_offset", [], None, own, recording_unnamed=_finding(
        "time_offset", {"seconds": 0.01}, std_err={"seconds": 0.03}, std_err_independent={"seconds": 0.01}))
    assert measured.std_errs == pytest.approx(2.0)   # in the standard errors of the estimate it goes to
    measured.shares_slow_error = True
    assert measured.std_errs == pytest.approx(6.0)
    assert measured.to_json()["change_std_errs"] == pytest.approx(6.0)
    assert change("time_offset", [], None, own).change == {"seconds": pytest.approx(0.05)}
    delay = _finding("anchor_delay", {"anchor": 3, "meters": 0.2})
    assert change("anchor_delay", [3], None, delay).change is None
    gone = changes([], [{**delay, "anchors": [3]}],
                   recording_unnamed=[{"effect": "anchor_delay", "anchors": [3], "params": {"anchor": 3, "meters": 0.05}}])
    assert gone[0].change == {"anchor": 3, "meters": pytest.approx(-0.15)}


def test_the_floors_effects_are_listed_not_subtracted() -> None:
    floor = {"height_m": 0.6, "std_m": 0.2}
    got = change("multipath_floor", [], _finding("multipath_floor", floor),
                 _finding("multipath_floor", {**floor, "std_m": 0.1}))
    assert got.change is None
    assert got.recording["params"]["std_m"] == 0.2 and got.control["params"]["std_m"] == 0.1


def _nlos_samples(fraction: float, seed: int) -> TdoaSamples:
    """Anchor 6's ranges over a room, unit noise of 0.1 m, those with the tag at y > 0 a
    `fraction` of them 0.3 m long on average (exponential), beside ranges of other
    anchors and on the floor that read metres long and must not count."""
    rng = np.random.default_rng(seed)
    n = 8000
    positions = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(0.5, 2, n)])
    pairs = np.where(rng.random(n)[:, None] < 0.5, [6, 1], [2, 6])
    sign = np.where(pairs[:, 1] == 6, 1.0, -1.0)
    excess = (positions[:, 1] > 0) * (rng.random(n) < fraction) * rng.exponential(0.3, n)
    left = rng.standard_normal(n) + sign * excess / 0.1
    others = np.column_stack([rng.uniform(-2, 2, 500), rng.uniform(0, 2, 500), np.full(500, 1.0)])
    on_floor = np.column_stack([rng.uniform(-2, 2, 500), rng.uniform(0, 2, 500), np.zeros(500)])
    return TdoaSamples(np.vstack([positions, others, on_floor]),
                       np.vstack([pairs, np.tile([1, 2], (500, 1)), np.tile([6, 1], (500, 1))]),
                       np.concatenate([left, np.full(500, 30.0), np.full(500, -30.0)]), 0.1)


@pytest.mark.parametrize("where", [{"found_by": "shape (a positive exponential tail)"}, {}],
                         ids=["by shape", "by mean shift"])
def test_an_nlos_changes_by_both_recordings_estimates_in_the_region_found(where: dict) -> None:
    """The control has excess paths of its own where the recording's were added (a
    fifth of its ranges there, against half) and names none: the change is the
    difference of the two estimates in the recording's region, made as the search
    that found it makes them, not the recording's whole excess. Named on the control
    only, it is estimated in the control's region."""
    recording, control = _nlos_samples(0.5, seed=1), _nlos_samples(0.2, seed=2)
    half = {"anchor": 6, "fraction": 0.5, "mean_excess_m": 0.3, "region": {"min": [-5, 0, -1], "max": [5, 5, 5]}}
    nlos = _finding("nlos", half, anchors=[6], where=where)
    tolerance = 0.02 if where else 0.04          # a Huber mean takes less of a skewed excess on both
    got = change("nlos", [6], nlos, None, recording, control_samples=control).change["mean_shift_m"]
    assert got == pytest.approx(0.3 * (0.5 - 0.2), abs=tolerance)
    gone = change("nlos", [6], None, nlos, control, control_samples=recording).change["mean_shift_m"]
    assert gone == pytest.approx(-got, abs=0.01)
    assert change("nlos", [6], nlos, nlos, recording).change is None      # the control's samples not at hand
    again = TdoaSamples.from_json(recording.to_json())
    assert change("nlos", [6], nlos, None, again, control_samples=control).change["mean_shift_m"] == \
        pytest.approx(got, abs=1e-3)


def test_changes_cover_both_recordings_and_list_the_telling_ones_first() -> None:
    recording = [_finding("anchor_delay", {"anchor": 1, "meters": 0.2}, 90.0, {"meters": 0.1}, anchors=[1]),
                 _finding("lever_arm", {"offset_m": [0.1, 0.0, 0.0]}, 40.0, {"offset_m": [0.01, 0.01, 0.01]}),
                 _finding("imu_gyro_bias", {"bias_rps": [0.0, 0.0, 0.02]}, 30.0)]
    control = [_finding("anchor_delay", {"anchor": 1, "meters": 0.1}, 80.0, anchors=[1]),
               _finding("lever_arm", {"offset_m": [0.05, 0.0, 0.0]}, 20.0),
               _finding("time_offset", {"seconds": 0.04}, 12.0)]
    listed = changes(recording, control)
    assert [(c.effect, c.named_in) for c in listed] == [("anchor_delay", "both"), ("lever_arm", "both"),
                                                        ("imu_gyro_bias", "recording"), ("time_offset", "control")]
    ordered = by_size([c.to_json() for c in listed])
    assert [c["effect"] for c in ordered] == ["imu_gyro_bias", "time_offset", "lever_arm", "anchor_delay"]
    assert ordered[2]["change_std_errs"] == pytest.approx(5.0) and ordered[3]["anchors"] == [1]


def test_each_change_is_assessed_against_what_the_recording_tells_apart() -> None:
    """A delay's change against its own column (no look-alike): told apart from
    √(2 bar / |column|²); a displacement whose look-alike, the delay, fits it whole:
    at no size, so any change of it is below; NLOS: not assessed."""
    rng = np.random.default_rng(4)
    delay, bar = rng.normal(size=(400, 1)), 10.0
    items = [assess("anchor_delay", [1], "meters", delay, {}, bar, 1.5),
             assess("anchor_position", [1], "offset_m", delay @ np.array([[0.5, 0.0, 0.0]]),
                    {"anchor_delay": delay}, bar, 1.0)]
    nlos = {"anchor": 1, "fraction": 0.5, "mean_excess_m": 0.3, "region": {"min": [0, 0, 0], "max": [1, 1, 1]}}
    recording = [_finding("anchor_delay", {"anchor": 1, "meters": 0.3}, anchors=[1]),
                 _finding("anchor_position", {"anchor": 1, "offset_m": [0.2, 0.0, 0.0]}, anchors=[1]),
                 _finding("nlos", nlos, anchors=[1])]
    control = [_finding("anchor_delay", {"anchor": 1, "meters": 0.1}, anchors=[1])]
    listed = {c.effect: c.to_json() for c in changes(recording, control, items)}
    grown = listed["anchor_delay"]
    assert grown["size"] == pytest.approx(0.2)
    assert grown["told_apart_from"] == pytest.approx(np.sqrt(2 * bar / float(np.sum(delay ** 2))), rel=1e-3)
    assert listed["anchor_position"]["size"] == pytest.approx(0.2)
    assert listed["anchor_position"]["told_apart_from"] is None          # JSON null: at no size
    assert "size" not in listed["nlos"] and "told_apart_from" not in listed["nlos"]
    assert all("size" not in c.to_json() for c in changes(recording, control))       # without identifiability


def test_a_delays_change_carries_the_lever_arms_share() -> None:
    """A lever arm changed by [0.05, −0.02, 0] m moves anchor 1's delay by its cross
    talk times that; a delay on an anchor without cross talk, or with no lever arm
    named on either recording, gets no share."""
    cross_talk = {1: [0.8, 0.5, 0.1]}
    recording = [_finding("anchor_delay", {"anchor": 1, "meters": 0.2}, anchors=[1]),
                 _finding("anchor_delay", {"anchor": 4, "meters": 0.1}, anchors=[4]),
                 _finding("lever_arm", {"offset_m": [0.07, -0.02, 0.0]})]
    control = [_finding("anchor_delay", {"anchor": 1, "meters": 0.1}, anchors=[1]),
               _finding("lever_arm", {"offset_m": [0.02, 0.0, 0.0]})]
    listed = {tuple(c.anchors): c.to_json() for c in changes(recording, control, (), cross_talk)}
    assert listed[(1,)]["lever_arm_share_m"] == pytest.approx(0.8 * 0.05 - 0.5 * 0.02)
    assert "lever_arm_share_m" not in listed[(4,)]
    assert change_text(listed[(1,)]) == "meters 0.1 (the lever arm's share 0.03)"      # report.md, the CLI
    assert "lever_arm_share_m" not in listed[()]                          # the lever arm itself
    gone = {tuple(c.anchors): c for c in changes(recording[:2], control, (), cross_talk)}
    assert gone[(1,)].lever_arm_share == pytest.approx(-0.8 * 0.02)       # named on the control only: back to none
    neither = {tuple(c.anchors): c for c in changes(recording[:2], control[:1], (), cross_talk)}
    assert neither[(1,)].lever_arm_share is None


def test_a_control_of_another_flight_is_told_apart_from_one_of_the_same() -> None:
    """A control must be the same flight (an injected copy keeps its ground truth and
    anchors): another trajectory, survey or span is named, not compared silently."""
    rec = read_recording(default_recording())
    assert flight_difference(rec, rec) is None
    truth = rec.truth
    elsewhere = replace(rec, truth=replace(truth, position=truth.position + [0.3, 0.0, 0.0]))
    assert "ground truth 0.30 m from the recording's" in flight_difference(rec, elsewhere)
    shorter = replace(rec, truth=truth.select(truth.t <= np.median(truth.t)))
    assert "ground truth over 50" in flight_difference(rec, shorter)
    moved = [replace(a, position=(a.position[0] + 0.2, *a.position[1:])) if a.id == 3 else a for a in rec.anchors]
    assert "anchors surveyed up to 0.20 m" in flight_difference(rec, replace(rec, anchors=moved))
    fewer = replace(rec, anchors=[a for a in rec.anchors if a.id != 3])
    assert "anchors [0, 1, 2, 4, 5, 6, 7] against the recording's [0, 1, 2, 3, 4, 5, 6, 7]" \
        in flight_difference(rec, fewer)
