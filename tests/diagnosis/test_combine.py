"""Combining the models diagnosed on several flights into one simulation config
(`rig combine-models`, how the shipped default recording gets its effects)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rigtest import run_rig

from rig.data.recording import read_recording
from rig.diagnosis.combine import combine, read_models, replace_fitted
from rig.diagnosis.robust import delay_centre

pytestmark = pytest.mark.slow        # left out of `make test-fast`


def _model(offset: float, delays: dict[int, float], nlos: bool = False, drift: float | None = None) -> list[dict]:
    effects = [{"effect": "time_offset", "params": {"seconds": offset}}]
    effects += [{"effect": "anchor_delay", "params": {"anchor": k, "meters": m}} for k, m in delays.items()]
    if nlos:
        effects.append({"effect": "nlos", "params": {"anchor": 2, "fraction": 1.0, "mean_excess_m": 0.3,
                                                     "region": {"min": [0, 0, 0], "max": [1, 1, 1]}}})
    if drift is not None:
        effects.append({"effect": "clock_drift", "params": {"ppm": drift}})
    effects.append({"effect": "imu_accel_bias", "params": {"bias_mps2": [offset, 0.0, 1.0], "during": [1.0, 2.0]}})
    return effects


def _changed_in_a_window(model: list[dict], anchor: int, meters: float) -> list[dict]:
    """The model with `anchor`'s delay reading `meters` for a second, its own value elsewhere."""
    return [{**e, "params": {**e["params"], "meters": meters, "during": [1.0, 2.0], "outside_m": e["params"]["meters"]}}
            if e["effect"] == "anchor_delay" and e["params"]["anchor"] == anchor else e for e in model]


MODELS = [_changed_in_a_window(_model(-0.05, {0: 0.1, 1: -0.1, 2: 0.0}, nlos=True, drift=500.0), 0, 0.9),
          _model(-0.07, {0: 0.3, 1: -0.1, 2: 0.0}),
          _model(-0.06, {0: 0.2, 1: -0.3, 2: 0.1})]


def test_effects_named_on_most_flights_enter_with_their_medians() -> None:
    combined = {(e["effect"], e["params"].get("anchor")): e["params"] for e in combine(MODELS)}
    assert combined[("time_offset", None)]["seconds"] == pytest.approx(-0.06)
    # medians 0.2, -0.1, 0.0 -> relative to their centre (all within its spread: their mean,
    # 0.1 / 3); anchor 0 enters with 0.1, its value outside the window of the first flight, not 0.9
    assert [combined[("anchor_delay", k)]["meters"] for k in (0, 1, 2)] == pytest.approx([0.2 - 0.1 / 3, -0.1 - 0.1 / 3,
                                                                                          -0.1 / 3])
    assert combined[("imu_accel_bias", None)] == {"bias_mps2": pytest.approx([-0.06, 0.0, 1.0])}   # no "during"
    assert ("clock_drift", None) not in combined, "named on one flight of three: not a property of the room"
    assert ("nlos", 2) not in combined, "an NLOS region belongs to one flight's path"


def test_the_config_keeps_its_own_outliers_imu_noise_and_pose_dependent_bias() -> None:
    own = [{"effect": "link_bias", "params": {"coeffs_m": [-0.4, 0.0, 0.2, -0.2, -0.4, 0.0], "gain": 1.0}},
           {"effect": "learned_bias", "params": {"gain": 1.0, "network": "room.json"}},
           {"effect": "outliers", "params": {"fraction": 0.05}}, {"effect": "imu_noise", "params": {"accel_std": 0.1}},
           {"effect": "imu_vibration", "params": {"accel_std": [0.3, 0.3, 0.0]}}]
    config = {"trajectory": "circle", "effects": [*own, {"effect": "tdoa_noise", "params": {"std_m": 0.1}}]}
    # every flight names the same noise and link gain: still the config's own (calibrated) ones
    diagnosed = [[*m, {"effect": "imu_noise", "params": {"accel_std": 0.9}},
                  {"effect": "link_bias", "params": {"coeffs_m": [0.1] * 6, "gain": 0.5}}] for m in MODELS]
    effects = replace_fitted(config, combine(diagnosed))["effects"]
    assert [e for e in effects if e["effect"] in ("link_bias", "imu_noise")] == [own[0], own[3]]
    assert effects[-5:] == own, \
        "the pose-dependent bias, heavy tails, the IMU's white noise and the rotors' vibration stay the config's own"
    assert all(e["effect"] != "tdoa_noise" for e in effects), "the config's own noise is replaced by none fitted"


def test_cli_combines_models_into_a_config_that_simulates(tmp_path: Path) -> None:
    paths = []
    for k, model in enumerate(MODELS):
        (tmp_path / f"f{k}").mkdir()
        paths.append(tmp_path / f"f{k}" / "model.json")
        paths[-1].write_text(json.dumps({"effects": model}))
    config = tmp_path / "sim.json"
    config.write_text(json.dumps({"trajectory": "circle", "duration": 3.0, "seed": 1, "effects": []}))
    run_rig("combine-models", *map(str, paths), "--config", str(config), check=True)
    effects = json.loads(config.read_text())["effects"]
    assert {e["effect"] for e in effects} == {"time_offset", "anchor_delay", "imu_accel_bias"}
    run_rig("simulate", "--config", str(config), "-o", str(tmp_path / "out.mcap"), check=True)
    assert len(read_recording(tmp_path / "out.mcap").tdoa) > 100


