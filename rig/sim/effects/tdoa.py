"""TDOA effects: noise and outliers, per-anchor delays, antenna patterns (anchor and
tag), NLOS in a region, floor multipath, the drone on the floor, and the learned
pose-dependent bias."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from rig.data import paths
from rig.estimator import native
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet
from rig.sim.effects.base import (
    CORRUPTION,
    FRACTION,
    HEIGHT,
    NOISE,
    SIGNAL,
    Effect,
    TdoaBatch,
    World,
    _anchor_id,
    _anchor_sign,
    _finite,
    _fraction,
    _non_negative,
    _positive,
    _vec3,
    _Windowed,
)
from rig.sim.effects.link import direction_angles, largest_on_links, pattern_basis


class TdoaNoise(Effect):
    """Zero-mean Gaussian noise on every TDOA measurement (m)."""

    name, stage = "tdoa_noise", NOISE

    def __init__(self, std_m: float = 0.1):
        self.std = _finite(std_m, "std_m", "a standard deviation >= 0", _non_negative)

    def params(self) -> dict:
        return {"std_m": self.std}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is not None:
            tdoa.value += rng.normal(0.0, self.std, tdoa.value.shape)


class Outliers(Effect):
    """A `fraction` of TDOA samples gets an excess path delay on one of its two
    anchors (exponential, mean `mean_excess_m`): multipath makes a path longer,
    so the error's sign says which anchor was hit."""

    name, stage = "outliers", CORRUPTION

    def __init__(self, fraction: float = 0.05, mean_excess_m: float = 2.0):
        self.fraction = _finite(fraction, "fraction", FRACTION, _fraction)
        self.mean_excess = _finite(mean_excess_m, "mean_excess_m")

    def params(self) -> dict:
        return {"fraction": self.fraction, "mean_excess_m": self.mean_excess}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is None:        # symmetric in sign: no expected shift
            return
        hit = rng.random(len(tdoa.value)) < self.fraction
        excess = 1.0 + rng.exponential(self.mean_excess, len(tdoa.value))
        # A longer path to B raises distance_diff, a longer path to A lowers it.
        sign = np.where(rng.random(len(tdoa.value)) < 0.5, 1.0, -1.0)
        tdoa.value += np.where(hit, sign * excess, 0.0)


class AnchorDelay(_Windowed, Effect):
    """Every range from `anchor` reads `meters` too long (an antenna delay error). With
    `during`, `meters` holds in that window and `outside_m` (default 0) elsewhere: a
    delay that changes for part of the flight (TDOA sees delays only relative to each
    other, so "no delay outside the window" is rarely what a diagnosis can say)."""

    name, stage, bounds = "anchor_delay", SIGNAL, {"meters": 1.5}

    def __init__(self, anchor: int = 0, meters: float = 0.0, during=None, outside_m: float = 0.0):
        self.anchor, self.meters = _anchor_id(anchor), _finite(meters, "meters")
        self.outside_m = _finite(outside_m, "outside_m")
        self._set_during(during)
        if self.outside_m and self.during is None:
            raise ValueError("outside_m needs a window (during)")

    def params(self) -> dict:
        window = {**self._window_params(), "outside_m": self.outside_m} if self.during else {}
        return {"anchor": self.anchor, "meters": self.meters, **window}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        delay = np.where(self.active(tdoa.t), self.meters, self.outside_m)
        tdoa.value += delay * _anchor_sign(tdoa, self.anchor)


def viewing_angles(tdoa: TdoaBatch, world: World, anchor: int) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of the tag seen in `anchor`'s own frame."""
    rel = tdoa.tag_position - world.anchor_positions[anchor]
    return direction_angles(world.anchor_rotations[anchor].inv().apply(rel))


