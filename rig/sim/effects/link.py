"""The link bias: the range bias of one tag–anchor link as a function of that link's
geometry, the same for every link (anchors of one type, one tag), so that a TDOA's
bias is β(link B) − β(link A) (paper Section II.B; docs/reference/diagnosis.md).

β is linear in six coefficients (`LINK_TERMS`), each weighing one bounded function of
the link's geometry:

- the anchor's antenna: the tag's direction in the anchor's own frame, through the
  second-order real spherical harmonics (`pattern_basis`: the first order is a
  displaced antenna, the zeroth a delay — both elsewhere in the catalog);
- the tag's antenna and the airframe around it: the anchor's elevation in the tag's
  body frame, sin(el) (the airframe below the antenna makes the pattern asymmetric
  up and down) and sin²(el) − 1/3 (the doughnut). Only the elevation: it does not
  depend on the heading, which the onboard estimator cannot observe;
- the received power: ln(distance / `REFERENCE_DISTANCE_M`), the receiver's range
  bias growing with the path loss.

Per-anchor parts stay in their own effects: the delay (`anchor_delay`) and a pattern
deviating from the shared one (`antenna_pattern`). `rig calibrate` fits all of them
to flights with ground truth; the coefficients it fitted to the 35 shared flights
ship as `calibrated_link_bias()` (`gain` scales them: one flight cannot tell the six
apart, but it can tell how strongly it shows their calibrated pattern).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rig.sim.effects.base import SIGNAL, Effect, TdoaBatch, World, _finite

LINK_TERMS = ("anchor_zonal", "anchor_cos2az", "anchor_sin2az", "tag_sin_el", "tag_zonal", "log_distance")
REFERENCE_DISTANCE_M = 3.0
# The largest coefficient a physical link can have (m). Each function above spans at
# most about one unit over the elevations and distances of a room, so a coefficient
# is about the largest bias difference it makes between two links.
LINK_BOUND_M = 1.5
CALIBRATION_FILE = Path(__file__).resolve().parent / "link_bias.json"     # `rig calibrate` on the shared flights


@cache
def calibrated_link_bias() -> tuple[float, ...]:
    """The `LINK_TERMS` coefficients fitted to the 35 shared flights (CALIBRATION_FILE,
    written by `make link-bias`)."""
    effects = json.loads(CALIBRATION_FILE.read_text())["effects"]
    return tuple(float(v) for v in next(e for e in effects if e["effect"] == "link_bias")["params"]["coeffs_m"])


def direction_angles(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of direction vectors given in some frame."""
    norm = np.linalg.norm(local, axis=1)
    return np.arctan2(local[:, 1], local[:, 0]), np.arcsin(np.clip(local[:, 2] / np.maximum(norm, 1e-12), -1.0, 1.0))


