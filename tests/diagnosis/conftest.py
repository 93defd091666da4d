"""Fixtures of the diagnosis tests: a survey, a simulated and a real flight, diagnosed once per module."""

from __future__ import annotations

from pathlib import Path

import pytest
from diagnosis_cases import REAL_FLIGHT, findings, sim_config

from rig.data.importer import load_any
from rig.diagnosis.diagnose import diagnose
from rig.sim.simulate import Predictor, simulate


@pytest.fixture(scope="module")
def survey(data_dir: Path) -> Path:
    return data_dir / "surveys" / "anchor_0425.txt"


@pytest.fixture(scope="module")
def sim_diagnosis(survey):
    return diagnose(simulate(sim_config(survey, [])))


@pytest.fixture(scope="module")
def sim_control(sim_diagnosis):
    return findings(sim_diagnosis)


@pytest.fixture(scope="module")
def real(data_dir: Path):
    rec = load_any(data_dir / "flights" / REAL_FLIGHT)
    return rec, Predictor(rec)


@pytest.fixture(scope="module")
def real_diagnosis(real):
    return diagnose(real[0])


@pytest.fixture(scope="module")
def real_control(real_diagnosis):
    return findings(real_diagnosis)