def test_a_rectification_enters_as_the_bias_it_made_on_its_flight(tmp_path: Path) -> None:
    """A config keeps its own white IMU noise, so a flight's vibration rectification
    enters the combination as the offset it made there: gain × that flight's mean
    vibration RMS, added to its accelerometer bias (or as one)."""
    rectified = {"effect": "imu_vibration_rectification", "params": {"gain": [-3.0, -2.0, 0.0]}}
    files = []
    for k, (effects, rms) in enumerate([(MODELS[1] + [rectified], [1.0, 0.5, 0.3]),
                                        ([rectified], [0.5, 0.5, 0.5])]):
        files.append(tmp_path / f"model{k}.json")
        files[-1].write_text(json.dumps({"effects": effects, "vibration_rms_mps2": rms}))
    with_bias, alone = read_models(files)
    assert all(e["effect"] != "imu_vibration_rectification" for e in with_bias + alone)
    bias = next(e["params"] for e in with_bias if e["effect"] == "imu_accel_bias")
    assert bias["bias_mps2"] == pytest.approx([-0.07 - 3.0, -1.0, 1.0]) and bias["during"] == [1.0, 2.0]
    assert alone == [{"effect": "imu_accel_bias", "params": {"bias_mps2": pytest.approx([-1.5, -1.0, 0.0])}}]
    files[1].write_text(json.dumps({"effects": [rectified]}))
    with pytest.raises(ValueError, match="without the flight's vibration_rms_mps2"):
        read_models(files[1:])


def test_a_file_that_is_not_a_model_is_refused_clearly(tmp_path: Path) -> None:
    bad = tmp_path / "model.json"
    bad.write_text("[1, 2]")
    config = tmp_path / "sim.json"
    config.write_text('{"effects": []}')
    proc = run_rig("combine-models", str(bad), "--config", str(config))
    assert proc.returncode == 2 and "not a model.json written by rig diagnose" in proc.stderr
    assert config.read_text() == '{"effects": []}', "the config is untouched"


def test_an_accelerometer_scale_enters_as_the_offset_it_made_in_hover(tmp_path: Path) -> None:
    """In hover a z scale and a z bias are one column, named one or the other flight by
    flight: each flight's scale enters as the offset it makes there ((scale − 1) × g
    on z, none on x and y, which see no force in hover), added to its bias, so the
    median over flights keeps the pair together."""
    scaled = {"effect": "imu_accel_scale", "params": {"scale": [1.3, 0.9, 0.88]}}
    flights = [[{"effect": "imu_accel_bias", "params": {"bias_mps2": [0.1, 0.2, 1.08]}}, scaled],
               [{"effect": "imu_accel_bias", "params": {"bias_mps2": [0.0, 0.0, -0.1]}}],
               [{"effect": "imu_accel_scale", "params": {"scale": [1.0, 1.0, 0.99]}}]]
    files = []
    for k, effects in enumerate(flights):
        files.append(tmp_path / f"model{k}.json")
        files[-1].write_text(json.dumps({"effects": effects}))
    both, bias_only, scale_only = read_models(files)
    assert both == [{"effect": "imu_accel_bias", "params": {"bias_mps2": pytest.approx([0.1, 0.2, 1.08 - 0.12 * 9.81])}}]
    assert bias_only == flights[1]
    assert scale_only == [{"effect": "imu_accel_bias", "params": {"bias_mps2": pytest.approx([0.0, 0.0, -0.0981])}}]
    combined = {e["effect"]: e["params"] for e in combine([both, bias_only, scale_only])}
    assert "imu_accel_scale" not in combined
    assert combined["imu_accel_bias"]["bias_mps2"] == pytest.approx([0.0, 0.0, -0.0981])


def test_the_ranges_on_the_floor_enter_with_each_anchors_median_against_their_centre() -> None:
    """Per anchor, over the flights that saw it on the floor; as TDOA sees them,
    relative to each other."""
    readings = [(0.1, {"0": 1.0, "1": -1.0}), (0.05, {"0": 2.0, "1": -1.0, "2": 0.5}),
                (0.1, {"0": 1.5, "1": -2.0, "2": 0.3})]
    models = [[{"effect": "on_ground_delay", "params": {"height_m": h, "meters": m}}] for h, m in readings]
    (combined,) = combine(models)
    meters = combined["params"]["meters"]
    assert combined["params"]["height_m"] == pytest.approx(0.1)
    assert list(meters) == ["0", "1", "2"]
    medians = np.array([1.5, -1.0, 0.4])
    assert [meters[k] for k in "012"] == pytest.approx(medians - delay_centre(medians))