def pattern_basis(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """The antenna-pattern bias terms: the second-order real spherical harmonics that do
    not look like a displaced antenna (first order) or a delay (constant):
    sin²(el) − 1/3, cos²(el)·cos(2 az), cos²(el)·sin(2 az)."""
    c2 = np.cos(elevation) ** 2
    return np.stack([np.sin(elevation) ** 2 - 1.0 / 3.0, c2 * np.cos(2 * azimuth), c2 * np.sin(2 * azimuth)], axis=1)


def link_basis(tag_position: np.ndarray, tag_rotation: Rotation, anchor_position: np.ndarray,
               anchor_rotation: np.ndarray) -> np.ndarray:
    """(n, 6) values of the `LINK_TERMS` functions for n links; `anchor_rotation`: (n, 3, 3)
    matrices, anchor frame → world."""
    to_anchor = anchor_position - tag_position
    anchor_view = pattern_basis(*direction_angles(np.einsum("nji,nj->ni", anchor_rotation, -to_anchor)))
    _, tag_elevation = direction_angles(tag_rotation.inv().apply(to_anchor))
    s = np.sin(tag_elevation)
    distance = np.maximum(np.linalg.norm(to_anchor, axis=1), 1e-3)
    return np.column_stack([anchor_view, s, s ** 2 - 1.0 / 3.0, np.log(distance / REFERENCE_DISTANCE_M)])


def tdoa_basis(tdoa: TdoaBatch, world: World, rows: np.ndarray) -> np.ndarray:
    """(len(rows), 6): each TDOA's basis, link B's minus link A's (known anchors only)."""
    position, rotation = tdoa.tag_position[rows], tdoa.tag_rotation[rows]
    (a_pos, a_rot), (b_pos, b_rot) = world.anchor_poses(tdoa.id_a[rows]), world.anchor_poses(tdoa.id_b[rows])
    return link_basis(position, rotation, b_pos, b_rot) - link_basis(position, rotation, a_pos, a_rot)


def largest_on_links(link_values, tdoa: TdoaBatch, world: World, rows: np.ndarray, anchors: list[int]) -> dict:
    """Where a range bias of the links varies most over a flight's TDOA `rows`:
    `link_values`(tag positions, tag rotations, anchor positions, anchor rotation
    matrices) gives it for n links. Each of `anchors`' spread (standard deviation of
    the bias over its links; the mean is a delay, which TDOA reads as one), and for the
    anchor of the largest, the viewing angles at its most extreme tenth: the tag seen
    from the anchor (azimuth, elevation in the anchor's frame) and the anchor seen from
    the tag (elevation, body frame), and whether its ranges read long or short there."""
    spread, extreme = {}, {}
    for k in anchors:
        on = rows[(tdoa.id_a[rows] == k) | (tdoa.id_b[rows] == k)]
        if len(on) < 10 or k not in world.anchor_positions:
            continue
        position, rotation = world.anchor_poses(np.full(len(on), k))
        beta = link_values(tdoa.tag_position[on], tdoa.tag_rotation[on], position, rotation)
        spread[k] = float(np.std(beta))
        far = np.abs(beta - beta.mean()) >= np.quantile(np.abs(beta - beta.mean()), 0.9)
        to_anchor = position[far] - tdoa.tag_position[on][far]
        az, el = direction_angles(np.einsum("nji,nj->ni", rotation[far], -to_anchor))
        _, tag_el = direction_angles(tdoa.tag_rotation[on][far].inv().apply(to_anchor))
        extreme[k] = {"tag_azimuth_deg": _degrees(az), "tag_elevation_deg": _degrees(el),
                      "anchor_elevation_in_body_deg": _degrees(tag_el),
                      "sign": "long" if np.mean(beta[far] - beta.mean()) > 0 else "short"}
    if not spread:
        return {}
    top = max(spread, key=spread.get)
    return {"anchors": [top], "spread_m": {str(k): round(v, 4) for k, v in spread.items()},
            "largest": {"anchor": top, **extreme[top]}}


class LinkBias(Effect):
    """Every link's range bias from its geometry, shared by all links: `gain` × `coeffs_m`
    weigh the `LINK_TERMS` functions (see the module); a TDOA's bias is link B's minus
    link A's."""

    name, stage = "link_bias", SIGNAL

    def __init__(self, coeffs_m=(0.0,) * len(LINK_TERMS), gain: float = 1.0):
        values = np.asarray(coeffs_m, dtype=float).reshape(-1)
        if values.shape != (len(LINK_TERMS),):
            raise ValueError(f"coeffs_m must hold {len(LINK_TERMS)} numbers ({', '.join(LINK_TERMS)}), "
                             f"got {coeffs_m!r}")
        self.coeffs = np.array([_finite(v, f"coeffs_m[{k}]") for k, v in enumerate(values)])
        self.gain = _finite(gain, "gain")

    def params(self) -> dict:
        return {"coeffs_m": self.coeffs.tolist(), "gain": self.gain}

    def beyond_bound(self) -> list[str]:
        """Each term's size (gain × coefficient) is at most LINK_BOUND_M, and the gain
        does not turn the pattern inside out (it is not negative)."""
        size = float(np.max(np.abs(self.gain * self.coeffs))) if len(self.coeffs) else 0.0
        return ([f"gain × coeffs_m up to {size:g} m (bound {LINK_BOUND_M:g})"] if size > LINK_BOUND_M else []) + \
            ([f"gain {self.gain:g} (bound: not negative)"] if self.gain < 0 else [])

    def link_values(self, tag_position: np.ndarray, tag_rotation: Rotation, anchor_position: np.ndarray,
                    anchor_rotation: np.ndarray) -> np.ndarray:
        """β of n links (metres)."""
        return link_basis(tag_position, tag_rotation, anchor_position, anchor_rotation) @ (self.gain * self.coeffs)

    def largest(self, tdoa: TdoaBatch, world: World, rows: np.ndarray) -> dict:
        """Where this bias varies most over a flight's TDOA `rows` (largest_on_links,
        over every anchor)."""
        return largest_on_links(self.link_values, tdoa, world, rows, sorted(world.anchor_positions))

    def apply_tdoa(self, tdoa: TdoaBatch, world: World, rng: np.random.Generator | None) -> None:
        known = np.flatnonzero(world.known_pairs(tdoa.id_a, tdoa.id_b))
        if len(known):
            tdoa.value[known] += tdoa_basis(tdoa, world, known) @ (self.gain * self.coeffs)


def _degrees(angles: np.ndarray) -> list[float]:
    """The 10th and 90th percentiles of `angles` (rad), in degrees: a range of angles,
    not one (azimuths near ±180° are rare here: anchors face the room)."""
    return np.round(np.degrees(np.percentile(angles, [10, 90])), 1).tolist()