class AntennaPattern(_Windowed, Effect):
    """Range bias of `anchor` depending on where the tag is seen from the anchor (its
    doughnut-shaped radiation pattern, paper Section II.B): `coeffs_m` weigh
    `pattern_basis` of the tag's azimuth and elevation in the anchor's frame. Its bound
    is on how much its ranges differ between two directions (`size_weights`), not on
    each coefficient."""

    name, stage, bounds = "antenna_pattern", SIGNAL, {"coeffs_m": 1.0}

    def __init__(self, anchor: int = 0, coeffs_m=(0.0, 0.0, 0.0), during=None):
        self.anchor, self.coeffs = _anchor_id(anchor), _vec3(coeffs_m, "coeffs_m")
        self._set_during(during)

    @classmethod
    def size_weights(cls, param: str, deviation: np.ndarray) -> np.ndarray:
        """A pattern's size is how much it changes its anchor's ranges between any two
        directions (its peak-to-peak bias), a property of the antenna that does not
        depend on where the basis puts its zero (the constant part is the anchor's
        delay). With s = sin² el and r = √(c1² + c2²) the bias is c0 (s − 1/3) + (1 − s) h,
        h in [−r, r] over the azimuth; its extremes lie on the axis (2 c0/3) and on the
        horizon (−c0/3 ± r), so it spans max(|c0|, r) + r, at least every coefficient.
        Its weights are the gradient of that span."""
        c0, c1, c2 = deviation
        r = np.hypot(c1, c2)
        harmonic = np.array([c1, c2]) / r if r > 0 else np.zeros(2)
        if abs(c0) >= r:
            return np.array([np.sign(c0), *harmonic])
        return np.array([0.0, *(2 * harmonic)])

    def params(self) -> dict:
        return {"anchor": self.anchor, "coeffs_m": self.coeffs.tolist(), **self._window_params()}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if self.anchor not in world.anchor_positions:
            return
        bias = pattern_basis(*viewing_angles(tdoa, world, self.anchor)) @ self.coeffs
        tdoa.value += bias * _anchor_sign(tdoa, self.anchor) * self.active(tdoa.t)

    def largest(self, tdoa: TdoaBatch, world: World, rows: np.ndarray) -> dict:
        """How much the pattern changes this anchor's ranges over a flight's TDOA `rows`
        and where most (largest_on_links)."""
        def bias(tag_position, tag_rotation, position, rotation):
            return pattern_basis(*direction_angles(np.einsum("nji,nj->ni", rotation, tag_position - position))) \
                @ self.coeffs

        return largest_on_links(bias, tdoa, world, rows, [self.anchor])


class TagAntennaPattern(Effect):
    """Range bias depending on where each anchor is seen from the tag's own antenna, in
    the body frame (paper Section II.B: the tag's pose shapes the bias as much as the
    anchors'; the doughnut of its antenna and the airframe around it): `coeffs_m`
    weigh `pattern_basis` of the anchor's azimuth and elevation in the body frame, the
    same for every anchor. Its first order is a lever arm (catalog's `lever_arm`)."""

    name, stage = "tag_antenna_pattern", SIGNAL

    def __init__(self, coeffs_m=(0.0, 0.0, 0.0)):
        self.coeffs = _vec3(coeffs_m, "coeffs_m")

    def params(self) -> dict:
        return {"coeffs_m": self.coeffs.tolist()}

    def range_bias(self, position: np.ndarray, attitude: Rotation, world: World, ids: np.ndarray) -> np.ndarray:
        """Each range's bias from anchor ids[k], seen in the tag's body frame."""
        anchors, _ = world.anchor_poses(ids)
        return pattern_basis(*direction_angles(attitude.inv().apply(anchors - position))) @ self.coeffs

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        known = np.flatnonzero(world.known_pairs(tdoa.id_a, tdoa.id_b))
        if len(known):
            pose = tdoa.tag_position[known], tdoa.tag_rotation[known], world
            tdoa.value[known] += self.range_bias(*pose, tdoa.id_b[known]) - self.range_bias(*pose, tdoa.id_a[known])


