"""The C estimator through its Python binding: tracking, robustness, bad input.

`test_estimator_under_sanitizers` reruns this module against the ASan/UBSan build."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rigtest import ROOT, run_rig, simulate_exact

from rig.data.importer import import_log
from rig.data.recording import Recording, read_recording, write_recording
from rig.estimator import native
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet
from rig.estimator.evaluate import build_events, evaluate, make_estimator, start_time, truth_pose_at


def _sim(survey: Path, effects: list[dict], duration: float = 20.0, **kw) -> Recording:
    return simulate_exact(survey, effects=effects, duration=duration, **kw)


def _start(rec: Recording, params=None) -> tuple[native.Estimator, np.ndarray, float]:
    params = params or native.params_with(use_bias_net=0)
    est = make_estimator(rec, params, None)
    t0 = start_time(rec)
    pos, quat = truth_pose_at(rec, t0)
    est.reset(0, pos, quat)
    return est, build_events(rec, t0), t0


def test_noiseless_flight_is_tracked_to_millimetres(survey_0425: Path) -> None:
    rec = _sim(survey_0425, [])
    for robust in (True, False):
        result = evaluate(rec, robust=robust, use_nn=False)
        assert result["rmse_3d"] < 0.005, (robust, result["rmse_3d"])
        assert not result["diverged"] and result["tdoa_rejected"] == 0


def test_outlier_bursts_do_not_break_tracking(survey_0425: Path) -> None:
    rec = _sim(survey_0425, [{"effect": "tdoa_noise", "params": {"std_m": 0.1}},
                             {"effect": "imu_noise", "params": {"accel_std": 0.1, "gyro_std": 0.01}}])
    rng = np.random.default_rng(3)
    bursts = [(9.0, 10.0), (14.0, 15.5), (19.0, 19.5)]
    for lo, hi in bursts:  # half the measurements of each burst are 1-5 m off
        inside = (rec.tdoa.t >= lo) & (rec.tdoa.t < hi) & (rng.random(len(rec.tdoa.t)) < 0.5)
        rec.tdoa.distance_diff[inside] += rng.uniform(1.0, 5.0, inside.sum()) * rng.choice([-1, 1], inside.sum())
    result = evaluate(rec, robust=True, use_nn=False)
    assert not result["diverged"]
    assert result["max_3d"] < 0.5, "an outlier burst pulled the estimate away"
    assert result["rmse_3d"] < 0.15
    assert result["tdoa_rejected"] + result["tdoa_downweighted"] > 100


@pytest.mark.slow
def test_rig_evaluate_tells_measurements_refused_at_input_from_those_the_update_rejects(tmp_path: Path) -> None:
    rec = read_recording(ROOT / "recordings" / "default.mcap")
    rec.tdoa.distance_diff[::50] = np.nan
    write_recording(rec, tmp_path / "nan.mcap")
    proc = run_rig("evaluate", str(tmp_path / "nan.mcap"), "--json", str(tmp_path / "e.json"), check=True)
    result = json.loads((tmp_path / "e.json").read_text())
    by_reason = result["rejected_by_reason"]
    assert 100 < by_reason["nonfinite"] <= len(rec.tdoa.t[::50])     # those from take-off on
    line = re.search(r"(\d+) rejected \(gate (\d+), robust weight (\d+)\); refused before the update: (.*?);",
                     proc.stdout)
    assert line, proc.stdout
    rejected, gate, weight = map(int, line.groups()[:3])
    assert rejected == result["tdoa_rejected"] == gate + weight and gate == by_reason["gate"]
    assert f"nonfinite {by_reason['nonfinite']}" in line.group(4) and "gate" not in line.group(4)


@pytest.mark.slow
def test_rig_evaluate_says_when_windows_had_no_imu_sample(tmp_path: Path) -> None:
    from dataclasses import replace

    from rig.data.recording import Vec3Series

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    whole = run_rig("evaluate", str(ROOT / "recordings" / "default.mcap"), check=True)
    assert "IMU:" not in whole.stderr                      # a whole recording: nothing to say
    none = Vec3Series(rec.accel.t[:0], rec.accel.xyz[:0])
    write_recording(replace(rec, accel=none, gyro=none), tmp_path / "no-imu.mcap")
    proc = run_rig("evaluate", str(tmp_path / "no-imu.mcap"), "--json", str(tmp_path / "e.json"))
    result = json.loads((tmp_path / "e.json").read_text())
    assert result["imu_samples"] == 0 and result["imu_gaps"] > 1000
    assert f"IMU: {result['imu_gaps']} windows of 10 ms without a sample" in proc.stderr
    assert "has no IMU samples" in proc.stderr


def test_every_bad_input_is_counted_by_reason_and_never_reaches_the_state(survey_0425: Path) -> None:
    rec = _sim(survey_0425, [{"effect": "tdoa_noise", "params": {"std_m": 0.05}}], duration=10.0)
    est, events, _ = _start(rec)
    tdoa = np.flatnonzero(events["kind"] == native.EV_TDOA)
    imu = np.flatnonzero(events["kind"] == native.EV_ACCEL)
    bad = events.copy()
    bad["v"][tdoa[10:20], 0] = np.nan
    bad["v"][tdoa[20:25], 0] = np.inf
    bad["id_a"][tdoa[30:40]] = 12          # not configured
    bad["id_b"][tdoa[40:45]] = 250         # out of range
    bad["id_b"][tdoa[50:55]] = bad["id_a"][tdoa[50:55]]
    bad["v"][tdoa[60:66], 0] = 40.0        # larger than any anchor separation
    bad["v"][imu[100:110], 1] = np.nan
    late = bad[tdoa[200]].copy()
    late["t_us"] = 0                       # time going backwards
    gap = (bad["t_us"] > 4_000_000) & (bad["t_us"] < 4_300_000) & (bad["kind"] < native.EV_TDOA)
    cut = tdoa[300]
    stream = np.concatenate([bad[:cut], late[None], bad[cut:]])
    stream = stream[~np.concatenate([gap[:cut], [False], gap[cut:]])]
    out = est.replay(stream)
    reasons = dict(zip(native.REJECT_REASONS, out["counters"][-1]["rejected"].tolist()))
    assert reasons["nonfinite"] == 10 + 5 + 10
    assert reasons["unknown_anchor"] == 15
    assert reasons["same_anchor"] == 5
    assert reasons["exceeds_baseline"] >= 6
    assert reasons["time_backwards"] == 1
    assert out["counters"][-1]["imu_gaps"] >= 25
    assert np.all(np.isfinite(out["pos"])) and np.all(np.isfinite(out["cov_diag"]))
    truth = np.column_stack([np.interp(out["t_us"] * 1e-6 + start_time(rec), rec.truth.t, rec.truth.position[:, i])
                             for i in range(3)])
    assert np.max(np.linalg.norm(out["pos"] - truth, axis=1)) < 0.3


@pytest.mark.slow
def test_covariance_stays_symmetric_positive_definite_over_a_real_flight(data_dir: Path) -> None:
    rec = import_log(data_dir / "flights" / "0426-traj7", data_dir / "surveys" / "anchor_0426.txt")
    est, events, _ = _start(rec, native.params_with(use_bias_net=0))
    steps = np.flatnonzero(events["kind"] == native.EV_STEP)
    lo = 0
    for hi in steps[99::100]:  # check once a second
        est.replay(events[lo: hi + 1])
        lo = hi + 1
        P = est.covariance()
        np.testing.assert_allclose(P, P.T, atol=1e-9)
        assert np.linalg.eigvalsh(P.astype(float)).min() > 0.0


def test_diverged_state_is_reset_and_counted(survey_0425: Path) -> None:
    rec = _sim(survey_0425, [], duration=8.0)
    est, events, _ = _start(rec)
    # Start 40 m off with a confident prior: the estimate cannot reconcile and must reset.
    events["v"][events["kind"] == native.EV_ACCEL] *= 30.0
    out = est.replay(events)
    assert out["counters"][-1]["resets"] >= 1
    assert np.all(np.isfinite(out["pos"]))
    assert np.all(np.abs(out["pos"]) <= 50.0)
    # the same flight goes on: its counts run through the divergence reset
    np.testing.assert_array_equal(out["counters"]["steps"], np.arange(1, len(out["counters"]) + 1))


def test_a_new_flight_counts_from_zero(survey_0425: Path) -> None:
    """The start of a flight (est_reset, a board's RESET) clears the counters: a bench
    board replaying flight after flight reports each flight's own."""
    rec = _sim(survey_0425, [{"effect": "tdoa_noise", "params": {"std_m": 0.1}}], duration=8.0)
    est, events, t0 = _start(rec)
    first = est.replay(events)["counters"][-1]
    pos, quat = truth_pose_at(rec, t0)
    est.reset(0, pos, quat)
    second = est.replay(events)["counters"][-1]
    assert first["steps"] > 0 and first["tdoa_accepted"] > 0
    assert second.tobytes() == first.tobytes()


def test_a_minute_of_flight_at_400_hz_is_evaluated_and_its_estimator_time_reported(survey_0425: Path) -> None:
    """The cost itself is counted in instructions by benchmarks/cost.py (a wall-clock bar
    here would measure the CI host); here only that the time is reported, and is far
    from the flight's own."""
    rec = _sim(survey_0425, [{"effect": "tdoa_noise", "params": {"std_m": 0.1}}], duration=60.0, tdoa_hz=400.0)
    result = evaluate(rec, use_nn=False)
    assert result["flight_seconds"] > 60.0
    assert 0 < result["estimator_seconds"] < result["flight_seconds"] / 10


@pytest.mark.slow
def test_estimator_under_sanitizers() -> None:
    if os.environ.get("UWB_RIG_UNDER_SANITIZERS"):
        return  # this is the inner run
    lib = native.build("sanitize")
    runtime = subprocess.run(["gcc", "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    env = {**os.environ, "UWB_RIG_ESTIMATOR_LIB": str(lib), "LD_PRELOAD": runtime,
           "ASAN_OPTIONS": "detect_leaks=0", "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
           "UWB_RIG_UNDER_SANITIZERS": "1", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", __file__,
                           "-k", "not sixty_seconds and not real_flight and not shared_flight"],
                          env=env, capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "passed" in proc.stdout and "ERROR: AddressSanitizer" not in proc.stderr


@pytest.mark.slow
def test_no_shared_flight_diverges_in_any_configuration_and_robust_averages_under_30_cm(data_dir: Path) -> None:
    from concurrent.futures import ProcessPoolExecutor

    from rig.data import paths

    with ProcessPoolExecutor(max_workers=2) as pool:
        rows = list(pool.map(_both_configs, paths.flights()))
    diverged = [(name, cfg) for name, res in rows for cfg, r in res.items() if r["diverged"]]
    assert diverged == []
    assert np.mean([res["robust"]["rmse_3d"] for _, res in rows]) <= 0.30


def _both_configs(flight: Path) -> tuple[str, dict]:
    """Every configuration, with and without the shipped bias network."""
    from rig.data import paths

    rec = import_log(flight, paths.survey_for(flight))
    return flight.name, {"robust": evaluate(rec, robust=True, use_nn=False),
                         "plain": evaluate(rec, robust=False, use_nn=False),
                         "robust+nn": evaluate(rec, robust=True, use_nn=True),
                         "plain+nn": evaluate(rec, robust=False, use_nn=True)}


def test_the_truth_orientation_between_samples_is_scipys_slerp() -> None:
    """The reset pose's orientation (numpy, so a replay does not import scipy) against
    scipy's Slerp, inside the samples, on them and beyond either end."""
    from scipy.spatial.transform import Rotation, Slerp

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    times, keep = np.unique(rec.truth.t, return_index=True)
    reference = Slerp(times, Rotation.from_quat(rec.truth.quaternion[keep]))
    for t in np.concatenate([np.linspace(times[0] - 1, times[-1] + 1, 997), times[::50]]):
        quat = truth_pose_at(rec, t)[1]
        expected = reference(np.clip(t, times[0], times[-1])).as_quat()
        assert np.abs(quat - expected).max() < 1e-12 or np.abs(quat + expected).max() < 1e-12


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0, -135.0, 400.0])
def test_a_given_start_pose_is_level_with_its_heading_as_scipy_builds_it(yaw_deg: float) -> None:
    from scipy.spatial.transform import Rotation

    from rig.estimator.evaluate import StartPose, initial_pose

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    pos, quat = initial_pose(rec, 3.0, StartPose((1.0, -2.0, 0.05), yaw_deg))
    assert pos.tolist() == [1.0, -2.0, 0.05]
    expected = Rotation.from_euler("ZYX", [yaw_deg, 0.0, 0.0], degrees=True).as_quat()
    assert np.abs(quat - expected).max() < 1e-12 or np.abs(quat + expected).max() < 1e-12


