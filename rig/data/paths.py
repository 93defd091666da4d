"""Where the rig finds things: the shared real data and the shipped recordings.

Real flights are never copied into the project; `UWB_RIG_DATA` points at them and
defaults to ``../shared/data/util`` next to the checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_DATA_DIR = PROJECT_ROOT.parent / "shared" / "data" / "util"
RECORDINGS_DIR = PROJECT_ROOT / "recordings"
BENCH_BASELINE = PROJECT_ROOT / "benchmarks" / "baseline.json"   # rig bench's committed figures
DEFAULT_SURVEY_NAME = "anchor_0425.txt"
SHIPPED_BIAS_NET = PROJECT_ROOT / "rig" / "bias" / "models" / "bias_net.json"   # the estimator's default correction


def data_dir() -> Path:
    return Path(os.environ.get("UWB_RIG_DATA", DEFAULT_DATA_DIR))


def flights() -> list[Path]:
    """All real flight logs, sorted by name."""
    return sorted(p for p in (data_dir() / "flights").iterdir() if p.is_file())


def survey_for(flight: Path) -> Path:
    """The survey of a flight's day: logs are named MMDD-..., surveys anchor_MMDD.txt,
    looked for in the flight's own data tree (FLIGHTS/../surveys: a copy of the data
    with altered flights keeps its surveys) and then in the shared data."""
    name = f"anchor_{Path(flight).name.split('-')[0]}.txt"
    beside = Path(flight).resolve().parent.parent / "surveys" / name
    return beside if beside.is_file() else data_dir() / "surveys" / name


def config_file(given: str | Path, *elsewhere: Path) -> Path:
    """A file a configuration names: as given (from the working directory), else from the
    project root (the shipped configurations name their files from there), else in each
    of `elsewhere`; the path as given when none exists (reading it then says so). So a
    configuration works from any directory."""
    path = Path(given)
    candidates = [path] if path.is_absolute() else [path, PROJECT_ROOT / path, *elsewhere]
    return next((p for p in candidates if p.is_file()), path)


def config_survey(given: str | Path) -> Path:
    """A survey a configuration names (`config_file`), else the survey of that name in
    the shared data (`UWB_RIG_DATA`, which may be elsewhere than the configuration said)."""
    return config_file(given, data_dir() / "surveys" / Path(given).name)


def default_survey() -> Path:
    return data_dir() / "surveys" / DEFAULT_SURVEY_NAME


def default_recording() -> Path:
    return RECORDINGS_DIR / "default.mcap"
