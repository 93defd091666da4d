"""The link bias (rig.sim.effects.link): one range bias per tag–anchor link from its
geometry, TDOA bias = link B's − link A's, checked against a second derivation."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import FULL_PRECISION, tdoa_poses
from scipy.spatial.transform import Rotation

from rig.sim.effects import LINK_TERMS, make_effect
from rig.sim.simulate import SimConfig, simulate

COEFFS = np.array([-0.45, 0.05, 0.2, -0.2, -0.4, 0.1])


def expected_link_bias(anchor_pos: np.ndarray, anchor_rot: Rotation, position: np.ndarray, body: Rotation
                       ) -> np.ndarray:
    """β of each link in Cartesian form: u the unit vector from the anchor to the tag in
    the anchor's frame, v from the tag to the anchor in the body frame."""
    u = anchor_rot.inv().apply(position - anchor_pos)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = body.inv().apply(anchor_pos - position)
    distance = np.linalg.norm(v, axis=1)
    v /= distance[:, None]
    basis = np.stack([u[:, 2] ** 2 - 1 / 3, u[:, 0] ** 2 - u[:, 1] ** 2, 2 * u[:, 0] * u[:, 1],
                      v[:, 2], v[:, 2] ** 2 - 1 / 3, np.log(distance / 3.0)], axis=1)
    return basis @ COEFFS


def test_a_tdoa_carries_link_bs_bias_minus_link_as(survey_0425: Path) -> None:
    cfg = SimConfig(trajectory="circle-sine", duration=8.0, survey=str(survey_0425),
                    resolution=dict(FULL_PRECISION),
                    effects=[{"effect": "link_bias", "params": {"coeffs_m": COEFFS.tolist()}}])
    biased, clean = simulate(cfg), simulate(replace(cfg, effects=[]))
    tdoa = biased.tdoa
    inside, t, body, position = tdoa_poses(biased)
    anchors = {a.id: a for a in biased.anchors}

    def link(ids: np.ndarray) -> np.ndarray:
        out = np.zeros(len(ids))
        for k in np.unique(ids):
            rows = ids == k
            out[rows] = expected_link_bias(np.array(anchors[int(k)].position), anchors[int(k)].rotation,
                                           position[rows], body[rows])
        return out

    expected = link(tdoa.id_b[inside]) - link(tdoa.id_a[inside])
    added = (tdoa.distance_diff - clean.tdoa.distance_diff)[inside]
    np.testing.assert_allclose(added, expected, atol=2e-3)
    assert np.std(expected) > 0.05


def test_the_link_bias_refuses_a_wrong_number_of_coefficients_or_nan() -> None:
    with pytest.raises(ValueError, match=f"coeffs_m must hold {len(LINK_TERMS)} numbers"):
        make_effect("link_bias", {"coeffs_m": [0.1, 0.2]})
    with pytest.raises(ValueError, match=r"coeffs_m\[2\] must be a finite number"):
        make_effect("link_bias", {"coeffs_m": [0.0, 0.0, float("nan"), 0.0, 0.0, 0.0]})