def test_rig_evaluate_starts_from_a_given_pose_at_the_usual_time_and_scores_as_ever(tmp_path: Path) -> None:
    from rig.estimator.evaluate import StartPose, estimator_config, replay

    rec = read_recording(ROOT / "recordings" / "default.mcap")
    params, model = estimator_config()
    moved = replay(rec, params, model, start_pose=StartPose((2.0, 0.5, 0.03), 90.0))
    assert moved.t_start == start_time(rec)                          # the usual time, the given pose
    assert np.abs(moved.position[0] - [2.0, 0.5, 0.03]).max() < 0.05     # 10 ms in; the truth stood 0.5 m away
    run_rig("evaluate", "recordings/default.mcap", "--start-position", "2.0", "0.5", "0.03", "--start-yaw", "90",
            "--json", str(tmp_path / "m.json"), check=True)
    result = json.loads((tmp_path / "m.json").read_text())
    assert result["config"]["start_pose"] == {"position": [2.0, 0.5, 0.03], "yaw_deg": 90.0}
    assert result["rmse_3d"] < 0.4                                   # half a metre off, it converged


def test_a_start_pose_without_finite_coordinates_is_refused() -> None:
    from rig.data.errors import InputError
    from rig.estimator.evaluate import StartPose

    for position, yaw in (((0.0, float("nan"), 0.0), 0.0), ((0.0, 0.0), 0.0), ((0.0, 0.0, 0.0), float("inf"))):
        with pytest.raises(InputError, match="three finite coordinates"):
            StartPose(position, yaw)