@dataclass
class Region:
    """An axis-aligned box in the world frame."""

    low: np.ndarray
    high: np.ndarray

    @classmethod
    def from_json(cls, region) -> "Region":
        if region is None:
            return cls(np.full(3, -np.inf), np.full(3, np.inf))
        if not isinstance(region, dict) or set(region) != {"min", "max"}:
            raise ValueError(f"region must be {{'min': [x, y, z], 'max': [x, y, z]}}, got {region!r}")
        return cls(_vec3(region["min"], "region min"), _vec3(region["max"], "region max"))

    def to_json(self) -> dict | None:
        if not np.isfinite(self.low).any() and not np.isfinite(self.high).any():
            return None
        return {"min": self.low.tolist(), "max": self.high.tolist()}

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.all((points >= self.low) & (points <= self.high), axis=1)


class Nlos(_Windowed, Effect):
    """Non-line-of-sight to `anchor` while the tag is inside `region`: a `fraction` of
    those ranges gets a positive excess delay, exponential with mean `mean_excess_m`."""

    name, stage, bounds = "nlos", NOISE, {"mean_excess_m": 1.0}

    def __init__(self, anchor: int = 0, fraction: float = 1.0, mean_excess_m: float = 0.0, region=None,
                 during=None):
        self.anchor, self.fraction = _anchor_id(anchor), _finite(fraction, "fraction", FRACTION, _fraction)
        self.mean_excess = _finite(mean_excess_m, "mean_excess_m", "an excess delay >= 0", _non_negative)
        self.region = Region.from_json(region)
        self._set_during(during)

    def params(self) -> dict:
        return {"anchor": self.anchor, "fraction": self.fraction, "mean_excess_m": self.mean_excess,
                "region": self.region.to_json(), **self._window_params()}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        inside = self.region.contains(tdoa.tag_position) & self.active(tdoa.t)
        if rng is None:
            excess = np.full(len(tdoa.t), self.fraction * self.mean_excess)
        else:
            hit = rng.random(len(tdoa.t)) < self.fraction
            excess = np.where(hit, rng.exponential(max(self.mean_excess, 1e-12), len(tdoa.t)), 0.0)
        tdoa.value += excess * inside * _anchor_sign(tdoa, self.anchor)


class MultipathFloor(Effect):
    """Near the floor, reflections add error: below `height_m` every TDOA gets extra
    zero-mean noise of `std_m` (the tag's height is what matters, not the anchor).
    Optionally a second, higher step: below `upper_height_m` extra noise of
    `upper_std_m` too (independent: below both, their variances add)."""

    name, stage = "multipath_floor", NOISE

    def __init__(self, height_m: float = 0.3, std_m: float = 0.0, upper_height_m: float | None = None,
                 upper_std_m: float = 0.0):
        self.height = _finite(height_m, "height_m", HEIGHT, _positive)
        self.std = _finite(std_m, "std_m", "a standard deviation >= 0", _non_negative)
        self.upper_height = None if upper_height_m is None else _finite(
            upper_height_m, "upper_height_m", f"a height above height_m ({self.height} m)", lambda h: h > self.height)
        self.upper_std = _finite(upper_std_m, "upper_std_m", "a standard deviation >= 0", _non_negative)

    def params(self) -> dict:
        upper = {} if self.upper_height is None else {"upper_height_m": self.upper_height,
                                                        "upper_std_m": self.upper_std}
        return {"height_m": self.height, "std_m": self.std} | upper

    def low(self, tag_position: np.ndarray) -> np.ndarray:
        return tag_position[:, 2] < self.height

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        if rng is None:
            return
        tdoa.value += rng.normal(0.0, self.std, len(tdoa.t)) * self.low(tdoa.tag_position)
        if self.upper_height is not None:
            below = tdoa.tag_position[:, 2] < self.upper_height
            tdoa.value += rng.normal(0.0, self.upper_std, len(tdoa.t)) * below


