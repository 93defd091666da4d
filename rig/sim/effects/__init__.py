"""The simulator's effect catalog, one module per stage: `world` (what is physically
true), `tdoa` (with `link`, the bias every tag–anchor link shares), `imu` and
`timing`, on the building blocks of `base`. `make_effect` builds one from its
catalog name and parameters, so a simulation (or a fitted model
from the diagnosis) is a plain JSON list of effects."""

from __future__ import annotations

import logging
from collections.abc import Iterable

from rig.sim.effects.base import (
    CORRUPTION,
    FILTERED,
    NOISE,
    RECTIFIED,
    SCALE,
    SIGNAL,
    TIMING,
    WORLD,
    Effect,
    ImuBatch,
    TdoaBatch,
    World,
    anchor_sign,
    ranges,
    staged,
)
from rig.sim.effects.imu import (
    LEAN_BOUND,
    LOWPASS_MAX_SHARE,
    AttitudeLean,
    ImuAccelBias,
    ImuAccelScale,
    ImuGyroBias,
    ImuGyroScale,
    ImuLowpass,
    ImuNoise,
    ImuResonance,
    ImuVibration,
    ImuVibrationRectification,
    apply_imu,
    filter_noise_gain,
    lowpass,
    lowpass_design,
    resonance_design,
    resonance_gain,
    resonant_noise,
    sample_rate,
    vibration_level,
)
from rig.sim.effects.tdoa import (
    AnchorDelay,
    AntennaPattern,
    LearnedBias,
    MultipathFloor,
    Nlos,
    OnGroundDelay,
    Outliers,
    Region,
    TagAntennaPattern,
    TdoaNoise,
    on_ground_weight,
    viewing_angles,
)
from rig.sim.effects.link import (
    LINK_BOUND_M,
    LINK_TERMS,
    LinkBias,
    calibrated_link_bias,
    link_basis,
    pattern_basis,
    tdoa_basis,
)
from rig.sim.effects.timing import ClockDrift, TimeOffset
from rig.sim.effects.world import AnchorPosition, LeverArm

log = logging.getLogger(__name__)

__all__ = ["CORRUPTION", "FILTERED", "NOISE", "RECTIFIED", "SCALE", "SIGNAL", "TIMING", "WORLD", "EFFECTS",
           "Effect", "ImuBatch", "TdoaBatch", "World", "Region", "make_effect", "effects_from_json", "bound_of",
           "params_by_name",
           "anchor_sign", "ranges", "staged", "apply_imu", "sample_rate", "vibration_level", "lowpass",
           "lowpass_design", "LOWPASS_MAX_SHARE", "resonance_design", "resonance_gain", "resonant_noise",
           "filter_noise_gain", "on_ground_weight", "pattern_basis", "viewing_angles", "link_basis", "tdoa_basis",
           "LINK_TERMS", "LINK_BOUND_M", "calibrated_link_bias", "LEAN_BOUND", "AttitudeLean",
           "ImuAccelBias", "ImuGyroBias", "ImuAccelScale", "ImuGyroScale", "ImuVibrationRectification", "ImuNoise",
           "ImuVibration", "ImuResonance", "ImuLowpass", "TdoaNoise", "Outliers", "TimeOffset", "ClockDrift",
           "AnchorPosition", "LeverArm", "AnchorDelay", "AntennaPattern", "TagAntennaPattern", "Nlos",
           "MultipathFloor", "OnGroundDelay", "LearnedBias", "LinkBias"]

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (AttitudeLean, ImuAccelBias, ImuGyroBias, ImuAccelScale, ImuGyroScale,
                              ImuVibrationRectification, ImuNoise, ImuVibration, ImuResonance, ImuLowpass,
                              TdoaNoise, Outliers, TimeOffset, ClockDrift, AnchorPosition, LeverArm, AnchorDelay,
                              AntennaPattern, TagAntennaPattern, LinkBias, Nlos, MultipathFloor, OnGroundDelay,
                              LearnedBias)
}


def bound_of(name: str, param: str) -> float:
    """The physical bound of an effect's parameter (`Effect.bounds`)."""
    return EFFECTS[name].bounds[param]


def size_of(name: str, param: str, deviation) -> float:
    """How large a deviation from neutral of an effect's parameter is, as its bound
    measures it (`Effect.size`; the largest |component| for a name the catalog lacks)."""
    kind = EFFECTS.get(name, Effect)
    return kind.size(param, deviation)


def make_effect(name: str, params: dict | None = None) -> Effect:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    try:
        return EFFECTS[name](**(params or {}))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"bad parameters for effect {name!r}: {exc}") from exc


def effects_from_json(items: list[dict], anchors: Iterable[int] | None = None) -> list[Effect]:
    """The effects listed as JSON; with the flight's `anchors` (ids), an effect on any
    other anchor is refused: it would change nothing, silently."""
    effects = [make_effect(item["effect"], item.get("params", {})) for item in items]
    for effect in effects:
        for what in effect.beyond_bound():
            log.warning("%s: %s is beyond what a real flight can carry: simulated as asked, but the "
                        "diagnosis would leave it unexplained", effect.name, what)
    if anchors is not None:
        known = sorted(set(anchors))
        for effect in effects:
            if getattr(effect, "anchor", None) is not None and effect.anchor not in known:
                raise ValueError(f"{effect.name}: anchor {effect.anchor} is not one of the flight's anchors {known}")
    return effects


def params_by_name(items: list[dict]) -> dict[str, dict]:
    """The parameters of effects listed as JSON, by effect name: for the effects a
    model has once (its noise, low-pass, resonance); of one per anchor, the last."""
    return {item["effect"]: item.get("params", {}) for item in items}
