"""The simulator: deterministic, physically consistent, effects composable."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import FULL_PRECISION, ROOT, run_rig, simulate_exact, tdoa_poses
from scipy.spatial.transform import Rotation

from rig.bias.dataset import measurement_features
from rig.data.importer import load_any
from rig.data.recording import Recording, Vec3Series, read_recording, write_recording
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet
from rig.sim.effects import ImuBatch, LearnedBias, TdoaBatch, World, make_effect, vibration_level
from rig.sim.simulate import Predictor, SimConfig, inject, simulate
from rig.sim.trajectory import GRAVITY, RecordedTrajectory, parametric, windowed_mean_quaternion


def _strapdown(rec: Recording) -> np.ndarray:
    """Integrate the IMU from the true initial state (midpoint rule). Returns positions at IMU times."""
    t, f, w = rec.accel.t, rec.accel.xyz, rec.gyro.xyz
    rot = Rotation.from_quat(rec.truth.quaternion[0])
    p = rec.truth.position[0].copy()
    v = np.zeros(3)
    g = np.array([0.0, 0.0, -GRAVITY])
    out = np.empty((len(t), 3))
    out[0] = p
    for k in range(len(t) - 1):
        dt = t[k + 1] - t[k]
        half = rot * Rotation.from_rotvec(0.5 * (w[k] + w[k + 1]) * dt / 2)
        a = half.apply(0.5 * (f[k] + f[k + 1])) + g
        rot = rot * Rotation.from_rotvec(0.5 * (w[k] + w[k + 1]) * dt)
        p = p + v * dt + 0.5 * a * dt**2
        v = v + a * dt
        out[k + 1] = p
    return out


@pytest.mark.slow
@pytest.mark.parametrize("trajectory", ["circle", "circle-sine", "smooth-random"])
def test_integrating_noiseless_imu_reproduces_the_trajectory(survey_0425: Path, trajectory: str) -> None:
    rec = simulate_exact(survey_0425, trajectory, duration=15.0)
    dead_reckoned = _strapdown(rec)
    truth = np.column_stack([np.interp(rec.accel.t, rec.truth.t, rec.truth.position[:, i]) for i in range(3)])
    drift = np.linalg.norm(dead_reckoned - truth, axis=1)
    assert drift.max() < 0.02, f"dead reckoning drifted {drift.max():.4f} m over {rec.accel.t[-1]:.0f} s"


def test_specific_force_at_rest_is_plus_g_on_z(survey_0425: Path) -> None:
    rec = simulate_exact(survey_0425, "circle", duration=5.0)
    on_ground = rec.accel.t < 1.5
    np.testing.assert_allclose(rec.accel.xyz[on_ground], [[0.0, 0.0, GRAVITY]] * on_ground.sum(), atol=1e-6)
    np.testing.assert_allclose(rec.gyro.xyz[on_ground], 0.0, atol=1e-9)


@pytest.mark.parametrize("mode", ["TDOA2", "TDOA3"])
def test_noiseless_tdoa_equals_the_geometry_exactly(survey_0425: Path, mode: str) -> None:
    rec = simulate_exact(survey_0425, "circle-sine", duration=5.0, uwb_mode=mode)
    anchors = rec.anchor_map()
    # The truth is sampled at other times, so evaluate the trajectory itself at the TDOA times.
    from rig.sim.trajectory import parametric
    p = parametric("circle-sine", duration=5.0).position(rec.tdoa.t)
    a = np.array([anchors[k].position for k in rec.tdoa.id_a])
    b = np.array([anchors[k].position for k in rec.tdoa.id_b])
    expected = np.linalg.norm(p - b, axis=1) - np.linalg.norm(p - a, axis=1)
    np.testing.assert_array_equal(rec.tdoa.distance_diff, expected)
    assert np.all(rec.tdoa.id_a != rec.tdoa.id_b)
    consecutive = np.mean((rec.tdoa.id_a + 1) % 8 == rec.tdoa.id_b)
    assert consecutive == 1.0 if mode == "TDOA2" else consecutive < 0.3
    if mode == "TDOA3":
        pairs = set(zip(rec.tdoa.id_a.tolist(), rec.tdoa.id_b.tolist()))
        assert len(pairs) > 40  # both orders of most of the 28 pairs


def test_noise_biases_and_outliers_have_their_configured_size(survey_0425: Path) -> None:
    cfg = SimConfig(trajectory="circle", duration=60.0, survey=str(survey_0425), tdoa_hz=400.0,
                    resolution=dict(FULL_PRECISION), effects=[
                        {"effect": "imu_noise", "params": {"accel_std": 0.1, "gyro_std": 0.01}},
                        {"effect": "imu_accel_bias", "params": {"bias_mps2": [0.2, -0.1, 0.3]}},
                        {"effect": "imu_gyro_bias", "params": {"bias_rps": [0.01, 0.02, -0.03]}},
                        {"effect": "tdoa_noise", "params": {"std_m": 0.1}},
                        {"effect": "outliers", "params": {"fraction": 0.07, "mean_excess_m": 2.0}},
                    ])
    noisy = simulate(cfg)
    clean = simulate(SimConfig(**{**cfg.__dict__, "effects": []}))
    accel_err = noisy.accel.xyz - clean.accel.xyz
    gyro_err = noisy.gyro.xyz - clean.gyro.xyz
    np.testing.assert_allclose(accel_err.mean(axis=0), [0.2, -0.1, 0.3], atol=0.005)
    np.testing.assert_allclose(accel_err.std(axis=0), 0.1, rtol=0.03)
    np.testing.assert_allclose(gyro_err.mean(axis=0), [0.01, 0.02, -0.03], atol=0.0005)
    tdoa_err = noisy.tdoa.distance_diff - clean.tdoa.distance_diff
    outlier = np.abs(tdoa_err) > 0.5  # outliers add at least 1 m, noise is 0.1 m
    assert outlier.mean() == pytest.approx(0.07, abs=0.01)
    assert np.std(tdoa_err[~outlier]) == pytest.approx(0.1, rel=0.05)


def test_the_vibration_level_is_the_shaking_not_the_motion() -> None:
    """A slow manoeuvre of 2 m/s² barely reads as vibration; white noise of 0.5 m/s²
    at 1 kHz reads as its RMS (less the share the 20 ms running mean takes)."""
    t = np.arange(0.0, 20.0, 0.001)
    motion = 2.0 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.ones(3)
    shaking = np.random.default_rng(0).normal(0.0, 0.5, (len(t), 3))
    assert vibration_level(t, motion).max() < 0.02          # 1 % of the manoeuvre (at the ends)
    level = vibration_level(t, motion + shaking)
    np.testing.assert_allclose(np.median(level, axis=0), 0.5 * np.sqrt(1 - 1 / 20), rtol=0.03)


def test_a_rectified_vibration_is_a_bias_that_follows_the_shaking() -> None:
    """Motors off for 5 s, then shaking of 1 m/s² RMS: the rectification's offset is
    gain × that RMS in flight and none on the ground; with the recording's own
    vibration given (as the diagnosis predicts a recording) it acts on that."""
    t = np.arange(0.0, 10.0, 0.001)
    flying = t >= 5.0
    shaking = np.random.default_rng(1).normal(0.0, 1.0, (len(t), 3)) * flying[:, None]
    imu = ImuBatch(t, shaking.copy(), np.zeros((len(t), 3)))
    make_effect("imu_vibration_rectification", {"gain": [-2.0, 0.0, 0.5]}).apply_imu(imu, None)
    offset = imu.accel - shaking
    steady = flying & (t > 5.3)
    np.testing.assert_allclose(offset[steady].mean(axis=0), [-2.0 * 0.975, 0.0, 0.5 * 0.975], rtol=0.03, atol=1e-9)
    assert np.all(offset[t < 4.7] == 0.0)
    given = ImuBatch(t, np.zeros((len(t), 3)), np.zeros((len(t), 3)), vibration=np.full((len(t), 3), 0.3))
    make_effect("imu_vibration_rectification", {"gain": [-2.0, 0.0, 0.5]}).apply_imu(given, None)
    np.testing.assert_allclose(given.accel, np.tile([-0.6, 0.0, 0.15], (len(t), 1)))


def test_the_rotors_shake_the_flight_and_not_the_ground(survey_0425: Path) -> None:
    """The rotors' vibration is noise of its configured size at hover while the motors
    run (growing with the rotors' speed) and none on the ground before take-off and
    after touch-down; a rectification on it comes and goes with the motors."""
    vibration = {"effect": "imu_vibration", "params": {"accel_std": [1.0, 0.5, 0.0], "gyro_std": [0.0, 0.0, 0.2]}}
    rectification = {"effect": "imu_vibration_rectification", "params": {"gain": [-1.0, 0.0, 0.0]}}
    cfg = SimConfig(trajectory="circle", survey=str(survey_0425), duration=30.0, seed=2,
                    effects=[vibration, rectification], resolution=FULL_PRECISION)
    rec, trajectory = simulate(cfg), parametric(cfg.trajectory, duration=cfg.duration, seed=cfg.seed)
    shaking = rec.accel.xyz - trajectory.specific_force(rec.accel.t)
    spin = rec.gyro.xyz - trajectory.angular_rate(rec.gyro.t)
    rotor, t, plan = trajectory.rotor_speed(rec.accel.t), rec.accel.t, trajectory.plan
    on = rotor > 0
    assert not on[t < plan.ground_before].any() and not on[t > trajectory.t_end - plan.ground_after].any()
    still = (t < plan.ground_before - 0.2) | (t > trajectory.t_end - plan.ground_after + 0.2)   # past the RMS window
    assert np.all(shaking[still] == 0.0) and np.all(spin[~on] == 0.0)
    hover = on & (np.abs(rotor - 1.0) < 0.01)
    np.testing.assert_allclose(np.std(shaking[hover] / rotor[hover, None], axis=0), [1.0, 0.5, 0.0], rtol=0.03,
                               atol=1e-12)
    np.testing.assert_allclose(np.std(spin[hover], axis=0), [0.0, 0.0, 0.2], rtol=0.03, atol=1e-12)
    steady = on & (rec.accel.t > plan.ground_before + 0.5) & (rec.accel.t < trajectory.t_end - plan.ground_after - 0.5)
    assert abs(np.mean(shaking[steady, 0]) + 0.975) < 0.05           # −gain × the level of 1 m/s² shaking


def test_a_rectification_behind_the_low_pass_feeds_on_the_vibration_the_log_shows(survey_0425: Path) -> None:
    """A rectification's gain is measured against a log's vibration (the diagnosis
    sees the readings after the flight controller's low-pass), so a simulation with
    the low-pass offsets the readings by gain × the vibration of its own log, not of
    the shaking before the filter (about 8 times larger at 30 Hz)."""
    shaking = [{"effect": "imu_vibration", "params": {"accel_std": [2.0, 0.0, 0.0]}},
               {"effect": "imu_lowpass", "params": {"accel_hz": 30.0, "gyro_hz": 80.0}}]
    rectification = {"effect": "imu_vibration_rectification", "params": {"gain": [-1.0, 0.0, 0.0]}}
    cfg = SimConfig(trajectory="circle", survey=str(survey_0425), duration=30.0, seed=2, effects=shaking,
                    resolution=FULL_PRECISION)
    logged, rectified = simulate(cfg), simulate(replace(cfg, effects=[*shaking, rectification]))
    t, plan = logged.accel.t, parametric(cfg.trajectory, duration=cfg.duration, seed=cfg.seed).plan
    steady = (t > plan.ground_before + 1.0) & (t < t[-1] - plan.ground_after - 1.0)
    offset = np.mean(rectified.accel.xyz[steady, 0] - logged.accel.xyz[steady, 0])
    level = np.mean(vibration_level(t, logged.accel.xyz)[steady, 0])
    assert 0.1 < level < 0.5                      # the filter kept a fraction of the 2 m/s² shaking
    assert offset == pytest.approx(-level, rel=0.05)


def test_a_recorded_flights_motors_run_from_take_off_to_touch_down(data_dir: Path) -> None:
    """A real flight sits on the floor at its start and end: the motors are off there
    and the rotors turn at about hover speed in between; an injected vibration shakes
    the recording in flight only."""
    rec = load_any(data_dir / "flights" / "0426-traj1")
    predictor = Predictor(rec)
    on, t = predictor.accel_rotor > 0, rec.accel.t
    assert not on[t < t[0] + 0.5].any() and not on[t > t[-1] - 0.5].any()
    assert 0.8 < on.mean() < 0.99
    assert abs(np.median(predictor.accel_rotor[on]) - 1.0) < 0.05
    shaken = inject(rec, [{"effect": "imu_vibration", "params": {"accel_std": [0.5, 0.5, 0.5]}}], seed=1)
    added = shaken.accel.xyz - rec.accel.xyz
    assert np.all(added[~on] == 0.0)
    np.testing.assert_allclose(np.std(added[on], axis=0), 0.5, rtol=0.05)


def test_a_delay_changed_in_a_window_keeps_its_own_value_outside(survey_0425: Path) -> None:
    changed = {"effect": "anchor_delay", "params": {"anchor": 3, "meters": 0.25, "during": [4.0, 7.0],
                                                    "outside_m": -0.1}}
    cfg = SimConfig(trajectory="circle", duration=10.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[changed])
    delayed, clean = simulate(cfg), simulate(replace(cfg, effects=[]))
    t, tdoa = delayed.tdoa.t, delayed.tdoa
    sign = (tdoa.id_b == 3).astype(float) - (tdoa.id_a == 3)
    inside = (t >= 4.0) & (t < 7.0)
    added = tdoa.distance_diff - clean.tdoa.distance_diff
    np.testing.assert_allclose(added[inside], 0.25 * sign[inside], atol=1e-4)
    np.testing.assert_allclose(added[~inside], -0.1 * sign[~inside], atol=1e-4)
    assert sign[inside].any() and sign[~inside].any()
    with pytest.raises(ValueError, match="outside_m needs a window"):
        make_effect("anchor_delay", {"anchor": 3, "meters": 0.25, "outside_m": -0.1})


def test_ranges_read_longer_per_anchor_only_while_the_drone_sits_on_the_floor(survey_0425: Path) -> None:
    """The drone's body, not its antenna: with the antenna 0.3 m below the body, the
    ranges read as on the floor only while the body is below the height."""
    on_ground = {"effect": "on_ground_delay", "params": {"height_m": 0.1, "meters": {"0": 1.5, "3": -1.2}}}
    hanging = {"effect": "lever_arm", "params": {"offset_m": [0.0, 0.0, -0.3]}}
    cfg = SimConfig(trajectory="circle", duration=10.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[hanging, on_ground])
    floored, clean = simulate(cfg), simulate(replace(cfg, effects=[hanging]))
    tdoa = floored.tdoa
    height = np.interp(tdoa.t, floored.truth.t, floored.truth.position[:, 2])
    low = height < 0.1
    expected = sum(m * ((tdoa.id_b == k).astype(float) - (tdoa.id_a == k)) for k, m in ((0, 1.5), (3, -1.2)))
    added = tdoa.distance_diff - clean.tdoa.distance_diff
    np.testing.assert_allclose(added[low], expected[low], atol=1e-4)
    np.testing.assert_allclose(added[~low], 0.0, atol=1e-4)
    assert (np.abs(expected[low]) > 1.0).sum() > 100 and (~low).sum() > low.sum()
    for bad in ({"-1": 0.5}, {"a": 0.5}, [0.5]):
        with pytest.raises(ValueError, match="meters must map anchor ids to metres"):
            make_effect("on_ground_delay", {"meters": bad})


def test_the_floors_error_fades_out_linearly_over_its_fade(survey_0425: Path) -> None:
    """All of it below the height, none above height + fade, in between linearly: a
    tag half way up the fade reads half of it."""
    on_ground = {"effect": "on_ground_delay", "params": {"height_m": 0.05, "fade_m": 0.1, "meters": {"0": 1.0}}}
    cfg = SimConfig(trajectory="circle", duration=10.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[on_ground])
    floored, clean = simulate(cfg), simulate(replace(cfg, effects=[]))
    tdoa = floored.tdoa
    height = np.interp(tdoa.t, floored.truth.t, floored.truth.position[:, 2])
    sign = (tdoa.id_b == 0).astype(float) - (tdoa.id_a == 0)
    share = np.clip((0.15 - height) / 0.1, 0.0, 1.0)
    added = tdoa.distance_diff - clean.tdoa.distance_diff
    np.testing.assert_allclose(added, share * sign, atol=1e-3)
    fading = (share > 0.1) & (share < 0.9) & (sign != 0)
    assert fading.sum() >= 5, "the take-off and landing pass through the fade"
    with pytest.raises(ValueError, match="fade_m must be a width >= 0"):
        make_effect("on_ground_delay", {"fade_m": -0.1})


def test_the_airframes_lean_reads_as_more_drag_and_turns_the_gyroscope_as_far(survey_0425: Path) -> None:
    """A lean of c rad per m/s into the motion: each horizontal accelerometer axis reads
    g·c·v more drag along it, and the gyroscope's extra rate, integrated, is the lean
    itself (about body y for x, about −x for y)."""
    lean = np.array([0.01, 0.02])
    cfg = SimConfig(trajectory="circle", duration=20.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[{"effect": "attitude_lean", "params": {"rad_per_mps": lean.tolist()}}])
    leaning, upright = simulate(cfg), simulate(replace(cfg, effects=[]))
    t = leaning.accel.t
    velocity = RecordedTrajectory(upright.truth).body_velocity(t)
    moving = np.linalg.norm(velocity, axis=1) > 0.3
    extra = leaning.accel.xyz - upright.accel.xyz
    for axis in (0, 1):
        slope = np.polyfit(velocity[moving, axis], extra[moving, axis], 1)[0]
        assert slope == pytest.approx(-GRAVITY * lean[axis], rel=0.02)
    turned = np.cumsum(leaning.gyro.xyz - upright.gyro.xyz, axis=0) * np.gradient(t)[:, None]
    assert np.polyfit(velocity[moving, 0], turned[moving, 1], 1)[0] == pytest.approx(lean[0], rel=0.05)
    assert np.polyfit(velocity[moving, 1], turned[moving, 0], 1)[0] == pytest.approx(-lean[1], rel=0.05)


def test_a_lean_needs_the_velocity_of_the_imus_samples() -> None:
    batch = ImuBatch(np.arange(3.0), np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="body velocity"):
        make_effect("attitude_lean", {"rad_per_mps": [0.01, 0.0]}).apply_imu(batch, None)
    with pytest.raises(ValueError, match="two finite numbers"):
        make_effect("attitude_lean", {"rad_per_mps": [0.01, 0.0, 0.0]})


def test_the_tags_antenna_pattern_biases_each_range_by_its_anchors_direction_in_the_body_frame(
        survey_0425: Path) -> None:
    """Each range reads c · [u_z² − 1/3, u_x² − u_y², 2 u_x u_y], u the unit vector
    from the tag to its anchor in the body frame (the basis in Cartesian form, another
    path to it than the angles): TDOA sees range B's minus range A's. The level
    circle's yaw turns with it, so the directions sweep the body frame."""
    coeffs = np.array([0.3, -0.2, 0.25])
    cfg = SimConfig(trajectory="circle", duration=10.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[{"effect": "tag_antenna_pattern", "params": {"coeffs_m": coeffs.tolist()}}])
    patterned, clean = simulate(cfg), simulate(replace(cfg, effects=[]))
    tdoa = patterned.tdoa
    inside, t, body, position = tdoa_poses(patterned)
    anchors = {a.id: np.array(a.position) for a in patterned.anchors}

    def range_bias(ids: np.ndarray) -> np.ndarray:
        u = body.inv().apply(np.array([anchors[int(k)] for k in ids]) - position)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return np.stack([u[:, 2] ** 2 - 1 / 3, u[:, 0] ** 2 - u[:, 1] ** 2, 2 * u[:, 0] * u[:, 1]], axis=1) @ coeffs

    expected = range_bias(tdoa.id_b[inside]) - range_bias(tdoa.id_a[inside])
    added = (tdoa.distance_diff - clean.tdoa.distance_diff)[inside]
    np.testing.assert_allclose(added, expected, atol=2e-3)
    assert np.std(expected) > 0.1
    unknown = TdoaBatch(t[:2], np.array([0, 99]), np.array([1, 0]), position[:2], body[:2], np.zeros(2))
    make_effect("tag_antenna_pattern", {"coeffs_m": coeffs.tolist()}).apply_tdoa(
        unknown, World.surveyed(patterned.anchors), None)
    assert unknown.value[0] != 0.0 and unknown.value[1] == 0.0     # an anchor the survey lacks: left alone
    with pytest.raises(ValueError, match="coeffs_m must be three finite numbers"):
        make_effect("tag_antenna_pattern", {"coeffs_m": [0.1, float("nan"), 0.0]})


# every number a catalog or noise effect takes alone (the vectors refuse NaN in _vec3)
SCALAR_PARAMS = [("time_offset", "seconds"), ("clock_drift", "ppm"), ("anchor_delay", "meters"),
                 ("anchor_delay", "outside_m"), ("nlos", "fraction"), ("nlos", "mean_excess_m"),
                 ("multipath_floor", "height_m"), ("multipath_floor", "std_m"), ("tdoa_noise", "std_m"),
                 ("outliers", "fraction"), ("outliers", "mean_excess_m"), ("on_ground_delay", "height_m"),
                 ("on_ground_delay", "fade_m"), ("learned_bias", "gain"), ("imu_noise", "accel_std"),
                 ("imu_lowpass", "gyro_hz"), ("imu_resonance", "accel_q")]


@pytest.mark.parametrize("effect,param", SCALAR_PARAMS)
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "fast"])
def test_a_parameter_that_is_not_a_finite_number_is_refused_by_name(effect: str, param: str, bad) -> None:
    """NaN passes every range check (each comparison is false), and would reach the
    data as NaN or fail far from its cause."""
    with pytest.raises(ValueError, match=f"bad parameters for effect '{effect}': {param} must be"):
        make_effect(effect, {param: bad})