def on_ground_weight(height: np.ndarray, below_m: float, fade_m: float = 0.0) -> np.ndarray:
    """How much of the floor's error a tag at `height` has: all of it below `below_m`,
    none above `below_m + fade_m`, linearly in between (0 fade: a step)."""
    if fade_m <= 0.0:
        return (height < below_m).astype(float)
    return np.clip((below_m + fade_m - height) / fade_m, 0.0, 1.0)


class OnGroundDelay(Effect):
    """With the drone on the floor (its body origin, the ground truth's position,
    below `height_m`), every range from anchor k reads `meters[k]` longer than in
    flight, fading out linearly over `fade_m` above that height: the floor lies in
    the direct paths, most to the anchors at its own height, and what arrives first
    has gone round (real flights: metres, docs/notebook/diagnosis.md). Keys are anchor ids;
    TDOA sees the values only relative to each other. The body, not the antenna: a
    lever arm fitted to a flight (decimetres on z, docs/notebook/diagnosis.md) would otherwise
    move where the floor begins."""

    name, stage = "on_ground_delay", SIGNAL

    def __init__(self, meters: dict | None = None, height_m: float = 0.2, fade_m: float = 0.0):
        self.height = _finite(height_m, "height_m", HEIGHT, _positive)
        self.fade = _finite(fade_m, "fade_m", "a width >= 0", lambda v: v >= 0.0)
        try:
            self.meters = {_anchor_id(int(k)): float(m) for k, m in (meters or {}).items()}
        except (TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"meters must map anchor ids to metres, got {meters!r}") from exc
        if not all(np.isfinite(m) for m in self.meters.values()):
            raise ValueError(f"meters must be finite, got {meters!r}")

    def params(self) -> dict:
        return {"height_m": self.height, "fade_m": self.fade,
                "meters": {str(k): m for k, m in sorted(self.meters.items())}}

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        body = tdoa.tag_position - tdoa.tag_rotation.apply(world.lever_arm)
        low = on_ground_weight(body[:, 2], self.height, self.fade)
        for anchor, meters in self.meters.items():
            tdoa.value += meters * low * _anchor_sign(tdoa, anchor)


class LearnedBias(Effect):
    """The pose-dependent TDOA bias that the bias network (paper Section III,
    `rig train`) learned from the shared flights, times `gain`: the network's
    prediction at the tag's true pose and the anchors' true poses. It stands for the
    bias of the antennas' patterns, of the airframe and of the room that the catalog's
    per-anchor effects do not carry, in a form that transfers to any trajectory.
    `network` is a `rig train` output (default: the shipped one)."""

    name, stage = "learned_bias", SIGNAL

    def __init__(self, gain: float = 1.0, network: str | None = None):
        path = paths.config_file(network) if network else DEFAULT_NETWORK
        if not path.is_file():
            raise ValueError(f"no bias network at {path} (write one with `rig train --out`)")
        self.gain, self.network, self.net = _finite(gain, "gain"), network, BiasNet.load(path)

    def params(self) -> dict:
        return {"gain": self.gain, **({"network": self.network} if self.network else {})}

    def bias(self, tdoa: TdoaBatch, world: World) -> np.ndarray:
        """The network's prediction for each sample (0 where an anchor is unknown)."""
        out = np.zeros(len(tdoa.t))
        known = np.flatnonzero(world.known_pairs(tdoa.id_a, tdoa.id_b))
        if not len(known):
            return out
        poses = [world.anchor_poses(ids[known]) for ids in (tdoa.id_a, tdoa.id_b)]
        features = native.features_batch(tdoa.tag_position[known], tdoa.tag_rotation[known].as_matrix(),
                                          *poses[0], *poses[1])
        out[known] = self.net.predict(features, tdoa.id_a[known], tdoa.id_b[known])
        return out

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        tdoa.value += self.gain * self.bias(tdoa, world)
