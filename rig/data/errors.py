"""The exceptions that mean bad input: the CLI reports them in one line (exit 2), never
as a traceback; and `read_json`, whose parse errors name their file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


class InputError(Exception):
    """Input the rig cannot use: a damaged or incomplete file, a value out of range."""


class LogFormatError(InputError):
    """The file is not a valid uSD event log (or not a complete one)."""


class SurveyError(InputError):
    """The survey file is missing, malformed or incomplete."""


class RecordingError(InputError):
    """A recording file is missing, unreadable or lacks required content."""


class ModelFileError(InputError):
    """A bias-correction model file is malformed, incomplete or holds non-finite values."""


class JsonFileError(InputError):
    """A JSON file (a configuration, metrics, a baseline) is not valid JSON."""


def read_json(path: Path) -> Any:
    """The JSON value in `path`; JsonFileError naming the file when it does not parse (a
    missing or unreadable file stays an OSError)."""
    text = Path(path).read_text()
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise JsonFileError(f"{path} is not valid JSON: {exc}") from exc


# What a command reports as bad input: the rig's own, and the standard library's for
# values it cannot parse and files it cannot read or write.
USER_ERRORS: tuple[type[Exception], ...] = (InputError, ValueError, OSError)