def test_an_effect_beyond_its_physical_bound_is_injected_with_a_warning_naming_it(tmp_path: Path) -> None:
    """The catalog's bounds are the diagnosis's (a fit beyond one is not explained): a
    configuration beyond one is what no real flight carries, so the rig says so, and
    still does what it was asked (a test may want an absurd effect)."""
    from rig.diagnosis.candidates import Candidate
    from rig.sim import effects as fx

    assert make_effect("time_offset", {"seconds": 0.4}).beyond_bound() == []
    assert make_effect("imu_gyro_scale", {"scale": [1.1, 0.9, 1.0]}).beyond_bound() == []     # |scale − 1|
    assert make_effect("imu_gyro_scale", {"scale": [1.2, 1.0, 1.0]}).beyond_bound() == \
        ["scale [1.2, 1.0, 1.0] (bound 0.15)"]
    assert make_effect("link_bias", {"coeffs_m": [0.1] * len(fx.LINK_TERMS), "gain": -1.0}).beyond_bound() == \
        ["gain -1 (bound: not negative)"]
    assert Candidate("anchor_delay", "tdoa", "meters", 1).bound == fx.AnchorDelay.bounds["meters"] == 1.5
    # a displacement is bounded by its length: 0.8 m along two axes moves an anchor 1.13 m
    assert make_effect("anchor_position", {"anchor": 3, "offset_m": [0.9, 0.0, 0.3]}).beyond_bound() == []
    assert make_effect("anchor_position", {"anchor": 3, "offset_m": [0.8, -0.8, 0.0]}).beyond_bound() == \
        ["offset_m [0.8, -0.8, 0.0] (bound 1)"]
    assert make_effect("lever_arm", {"offset_m": [0.1, 0.1, 0.1]}).beyond_bound() != []          # 0.17 m
    assert fx.size_of("anchor_position", "offset_m", [0.6, 0.0, -0.8]) == pytest.approx(1.0)
    assert fx.size_of("imu_accel_bias", "bias_mps2", [3.0, -4.0, 0.0]) == 4.0                  # per axis
    # a pattern is bounded by how much its ranges differ between directions, not by its coefficients
    assert make_effect("antenna_pattern", {"anchor": 2, "coeffs_m": [0.0, 0.4, -0.3]}).beyond_bound() == []  # 1.0 m
    assert make_effect("antenna_pattern", {"anchor": 2, "coeffs_m": [0.0, 0.6, 0.0]}).beyond_bound() == \
        ["coeffs_m [0.0, 0.6, 0.0] (bound 1)"]                                                                # 1.2 m
    assert make_effect("antenna_pattern", {"anchor": 6, "coeffs_m": [-0.9, 0.0, -0.2]}).beyond_bound() == \
        ["coeffs_m [-0.9, 0.0, -0.2] (bound 1)"]                                                              # 1.1 m
    proc = run_rig("inject", "recordings/default.mcap", "--effects",
                   '[{"effect": "time_offset", "params": {"seconds": 1e9}}]', "-o", str(tmp_path / "far.mcap"))
    assert proc.returncode == 0, proc.stderr
    assert "time_offset: seconds 1000000000.0 (bound 0.5) is beyond what a real flight can carry" in proc.stderr


