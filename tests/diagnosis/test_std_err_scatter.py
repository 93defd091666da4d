"""benchmarks/std_err_scatter.py on two made-up runs: it reads each untouched flight's
lever arm and delays wherever its report lists them, groups them by day, and compares
the standard errors of two runs of the same cases."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from rigtest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import std_err_scatter  # noqa: E402  - the benchmark's reading of the findings


def _listed(lever_m: float, delay_m: float, error: float) -> dict:
    lever = {"effect": "lever_arm", "params": {"offset_m": [lever_m, 0.0, 0.0]},
             "std_err": {"offset_m": [error, error, error]}, "beyond_physical_bound": True}
    delay = {"effect": "anchor_delay", "anchors": [3], "params": {"anchor": 3, "meters": delay_m},
             "std_err": {"meters": error}}
    accel = {"effect": "imu_accel_bias", "params": {"bias_mps2": [0.1, 0, 0]}, "std_err": {"bias_mps2": [1, 1, 1]}}
    return {"findings": [lever, accel], "unnamed": [delay], "in_place": []}


def _run(path: Path, error: float) -> Path:
    flights = {"0426-traj1": (0.1, 0.2), "0426-traj2": (0.3, 0.1), "0426-traj3": (0.2, 0.3), "0425-traj1": (0.9, 0.9)}
    data = {f"{flight}|control": [_listed(lever, delay, error), None, None, None]
            for flight, (lever, delay) in flights.items()}
    data["0426-traj1|lever_arm"] = [_listed(5.0, 5.0, error), None, None, None]    # injected: not read
    path.write_text(json.dumps(data))
    return path


def test_a_days_scatter_is_read_from_its_untouched_flights(tmp_path: Path) -> None:
    days = std_err_scatter.by_day([_run(tmp_path / "a.json", 0.05)])
    assert sorted(days) == ["0425", "0426"]
    values, errors = np.array(days["0426"]["lever_arm x"]).T
    assert values.tolist() == [0.1, 0.3, 0.2] and errors.tolist() == [0.05] * 3
    assert [v for v, _ in days["0426"]["delay 3"]] == [0.2, 0.1, 0.3]
    assert not any(q.startswith("imu") for q in days["0426"])


def test_the_change_of_standard_errors_between_two_runs(tmp_path: Path) -> None:
    ratios = std_err_scatter.std_err_change([_run(tmp_path / "after.json", 0.2)], [_run(tmp_path / "before.json", 0.05)])
    assert sorted(ratios) == ["anchor_delay", "lever_arm"]
    assert ratios["lever_arm"] == pytest.approx([4.0] * 12) and ratios["anchor_delay"] == pytest.approx([4.0] * 4)


def test_fits_beyond_bound_are_counted_by_how_many_standard_errors(tmp_path: Path) -> None:
    """Lever arms of 0.1, 0.3, 0.2 and 0.9 m, each ± 0.05, against the airframe's 0.15 m:
    three beyond it, two by more than two standard errors (0.3 and 0.9)."""
    counts = std_err_scatter.beyond_counts([_run(tmp_path / "a.json", 0.05)])
    assert counts == {"lever_arm": {"beyond": 3, "by_two_std_errs": 2}}
