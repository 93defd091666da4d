"""Anchor surveys: the anchor body frame is a proper rotation; ceiling anchors are upside down."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.data.survey import SurveyError, anchor_rotation, parse_survey


@pytest.mark.parametrize("day", ["0422", "0425", "0426"])
def test_every_anchor_frame_is_a_proper_rotation(data_dir: Path, day: str) -> None:
    anchors = parse_survey(data_dir / "surveys" / f"anchor_{day}.txt")
    assert [a.id for a in anchors] == list(range(8))
    for anchor in anchors:
        rot = anchor.rotation.as_matrix()
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
        assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-9)
        up_in_world = rot[:, 2]
        if anchor.position[2] > 2.0:  # ceiling anchors are mounted upside down
            assert up_in_world[2] < -0.5, f"ceiling anchor {anchor.id} should point down"
        else:
            assert up_in_world[2] > 0.5, f"floor anchor {anchor.id} should point up"
        # +x is the side the antenna faces: into the arena (anchors sit in its corners).
        towards_centre = -np.array(anchor.position[:2]) / np.linalg.norm(anchor.position[:2])
        assert rot[:2, 0] @ towards_centre > 0.1


def test_anchor_frame_of_hand_built_markers() -> None:
    antenna = np.zeros(3)
    rot = anchor_rotation(antenna, m1=np.array([0.0, 0.0, 0.1]), m2=np.array([0.0, -0.1, -0.05]),
                          m3=np.array([0.0, 0.1, -0.05]))
    np.testing.assert_allclose(rot, np.eye(3), atol=1e-12)
    # The same mount upside down: z flips, y flips (markers swap sides), x stays.
    flipped = anchor_rotation(antenna, m1=np.array([0.0, 0.0, -0.1]), m2=np.array([0.0, 0.1, 0.05]),
                              m3=np.array([0.0, -0.1, 0.05]))
    np.testing.assert_allclose(flipped, np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_survey_errors_are_clear(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("anchorAnt0,0,0,0\nanchor0_1,0,0,1\n")
    with pytest.raises(SurveyError, match="lacks marker"):
        parse_survey(bad)
    bad.write_text("anchorAnt0,0,zero,0\n")
    with pytest.raises(SurveyError, match="expected 'name,x,y,z'"):
        parse_survey(bad)
    with pytest.raises(SurveyError, match="cannot read"):
        parse_survey(tmp_path / "missing.txt")