def test_an_effect_on_an_anchor_the_flight_lacks_is_refused(survey_0425: Path) -> None:
    """It would change nothing: a concealed-effect check would then judge a flight that
    carries nothing injected."""
    delay = {"effect": "anchor_delay", "params": {"anchor": 9, "meters": 0.1}}
    cfg = SimConfig(duration=3.0, survey=str(survey_0425))
    with pytest.raises(ValueError, match=r"anchor_delay: anchor 9 is not one of the flight's anchors \[0, 1, 2"):
        simulate(replace(cfg, effects=[delay]))
    with pytest.raises(ValueError, match="anchor 9 is not one of the flight's anchors"):
        inject(simulate(cfg), [delay])
    inject(simulate(cfg), [{"effect": "anchor_delay", "params": {"anchor": 7, "meters": 0.1}}])


def test_same_seed_same_bytes_other_seed_other_data(tmp_path: Path, survey_0425: Path) -> None:
    cfg = SimConfig(duration=5.0, survey=str(survey_0425), seed=7)
    write_recording(simulate(cfg), tmp_path / "a.mcap")
    write_recording(simulate(cfg), tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    cfg.seed = 8
    other = simulate(cfg)
    assert not np.array_equal(other.accel.xyz, read_recording(tmp_path / "a.mcap").accel.xyz)


def test_another_trajectory_than_the_configs_leaves_its_parameters_and_a_wrong_one_is_a_clear_error(
        tmp_path: Path) -> None:
    proc = run_rig("simulate", "--config", "recordings/default.sim.json", "--trajectory", "smooth-random",
                   "--duration", "2", "-o", str(tmp_path / "random.mcap"))
    assert proc.returncode == 0, proc.stderr
    assert "trajectory_params (for circle-sine) are not used" in proc.stdout
    assert read_recording(tmp_path / "random.mcap").metadata["source"] == "rig simulate"
    config = json.loads((ROOT / "recordings" / "default.sim.json").read_text())
    config["trajectory_params"]["wobble"] = 1.0
    config["survey"] = str(ROOT / config["survey"])
    (tmp_path / "bad.json").write_text(json.dumps(config))
    proc = run_rig("simulate", "--config", str(tmp_path / "bad.json"), "-o", str(tmp_path / "bad.mcap"))
    assert proc.returncode == 2 and "trajectory 'circle-sine'" in proc.stderr and "wobble" in proc.stderr
    assert "internal error" not in proc.stderr and not (tmp_path / "bad.mcap").exists()


@pytest.mark.slow
def test_shipped_default_recording_regenerates_byte_identically_from_any_directory(tmp_path: Path) -> None:
    """Its config names its survey and room network from the project root: they are
    found from another working directory too."""
    out = tmp_path / "default.mcap"
    run_rig("simulate", "--config", str(ROOT / "recordings" / "default.sim.json"), "-o", str(out), check=True,
            cwd=tmp_path)
    assert out.read_bytes() == (ROOT / "recordings" / "default.mcap").read_bytes()


@pytest.mark.parametrize("setting", [{"duration": -5}, {"duration": 0}, {"imu_hz": float("nan")}, {"tdoa_hz": "fast"}])
def test_a_simulation_setting_that_is_not_a_number_above_zero_is_refused(setting: dict) -> None:
    with pytest.raises(ValueError, match=f"{next(iter(setting))} must be a finite number above zero"):
        SimConfig(**setting)


@pytest.mark.slow
def test_simulating_a_recordings_own_trajectory(tmp_path: Path, data_dir: Path) -> None:
    from rig.data.importer import import_log

    real = import_log(data_dir / "flights" / "0425-traj1", data_dir / "surveys" / "anchor_0425.txt")
    write_recording(real, tmp_path / "real.mcap")
    sim = simulate(SimConfig(trajectory="recording", recording=str(tmp_path / "real.mcap"), effects=[]))
    assert sim.anchors == real.anchors
    # The thrust axis must agree with the real accelerometer (averaged over 50 ms against
    # propeller vibration). The real x/y axes do not: in flight they read drag and
    # vibration rectification, which is for the diagnosis to find, not for this test.
    t = sim.accel.t
    kernel = np.ones(50) / 50
    real_z = np.convolve(np.interp(t, real.accel.t, real.accel.xyz[:, 2]), kernel, "same")
    flying = np.interp(t, real.truth.t, real.truth.position[:, 2]) > 0.5
    assert np.median(np.abs(sim.accel.xyz[flying, 2] - real_z[flying])) < 0.5
    assert np.corrcoef(sim.accel.xyz[flying, 2], real_z[flying])[0, 1] > 0.3


def test_imu_effects_predict_a_recording_whose_gyroscope_has_its_own_clock(data_dir: Path) -> None:
    """Each IMU stream is predicted on its own samples: a gyroscope logged at half the
    accelerometer's rate takes windowed and vibration effects of either stream."""
    rec = load_any(data_dir / "flights" / "0426-traj1")
    rec = replace(rec, gyro=Vec3Series(rec.gyro.t[::2].copy(), rec.gyro.xyz[::2].copy()))
    predictor = Predictor(rec)
    effects = [make_effect("imu_vibration_rectification", {"gain": [1.0, 0.0, 0.0]}),
               make_effect("imu_accel_bias", {"bias_mps2": [1.0, 0.0, 0.0], "during": [30.0, 40.0]}),
               make_effect("imu_gyro_bias", {"bias_rps": [1.0, 0.0, 0.0], "during": [30.0, 40.0]})]
    accel, gyro = predictor.imu(effects)
    assert accel.shape == rec.accel.xyz.shape and gyro.shape == rec.gyro.xyz.shape
    in_window = (rec.gyro.t >= 30.0) & (rec.gyro.t < 40.0)
    np.testing.assert_allclose(gyro[in_window, 0] - predictor.gyro_true[in_window, 0], 1.0)
    np.testing.assert_allclose(accel[:, 0] - predictor.accel_true[:, 0],
                               predictor.accel_vibration[:, 0]
                               + ((rec.accel.t >= 30.0) & (rec.accel.t < 40.0)), atol=1e-12)


def test_a_lean_injected_into_a_real_flight_reads_on_both_sensors_along_its_velocity(data_dir: Path) -> None:
    """`rig inject` acts on the recorded readings along the flight's ground truth: the
    accelerometer reads g·c·v more drag, the gyroscope turns by the lean."""
    rec = load_any(data_dir / "flights" / "0426-traj1")
    leaning = inject(rec, [{"effect": "attitude_lean", "params": {"rad_per_mps": [0.01, 0.0]}}])
    velocity = RecordedTrajectory(rec.truth).body_velocity(rec.accel.t)
    extra = leaning.accel.xyz - rec.accel.xyz
    assert np.polyfit(velocity[:, 0], extra[:, 0], 1)[0] == pytest.approx(-GRAVITY * 0.01, rel=0.02)
    assert np.abs(extra[:, 1]).max() < 1e-3
    turned = np.cumsum((leaning.gyro.xyz - rec.gyro.xyz)[:, 1] * np.gradient(rec.gyro.t))
    assert np.polyfit(RecordedTrajectory(rec.truth).body_velocity(rec.gyro.t)[:, 0], turned, 1)[0] \
        == pytest.approx(0.01, rel=0.05)


def test_windowed_mean_attitude_averages_out_pose_noise_across_sign_flips() -> None:
    """Motion-capture attitude noise averaged over a window drops by √(poses); a pose
    reported as −q (the same rotation) must not cancel its neighbours."""
    t = np.arange(0.0, 10.0, 1 / 300)
    def yaw(times: np.ndarray) -> Rotation:
        return Rotation.from_euler("z", 0.2 * np.sin(times)[:, None])

    true = yaw(t)
    rng = np.random.default_rng(1)
    noisy = (Rotation.from_rotvec(rng.normal(0.0, 0.006, (len(t), 3))) * true).as_quat()
    noisy[::7] *= -1.0
    at = np.arange(1.0, 9.0, 0.02)
    mean = Rotation.from_quat(windowed_mean_quaternion(t, noisy, at, 0.2))
    nearest = np.searchsorted(t, at)
    error = np.linalg.norm((mean * yaw(at).inv()).as_rotvec(), axis=1)
    single = np.linalg.norm((Rotation.from_quat(noisy[nearest]) * yaw(t[nearest]).inv()).as_rotvec(), axis=1)
    assert np.sqrt(np.mean(error ** 2)) < np.sqrt(np.mean(single ** 2)) / 5     # √60 ≈ 7.7 fewer


def test_a_recorded_trajectory_flies_through_lost_motion_capture_poses(data_dir: Path) -> None:
    """A pose with NaN (an occluded motion-capture frame) is left out, not fatal, and
    the flight elsewhere is unchanged."""
    truth = load_any(data_dir / "flights" / "0426-traj1").truth
    position, quaternion = truth.position.copy(), truth.quaternion.copy()
    position[5000], quaternion[6000] = np.nan, np.nan
    clean, holed = RecordedTrajectory(truth), RecordedTrajectory(replace(truth, position=position,
                                                                         quaternion=quaternion))
    t = np.linspace(clean.t_start + 1.0, clean.t_end - 1.0, 500)
    assert np.abs(holed.position(t) - clean.position(t)).max() < 0.01
    assert np.linalg.norm((holed.rotation(t) * clean.rotation(t).inv()).as_rotvec(), axis=1).max() < 0.01


def test_the_learned_bias_is_the_networks_prediction_at_the_true_pose(data_dir: Path) -> None:
    """`learned_bias` is the shipped bias network fed, through the C feature function,
    the features of the tag's true pose: the same as the training data's features
    taken from the ground truth (rig/bias_dataset.py, another path to them), times
    its gain."""
    rec = load_any(data_dir / "flights" / "0426-traj1")
    predictor = Predictor(rec)
    batch, world = predictor.tdoa([]), predictor.world([])
    unit = LearnedBias(1.0).bias(batch, world)
    rows = np.flatnonzero(np.isfinite(rec.tdoa.distance_diff))[::50]
    expected = BiasNet.load(DEFAULT_NETWORK).predict(measurement_features(rec, rows, 0.0, "truth")[0],
                                                     rec.tdoa.id_a[rows], rec.tdoa.id_b[rows])
    # within 5 %: the simulator's ground truth is smoothed (RecordedTrajectory), the training data's is not
    assert np.sqrt(np.mean((unit[rows] - expected) ** 2)) < 0.05 * np.sqrt(np.mean(expected ** 2))
    before = batch.value.copy()
    make_effect("learned_bias", {"gain": 0.5}).apply_tdoa(batch, world, None)
    assert np.allclose(batch.value - before, 0.5 * unit)


@pytest.mark.parametrize("coeffs", [[0.899, -0.988, -0.679], [1.2, 0.0, 0.0], [-1.0, 0.2, -0.3], [0.0, 0.5, -0.5],
                                    [-0.3, 0.0, 0.0], [0.0, 0.0, 0.0]])
def test_a_patterns_size_is_how_much_its_ranges_differ_between_two_directions(coeffs: list[float]) -> None:
    """Over a dense sphere of directions, max − min of `pattern_basis` · coeffs is the
    size its bound measures, at least every coefficient, and the weights give it back
    as a linear form."""
    from rig.sim import effects as fx
    from rig.sim.effects.link import pattern_basis

    azimuth, elevation = np.meshgrid(np.linspace(-np.pi, np.pi, 721), np.linspace(-np.pi / 2, np.pi / 2, 361))
    bias = pattern_basis(azimuth.ravel(), elevation.ravel()) @ np.array(coeffs)
    span = bias.max() - bias.min()
    assert fx.size_of("antenna_pattern", "coeffs_m", coeffs) == pytest.approx(span, abs=1e-4)
    assert span >= np.abs(coeffs).max() - 1e-4
    weights = fx.AntennaPattern.size_weights("coeffs_m", np.array(coeffs))
    assert weights @ np.array(coeffs) == pytest.approx(span, abs=1e-4)