def test_rig_evaluate_refuses_a_damaged_model_file_in_one_line_naming_it(tmp_path: Path) -> None:
    shipped = json.loads(DEFAULT_NETWORK.read_text())
    nan = json.loads(json.dumps(shipped))
    nan["weights"][1][3][2] = float("nan")            # a diverged training
    lacking = {k: v for k, v in shipped.items() if k != "biases"}
    wrong = {**shipped, "in_mean": shipped["in_mean"][:-1]}
    files = {"nan.json": json.dumps(nan), "lacking.json": json.dumps(lacking), "wrong.json": json.dumps(wrong),
             "cut.json": DEFAULT_NETWORK.read_text()[:700]}
    reasons = {"nan.json": "weights are not all finite", "lacking.json": "lacks 'biases'",
               "wrong.json": "layers are", "cut.json": "not a usable bias model"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        proc = run_rig("evaluate", str(ROOT / "recordings" / "default.mcap"), "--model", str(tmp_path / name))
        assert proc.returncode == 2, (name, proc.stderr)
        assert str(tmp_path / name) in proc.stderr and reasons[name] in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert BiasNet.load(DEFAULT_NETWORK).form == "link"   # the file it was made from is sound


def test_a_board_whose_network_predicts_nan_refuses_those_measurements_and_keeps_its_state() -> None:
    rec = read_recording(ROOT / "recordings" / "default.mcap")
    packed = BiasNet.load(DEFAULT_NETWORK).pack()
    packed["link"]["b4"] = np.nan                    # what a damaged upload could hold
    params = native.params_with(use_bias_net=1)
    est = make_estimator(rec, params, None)
    est.set_bias_net(packed)
    t0 = start_time(rec)
    est.reset(0, *truth_pose_at(rec, t0))
    outputs = est.replay(build_events(rec, t0))
    counters = outputs["counters"][-1]
    assert np.isfinite(outputs["pos"]).all() and counters["resets"] == 0
    corrected = counters["rejected"][native.REJECT_REASONS.index("nonfinite")]
    assert corrected > 0.9 * len(rec.tdoa.t[rec.tdoa.t > t0])      # every measurement it would correct
    assert counters["tdoa_accepted"] + counters["tdoa_downweighted"] == 0
