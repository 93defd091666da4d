"""benchmarks/richer_sizes.py on made-up reports: displacement sizes from findings and
not explained alike, and the richer estimates beyond bound counted by effect."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from rigtest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import richer_sizes  # noqa: E402  - the benchmark's reading of the reports


def _report() -> dict:
    moved = {"effect": "anchor_position", "params": {"anchor": 1, "offset_m": [0.3, 0.0, 0.4]}}
    far = {"effect": "anchor_position", "params": {"anchor": 2, "offset_m": [2.0, 0.0, 0.0]},
           "beyond_physical_bound": True, "where": {"anchors": [2], "spread_m": {"2": 0.15}}}
    plausible = {"effect": "anchor_delay", "params": {"anchor": 5, "meters": -0.07}, "beyond_physical_bound": True}
    pattern = {"effect": "antenna_pattern", "params": {"anchor": 2, "coeffs_m": [3.0, 0.0, 0.0]},
               "beyond_physical_bound": True}
    lever = {"effect": "lever_arm", "params": {"offset_m": [0.0, 0.0, 0.5]}, "beyond_physical_bound": True}
    return {"findings": [moved], "not_explained": [far, pattern, lever, plausible],
            "channels": {"tdoa": {"fit_after": 0.25}}}


def test_sizes_and_counts_cover_findings_and_not_explained_of_the_richer_terms_only() -> None:
    figures = richer_sizes.flight_figures(_report())
    assert figures["displacement_sizes_m"] == pytest.approx([0.5, 2.0])
    assert figures["range_spreads_m"] == {"anchor_position": [0.15], "antenna_pattern": []}   # where reports give it
    assert figures["beyond_bound"] == {"anchor_position": 1, "antenna_pattern": 1, "link_bias": 0}
    assert figures["not_explained_within_bound"] == {"anchor_delay": 1}       # the lever arm's 0.5 m is not
    total = richer_sizes.summary({"a": figures, "b": figures})
    assert total["displacements"] == 4 and total["displacement_median_m"] == pytest.approx(1.25)
    assert total["beyond_bound_total"] == 4 and total["named"]["anchor_position"] == 4
    assert total["not_explained_within_bound"] == {"anchor_delay": 2}
    assert total["tdoa_fit_after_median_m"] == pytest.approx(0.25)
    assert total["range_spread_median_m"] == {"anchor_position": pytest.approx(0.15)}


def test_the_benchmark_writes_its_figures_and_refuses_an_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "f1").mkdir()
    (tmp_path / "f1" / "report.json").write_text(json.dumps(_report()))
    command = [sys.executable, str(ROOT / "benchmarks" / "richer_sizes.py"), "--reports", str(tmp_path),
               "--json", str(tmp_path / "out.json")]
    subprocess.run(command, check=True, capture_output=True, text=True)
    written = json.loads((tmp_path / "out.json").read_text())
    assert written["summary"]["beyond_bound_total"] == 2
    refused = subprocess.run([*command[:2], "--reports", str(tmp_path / "none")], capture_output=True, text=True)
    assert refused.returncode == 2 and "run benchmarks/diagnosis.py first" in refused.stderr
