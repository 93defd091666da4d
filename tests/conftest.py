"""Fixtures every test may use: the real data directory, the default recording, a survey."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

from rig.data import paths

# The recordings' binary cache (rig.data.cache) in a directory of this session's own,
# inherited by every `rig` the tests start: no test reads what another run left.
os.environ["UWB_RIG_CACHE"] = tempfile.mkdtemp(prefix="uwb-rig-cache-")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    path = paths.data_dir()
    assert (path / "flights").is_dir(), f"real flights not found at {path}: set UWB_RIG_DATA"
    return path


@pytest.fixture(scope="session")
def default_rec():
    """The shipped default recording."""
    from rig.data.importer import load_any

    return load_any(paths.default_recording())


@pytest.fixture(scope="session")
def survey_0425(data_dir: Path) -> Path:
    return data_dir / "surveys" / "anchor_0425.txt"
