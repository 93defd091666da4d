"""Foxglove's well-known schemas, JSON-encoded, for what a run record shows in 3D: poses
in the world frame (`foxglove.PoseInFrame`), the anchors as a scene
(`foxglove.SceneUpdate`) and notes as log lines (`foxglove.Log`). Foxglove recognises a
channel by its schema's name; the schemas here are the JSON Schema subset of the
fields written (foxglove-sdk's `schemas/jsonschema` define them in full)."""

from __future__ import annotations

import numpy as np

FRAME = "world"                   # the motion-capture frame every position is in
ANCHOR_SIZE_M = 0.12              # the cube drawn at an anchor
LOG_LEVEL = {"info": 2, "warning": 3, "error": 4}     # foxglove.LogLevel

_NUMBER = {"type": "number"}
_TIME = {"type": "object", "title": "time", "properties": {"sec": {"type": "integer", "minimum": 0},
                                                            "nsec": {"type": "integer", "minimum": 0}}}
_VECTOR3 = {"type": "object", "title": "foxglove.Vector3", "properties": {k: _NUMBER for k in "xyz"}}
_QUATERNION = {"type": "object", "title": "foxglove.Quaternion", "properties": {k: _NUMBER for k in "xyzw"}}
_POSE = {"type": "object", "title": "foxglove.Pose", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_COLOR = {"type": "object", "title": "foxglove.Color", "properties": {k: _NUMBER for k in "rgba"}}

SCHEMAS = {
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame", "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object", "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE}},
    "foxglove.SceneUpdate": {
        "title": "foxglove.SceneUpdate", "description": "An update to the entities displayed in a 3D scene",
        "type": "object", "properties": {
            "deletions": {"type": "array", "items": {"type": "object"}},
            "entities": {"type": "array", "items": {
                "type": "object", "title": "foxglove.SceneEntity", "properties": {
                    "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
                    "lifetime": {"type": "object", "properties": _TIME["properties"]},
                    "frame_locked": {"type": "boolean"},
                    "cubes": {"type": "array", "items": {"type": "object", "properties": {
                        "pose": _POSE, "size": _VECTOR3, "color": _COLOR}}},
                    "texts": {"type": "array", "items": {"type": "object", "properties": {
                        "pose": _POSE, "billboard": {"type": "boolean"}, "font_size": _NUMBER,
                        "scale_invariant": {"type": "boolean"}, "color": _COLOR, "text": {"type": "string"}}}}}}}}},
    "foxglove.Log": {
        "title": "foxglove.Log", "description": "A log message", "type": "object", "properties": {
            "timestamp": _TIME, "level": {"type": "integer", "description": "1 debug, 2 info, 3 warning, 4 error"},
            "message": {"type": "string"}, "name": {"type": "string"}, "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0}}},
}


def time(t: float) -> dict:
    """A foxglove.Time of seconds on the recording's clock (clamped at 0: the type is unsigned)."""
    nanoseconds = max(0, round(t * 1e9))
    return {"sec": nanoseconds // 1_000_000_000, "nsec": nanoseconds % 1_000_000_000}


def pose(position, orientation) -> dict:
    return {"position": {k: float(v) for k, v in zip("xyz", position)},
            "orientation": {k: float(v) for k, v in zip("xyzw", orientation)}}


def pose_in_frame(t: float, position, orientation) -> dict:
    return {"timestamp": time(t), "frame_id": FRAME, "pose": pose(position, orientation)}


def anchors_scene(t: float, anchors) -> dict:
    """Each anchor (`survey.Anchor`) as a cube at its pose with its id above it, for ever."""
    entities = []
    for a in anchors:
        quaternion = np.asarray(a.quaternion, float) / np.linalg.norm(a.quaternion)
        label = (a.position[0], a.position[1], a.position[2] + 1.5 * ANCHOR_SIZE_M)
        entities.append({
            "timestamp": time(t), "frame_id": FRAME, "id": f"anchor{a.id}", "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": True,
            "cubes": [{"pose": pose(a.position, quaternion), "size": {k: ANCHOR_SIZE_M for k in "xyz"},
                       "color": {"r": 1.0, "g": 0.55, "b": 0.0, "a": 1.0}}],
            "texts": [{"pose": pose(label, (0, 0, 0, 1)), "billboard": True, "font_size": 14.0, "scale_invariant": True,
                       "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}, "text": f"anchor {a.id}"}]})
    return {"deletions": [], "entities": entities}


def log(t: float, level: str, name: str, message: str) -> dict:
    return {"timestamp": time(t), "level": LOG_LEVEL[level], "message": message, "name": name, "file": "", "line": 0}
