"""World effects: what is physically true differs from what the survey says."""

from __future__ import annotations

from rig.sim.effects.base import WORLD, Effect, World, _anchor_id, _vec3


class AnchorPosition(Effect):
    """The anchor's antenna is really at surveyed + `offset_m` (true minus surveyed)."""

    name, stage, bounds = "anchor_position", WORLD, {"offset_m": 1.0}

    def __init__(self, anchor: int = 0, offset_m=(0.0, 0.0, 0.0)):
        self.anchor, self.offset = _anchor_id(anchor), _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"anchor": self.anchor, "offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        if self.anchor in world.anchor_positions:
            world.anchor_positions[self.anchor] = world.anchor_positions[self.anchor] + self.offset


# The farthest a Crazyflie-class tag's antenna can sit from the body origin (m): the
# airframe is about 0.1 m across and the UWB deck sits a few centimetres above it.
AIRFRAME_M = 0.15


class LeverArm(Effect):
    """The UWB antenna sits at `offset_m` from the body origin (body frame)."""

    name, stage, bounds = "lever_arm", WORLD, {"offset_m": AIRFRAME_M}

    def __init__(self, offset_m=(0.0, 0.0, 0.0)):
        self.offset = _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        world.lever_arm = world.lever_arm + self.offset
