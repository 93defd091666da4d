"""One simulator model from the models `rig diagnose` fitted on several real flights
of one room, to fly another trajectory there (the shipped default recording).

An effect transfers to another trajectory if it belongs to the hardware or the room
(a delay, how the ranges read with the drone on the floor, a clock, an IMU error, the
TDOA noise), not to one flight's path: NLOS regions, anchor displacements, antenna
patterns and lever arms, as the diagnosis fits them on real flights, are mostly the
pose-dependent bias seen along that path (docs/notebook/diagnosis.md) and are left out; a
config's own `link_bias` and `learned_bias` carry that bias to any trajectory and are
kept. An
effect enters when the diagnosis named it on at least half of the flights (a
property of the room, not of one flight); its parameters are the medians over those
flights (per anchor, for how the ranges read on the floor). Confinement in time
(`during`) is dropped: it belongs to one flight's clock (a delay that changed in a
window enters with its value outside it)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from rig.diagnosis.findings import rounded_floats
from rig.diagnosis.robust import delay_centre
from rig.sim.trajectory import GRAVITY

log = logging.getLogger(__name__)

# in the order they are listed in a config (a vibration rectification and an
# accelerometer scale enter as the accelerometer bias they made on their flight, see
# fold_rectification and fold_accel_scale)
TRANSFERABLE = ("time_offset", "clock_drift", "anchor_delay", "on_ground_delay", "multipath_floor", "imu_accel_bias",
                "imu_gyro_bias", "imu_gyro_scale", "tdoa_noise")
MIN_SHARE = 0.5
CONFIG_DIGITS = 4            # a config a person reads: the fit is not more precise


def read_models(paths: list[Path]) -> list[list[dict]]:
    """The effect lists of `rig diagnose` model files (DIR/model.json)."""
    models = []
    for path in paths:
        try:
            model = json.loads(Path(path).read_text())
            effects = model["effects"]
            if not all(isinstance(e, dict) and "effect" in e and isinstance(e.get("params"), dict) for e in effects):
                raise ValueError("an effect without a name or parameters")
            effects = fold_accel_scale(fold_rectification(effects, model.get("vibration_rms_mps2")))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: not a model.json written by rig diagnose ({exc})") from exc
        models.append(effects)
    return models


def fold_rectification(effects: list[dict], vibration_rms: list[float] | None) -> list[dict]:
    """A flight's vibration rectification as the offset it made there (gain × the
    flight's mean vibration RMS), added to its accelerometer bias. A combined config
    keeps its own white IMU noise (KEPT_FROM_CONFIG), whose RMS is not the flight's:
    the rectification itself would make another offset there."""
    rectified = [e for e in effects if e["effect"] == "imu_vibration_rectification"]
    if not rectified:
        return effects
    if vibration_rms is None:
        raise ValueError("a vibration rectification without the flight's vibration_rms_mps2")
    offset = sum(np.asarray(e["params"]["gain"], float) * np.asarray(vibration_rms, float) for e in rectified)
    return _with_accel_offset([e for e in effects if e["effect"] != "imu_vibration_rectification"], offset)


# what an accelerometer reads in hover, body frame
HOVER_SPECIFIC_FORCE = np.array([0.0, 0.0, GRAVITY])


def fold_accel_scale(effects: list[dict]) -> list[dict]:
    """A flight's accelerometer scale as the offset it makes in hover, (scale − 1) ×
    the specific force there, added to its bias. In hover a z scale and a z bias are
    one column, and the diagnosis names one or the other flight by flight (both
    jointly where the thrust varies a little): medians taken over flights apart do
    not keep the pair together (a large scale and a large bias that cancel in hover
    would each enter a median alone). The x and y scales act only on the
    small horizontal forces, which these flights do not identify, and go."""
    scaled = [e for e in effects if e["effect"] == "imu_accel_scale"]
    if not scaled:
        return effects
    offset = sum((np.asarray(e["params"]["scale"], float) - 1.0) * HOVER_SPECIFIC_FORCE for e in scaled)
    return _with_accel_offset([e for e in effects if e["effect"] != "imu_accel_scale"], offset)


def _with_accel_offset(effects: list[dict], offset: np.ndarray) -> list[dict]:
    """`effects` with `offset` added to their accelerometer bias, or as one."""
    bias = next((e for e in effects if e["effect"] == "imu_accel_bias"), None)
    if bias is None:
        return effects + [{"effect": "imu_accel_bias", "params": {"bias_mps2": np.asarray(offset, float).tolist()}}]
    folded = {**bias["params"], "bias_mps2": (np.asarray(bias["params"]["bias_mps2"], float) + offset).tolist()}
    return [{**e, "params": folded} if e is bias else e for e in effects]


def combine(models: list[list[dict]]) -> list[dict]:
    """The transferable effects named on at least MIN_SHARE of `models`, each with the
    median of its parameters; delays relative to their centre as a diagnosis reports
    them (`delay_centre`: TDOA sees no common delay)."""
    if not models:
        raise ValueError("no fitted models to combine")
    groups: dict[tuple[str, int | None], list[dict]] = {}
    for model in models:
        for item in model:
            if item["effect"] in TRANSFERABLE:
                key = (item["effect"], item["params"].get("anchor"))
                groups.setdefault(key, []).append(outside_window(item["params"]))
    out = []
    for (effect, anchor), params in sorted(groups.items(), key=lambda kv: (TRANSFERABLE.index(kv[0][0]),
                                                                          kv[0][1] if kv[0][1] is not None else -1)):
        if len(params) < MIN_SHARE * len(models):
            log.info("%s%s: named on %d of %d flights, left out", effect, "" if anchor is None else f":{anchor}",
                     len(params), len(models))
            continue
        out.append({"effect": effect, "params": _median_params(params)})
    _centre_delays(out)
    return out


def outside_window(params: dict) -> dict:
    """The parameters outside any window: a delay that changed for part of one flight
    keeps its value elsewhere (`outside_m`)."""
    if "outside_m" not in params:
        return params
    kept = {k: v for k, v in params.items() if k not in ("during", "outside_m")}
    return {**kept, "meters": params["outside_m"]}


def _median_params(params: list[dict]) -> dict:
    merged = {}
    for field, value in params[0].items():
        if field == "during":
            continue
        if isinstance(value, dict):         # per anchor: each anchor's median over the flights that have it
            keys = sorted({key for p in params for key in p.get(field, {})}, key=int)
            merged[field] = {key: float(np.median([p[field][key] for p in params if key in p.get(field, {})]))
                             for key in keys}
            continue
        if field == "anchor" or not isinstance(value, (int, float, list)):
            merged[field] = value
            continue
        values = np.array([p[field] for p in params if field in p], float)
        merged[field] = float(np.median(values)) if values.ndim == 1 else np.median(values, axis=0).tolist()
    return merged


def _centre_delays(effects: list[dict]) -> None:
    delays = [e["params"] for e in effects if e["effect"] == "anchor_delay"]
    if delays:
        shift = delay_centre(np.array([d["meters"] for d in delays]))
        for d in delays:
            d["meters"] -= shift
    for on_ground in (e["params"] for e in effects if e["effect"] == "on_ground_delay"):
        shift = delay_centre(np.array(list(on_ground["meters"].values())))
        on_ground["meters"] = {k: m - shift for k, m in on_ground["meters"].items()}


# kept from the config when its fitted effects are replaced: the heavy tails beyond the
# diagnosis's robust noise scale (not fitted), and the IMU's noise, the rotors'
# vibration and the low-pass they go through: a flight's noise is its own (0.35-2.2
# m/s2 RMS of vibration on the accelerometer), and noise of that size would more than
# double the bytes a replay sends per window. And the pose-dependent bias: the link
# bias as `rig calibrate` fitted it to all the shared flights (`link_bias`; a flight's
# diagnosis names only its gain) and what it leaves (`learned_bias`), which the
# diagnosis leaves to one flight's path and a network trained on other flights
# carries to any trajectory.
KEPT_FROM_CONFIG = ("link_bias", "learned_bias", "outliers", "imu_noise", "imu_vibration", "imu_resonance",
                    "imu_lowpass")


def replace_fitted(config: dict, effects: list[dict]) -> dict:
    """`config` (a `rig simulate` config) with `effects` in place of its effects,
    keeping those of KEPT_FROM_CONFIG."""
    kept = [e for e in config.get("effects", []) if e["effect"] in KEPT_FROM_CONFIG]
    return {**config, "effects": rounded_floats(effects, CONFIG_DIGITS) + kept}


def config_json(config: dict) -> str:
    """A simulation config as JSON with one effect per line: a config a person reads and diffs."""
    head = {k: v for k, v in config.items() if k != "effects"}
    lines = [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    effects = ",\n".join(f"    {json.dumps(e)}" for e in config.get("effects", []))
    return "{\n" + "\n".join(lines) + '\n  "effects": [\n' + effects + "\n  ]\n}\n"
