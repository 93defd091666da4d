"""The link bias (rig.sim.effects.link): one range bias per tag–anchor link from its
geometry, TDOA bias = link B's − link A's, checked against a second derivation."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rigtest import FULL_PRECISION, tdoa_poses
from scipy.spatial.transform import Rotation

from rig.sim.effects import LINK_BOUND_M, LINK_TERMS, calibrated_link_bias, make_effect
from rig.sim.simulate import Predictor, SimConfig, simulate

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
    with pytest.raises(ValueError, match="gain must be a finite number"):
        make_effect("link_bias", {"coeffs_m": COEFFS.tolist(), "gain": float("inf")})


def test_a_gain_scales_every_link_and_the_calibration_is_within_the_bounds(survey_0425: Path) -> None:
    cfg = SimConfig(trajectory="circle-sine", duration=8.0, survey=str(survey_0425), resolution=dict(FULL_PRECISION),
                    effects=[])
    clean = simulate(cfg)
    inside = tdoa_poses(clean)[0]
    added = {gain: (simulate(replace(cfg, effects=[{"effect": "link_bias", "params": {
        "coeffs_m": COEFFS.tolist(), "gain": gain}}])).tdoa.distance_diff - clean.tdoa.distance_diff)[inside]
        for gain in (1.0, -2.5)}
    np.testing.assert_allclose(added[-2.5], -2.5 * added[1.0], atol=5e-3)
    assert np.std(added[1.0]) > 0.05
    calibrated = calibrated_link_bias()
    assert len(calibrated) == len(LINK_TERMS) and 0.1 < max(map(abs, calibrated)) <= LINK_BOUND_M


def test_where_the_link_bias_is_largest_is_the_anchor_whose_links_vary_most(survey_0425: Path) -> None:
    """Each anchor's spread is the standard deviation of its links' β over the rows;
    the viewing angles are those of its most extreme tenth."""
    rec = simulate(SimConfig(trajectory="circle-sine", duration=8.0, survey=str(survey_0425),
                             resolution=dict(FULL_PRECISION), effects=[]))
    predictor = Predictor(rec)
    tdoa, world = predictor.tdoa([]), predictor.world([])
    effect = make_effect("link_bias", {"coeffs_m": COEFFS.tolist(), "gain": 1.5})
    where = effect.largest(tdoa, world, np.arange(len(tdoa.t)))
    spreads = {}
    for k in world.anchor_positions:
        rows = (tdoa.id_a == k) | (tdoa.id_b == k)
        position, rotation = world.anchor_poses(np.full(rows.sum(), k))
        beta = 1.5 * expected_link_bias(position[0], Rotation.from_matrix(rotation[0]), tdoa.tag_position[rows],
                                        tdoa.tag_rotation[rows])
        spreads[str(k)] = np.std(beta)
    assert where["spread_m"] == pytest.approx(spreads, abs=1e-3)
    top = max(spreads, key=spreads.get)
    assert where["anchors"] == [int(top)] and where["largest"]["anchor"] == int(top)
    low, high = where["largest"]["tag_elevation_deg"]
    assert -90 <= low <= high <= 90
