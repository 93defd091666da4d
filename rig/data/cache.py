"""A binary cache of recordings read from MCAP or imported from flight logs: decoding
130 000 JSON messages, or a log's binary events, takes a second or more, loading their
arrays back takes milliseconds. An entry is keyed by the resolved path, size and
modification time of every file it was made from (a log and its survey), so a changed
or damaged file is read afresh; only files read whole (not salvaged) are cached. The
cache is an optimisation only: any failure to read or write it falls back to the files.

Location: `$UWB_RIG_CACHE`, else `$XDG_CACHE_HOME/uwb-rig`, else `~/.cache/uwb-rig`;
`UWB_RIG_CACHE=off` turns it off."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import tempfile
from dataclasses import fields
from pathlib import Path

import numpy as np

from rig.data.errors import RecordingError
from rig.data.recording import PoseSeries, Recording, TdoaSeries, Vec3Series, check_anchor_set, read_recording_checked
from rig.data.survey import Anchor

log = logging.getLogger(__name__)

FORMAT = 1                     # bump when Recording's arrays change
SERIES = {"accel": Vec3Series, "gyro": Vec3Series, "tdoa": TdoaSeries, "truth": PoseSeries}


def cache_dir() -> Path | None:
    setting = os.environ.get("UWB_RIG_CACHE")
    if setting == "off":
        return None
    if setting:
        return Path(setting)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "uwb-rig"


def _entry(sources: list[Path]) -> Path | None:
    root = cache_dir()
    if root is None:
        return None
    key = str(FORMAT)
    for path in sources:
        stat = path.stat()
        key += f":{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}"
    return root / "recordings" / (hashlib.sha256(key.encode()).hexdigest()[:32] + ".npz")


def read_cached(path: Path, strict: bool = False) -> Recording:
    """The recording at `path`: from the cache if it holds this very file, else read
    from it (and cached when it was read whole). `strict`: a damaged or unfinished
    file is an error, not the part of it before the damage."""
    rec = load(path)
    if rec is not None:
        check_anchor_set(path, rec.anchors)          # an entry cached before the check existed
    else:
        rec, whole = read_recording_checked(path)
        if whole:
            store(path, rec=rec)
        elif strict:
            raise RecordingError(f"{path} is damaged or unfinished (--strict: not used in part)")
    return rec


def load(*sources: Path) -> Recording | None:
    """The cached recording made from `sources`, or None."""
    try:
        entry = _entry(list(sources))
        if entry is None or not entry.is_file():
            return None
        with np.load(entry) as data:
            series = {name: cls(*(data[f"{name}.{f.name}"] for f in fields(cls))) for name, cls in SERIES.items()}
            extra = json.loads(str(data["extra"]))
        anchors = [Anchor(a["id"], tuple(a["position"]), tuple(a["quaternion"])) for a in extra["anchors"]]
        return Recording(**series, anchors=anchors, metadata=extra["metadata"])
    except Exception as exc:  # a damaged entry: the files are the truth
        log.debug("recording cache for %s unusable: %s", sources[0], exc)
        return None


def store(*sources: Path, rec: Recording) -> None:
    """Cache `rec`, read whole from `sources` (atomically; failures only logged: a full
    disk or a read-only home must not fail the job)."""
    tmp = None
    try:
        entry = _entry(list(sources))
        if entry is None:
            return
        entry.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f"{name}.{f.name}": getattr(getattr(rec, name), f.name)
                  for name, cls in SERIES.items() for f in fields(cls)}
        extra = {"anchors": [a.to_json() for a in rec.anchors], "metadata": rec.metadata}
        fd, tmp = tempfile.mkstemp(dir=entry.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as stream:
            np.savez(stream, **arrays, extra=np.array(json.dumps(extra)))
        os.replace(tmp, entry)
        tmp = None
    except Exception as exc:
        log.debug("could not cache %s: %s", sources[0], exc)
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
