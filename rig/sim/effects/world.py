"""World effects: what is physically true differs from what the survey says."""

from __future__ import annotations

import numpy as np

from rig.sim.effects.base import WORLD, Effect, TdoaBatch, World, _anchor_id, _vec3
from rig.sim.effects.link import largest_on_links


class AnchorPosition(Effect):
    """The anchor's antenna is really at surveyed + `offset_m` (true minus surveyed)."""

    name, stage, bounds, lengths = "anchor_position", WORLD, {"offset_m": 1.0}, frozenset({"offset_m"})

    def __init__(self, anchor: int = 0, offset_m=(0.0, 0.0, 0.0)):
        self.anchor, self.offset = _anchor_id(anchor), _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"anchor": self.anchor, "offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        if self.anchor in world.anchor_positions:
            world.anchor_positions[self.anchor] = world.anchor_positions[self.anchor] + self.offset

    def largest(self, tdoa: TdoaBatch, world: World, rows: np.ndarray) -> dict:
        """How much the displacement changes this anchor's ranges over a flight's TDOA
        `rows` and where most (largest_on_links), to first order, as a fit has it: what
        a displacement fitted on a real flight stands for is that change, whatever its
        cause."""
        def change(tag_position, tag_rotation, position, rotation):
            to_anchor = position - tag_position
            return to_anchor @ self.offset / np.linalg.norm(to_anchor, axis=1)

        return largest_on_links(change, tdoa, world, rows, [self.anchor])


# The farthest a Crazyflie-class tag's antenna can sit from the body origin (m): the
# airframe is about 0.1 m across and the UWB deck sits a few centimetres above it.
AIRFRAME_M = 0.15


class LeverArm(Effect):
    """The UWB antenna sits at `offset_m` from the body origin (body frame)."""

    name, stage, bounds, lengths = "lever_arm", WORLD, {"offset_m": AIRFRAME_M}, frozenset({"offset_m"})

    def __init__(self, offset_m=(0.0, 0.0, 0.0)):
        self.offset = _vec3(offset_m, "offset_m")

    def params(self) -> dict:
        return {"offset_m": self.offset.tolist()}

    def apply_world(self, world: World) -> None:
        world.lever_arm = world.lever_arm + self.offset
