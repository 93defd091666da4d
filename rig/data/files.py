"""The rig's own output files written whole: a temporary file beside the target, renamed
over it once complete, so a reader never sees half a file and a failed write (a full
disk, a signal) leaves what was there. Every command's JSON, model and report goes
through here."""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)


def write_text_whole(path: Path, text: str) -> None:
    """`text` into `path`, atomically; an OSError names the file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException as exc:        # interrupted too: no temporary left behind
        Path(temporary).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from exc
        raise
    log.info("wrote %s", path)


def finite_json(value):
    """`value` with every non-finite float as None: JSON has no NaN or infinity, and
    strict readers (jq, JavaScript, most CI tools) refuse Python's `NaN` and `Infinity`."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    return value


def write_json(path: Path, data: dict) -> None:
    """`data` as indented, key-sorted, strict JSON (what every command writes), whole:
    a figure that is not finite (the RMSE of a run whose estimate diverged) is null."""
    write_text_whole(path, json.dumps(finite_json(data), indent=2, sort_keys=True, allow_nan=False) + "\n")
