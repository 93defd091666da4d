"""Anchor survey files and the anchor body frame.

A survey line is ``name,x,y,z`` in the motion-capture frame (metres):
``anchorAntK`` is the antenna centre of anchor K and ``anchorK_1..3`` are three
markers on its mount. ``uwbDatasetFrameN`` calibration points are ignored.

Anchor body frame (used everywhere in the rig, C estimator included):

* origin: the antenna centre;
* +z ("anchor up"): from the antenna centre towards marker 1, made orthogonal to
  the marker baseline. Marker 1 sits above the antenna on a floor anchor and below
  it on a ceiling anchor, so ceiling anchors, mounted upside down, get +z pointing
  down in the world;
* +y: along the mount's marker baseline, from marker 2 to marker 3;
* +x = y × z: normal to the mount's plane, the side the antenna faces.

The rotation is built from orthonormalised vectors and a cross product, so it is a
proper rotation (det +1) by construction; `anchor_rotation` checks it anyway.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.data.errors import SurveyError

_LINE_RE = re.compile(r"^anchor(?:Ant(?P<ant>\d+)|(?P<mk>\d+)_(?P<idx>[123]))$")


# The orientation from the markers differs in its last bit between CPUs (scipy's
# matrix-to-quaternion takes other SIMD paths), which changed the shipped default
# recording's bytes on another machine: rounded far below what markers surveyed to
# 0.1 mm can tell.
QUATERNION_DECIMALS = 12


@dataclass(frozen=True)
class Anchor:
    """A UWB anchor: antenna position (m) and orientation (quaternion x,y,z,w, anchor→world)."""

    id: int
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]

    @property
    def rotation(self):
        """The orientation as a scipy Rotation (scipy imported here: reading a survey, as
        every replay does, should not cost its import)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.quaternion)

    def to_json(self) -> dict:
        return {"id": self.id, "position": list(self.position), "quaternion": list(self.quaternion)}

    @classmethod
    def from_json(cls, obj: dict) -> "Anchor":
        return cls(int(obj["id"]), tuple(map(float, obj["position"])), tuple(map(float, obj["quaternion"])))


def anchor_rotation(antenna: np.ndarray, m1: np.ndarray, m2: np.ndarray, m3: np.ndarray) -> np.ndarray:
    """Rotation matrix anchor→world (columns are the anchor axes in the world frame)."""
    y = m3 - m2
    if np.linalg.norm(y) < 1e-6:
        raise SurveyError("markers 2 and 3 coincide: orientation undefined")
    y = y / np.linalg.norm(y)
    up = m1 - antenna
    z = up - np.dot(up, y) * y
    if np.linalg.norm(z) < 1e-6:
        raise SurveyError("marker 1 lies on the marker baseline: orientation undefined")
    z = z / np.linalg.norm(z)
    x = np.cross(y, z)
    rot = np.column_stack([x, y, z])
    if not np.isclose(np.linalg.det(rot), 1.0, atol=1e-9):
        raise SurveyError("anchor frame is not a proper rotation")
    return rot


def parse_survey(path: Path) -> list[Anchor]:
    """Read a survey file and return its anchors sorted by id."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SurveyError(f"cannot read survey {path}: {exc.strerror}") from exc
    antennas: dict[int, np.ndarray] = {}
    markers: dict[tuple[int, int], np.ndarray] = {}
    defined_at: dict[str, int] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        match = _LINE_RE.match(fields[0])
        if not match:
            continue  # calibration frame points and anything else are not anchors
        try:
            if len(fields) != 4:
                raise ValueError
            point = np.array([float(v) for v in fields[1:]])
        except ValueError:
            raise SurveyError(f"{path}:{lineno}: expected 'name,x,y,z', got {line!r}") from None
        if not np.all(np.isfinite(point)):
            raise SurveyError(f"{path}:{lineno}: non-finite coordinate in {line!r}")
        if fields[0] in defined_at:              # which of two positions is the anchor's? neither can be trusted
            raise SurveyError(f"{path}:{lineno}: {fields[0]} is defined again (first on line {defined_at[fields[0]]})")
        defined_at[fields[0]] = lineno
        if match["ant"] is not None:
            antennas[int(match["ant"])] = point
        else:
            markers[(int(match["mk"]), int(match["idx"]))] = point
    if not antennas:
        raise SurveyError(f"{path}: no anchorAntK lines found")
    from scipy.spatial.transform import Rotation

    anchors = []
    for aid in sorted(antennas):
        missing = [i for i in (1, 2, 3) if (aid, i) not in markers]
        if missing:
            raise SurveyError(f"{path}: anchor {aid} lacks marker(s) {missing}; orientation undefined")
        rot = anchor_rotation(antennas[aid], *(markers[(aid, i)] for i in (1, 2, 3)))
        quat = np.round(Rotation.from_matrix(rot).as_quat(), QUATERNION_DECIMALS)
        anchors.append(Anchor(aid, tuple(antennas[aid].tolist()), tuple(quat.tolist())))
    return anchors
