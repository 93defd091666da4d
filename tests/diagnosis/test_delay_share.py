"""benchmarks/delay_share.py on made-up reports: each flight's delays against the
report's own per-anchor mismatch before modelling, both about their medians."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rigtest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import delay_share  # noqa: E402  - the benchmark's reading of the reports


def _report(delays: dict[int, float], direct: dict[int, float]) -> dict:
    findings = [{"effect": "anchor_delay", "params": {"anchor": k, "meters": m}} for k, m in delays.items()]
    return {"findings": findings[:2], "not_explained": findings[2:],
            "mismatch": {"tdoa_per_anchor_m": {str(k): v for k, v in direct.items()}}}


def test_delays_are_compared_with_the_direct_measure_about_their_medians() -> None:
    agree = delay_share.flight_figures(_report({0: 0.55, 1: 0.52, 2: 0.50}, {0: 0.05, 1: 0.02, 2: 0.0}))
    assert agree["anchors"] == 3 and agree["rms_vs_direct_m"] == pytest.approx(0.0, abs=1e-12)
    assert agree["largest_m"] == pytest.approx(0.03)                     # 0.55, 0.52, 0.50 about 0.52
    apart = delay_share.flight_figures(_report({0: 0.5, 1: -0.4, 2: 0.0}, {0: 0.0, 1: 0.0, 2: 0.0}))
    assert apart["rms_vs_direct_m"] == pytest.approx(np.sqrt((0.25 + 0.16) / 3))
    assert delay_share.flight_figures(_report({0: 0.1}, {0: 0.1})) is None      # one delay says nothing relative


def test_the_benchmark_writes_its_figures_and_refuses_an_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "f1").mkdir()
    (tmp_path / "f1" / "report.json").write_text(json.dumps(_report({0: 0.3, 1: -0.3}, {0: 0.0, 1: 0.0})))
    command = [sys.executable, str(ROOT / "benchmarks" / "delay_share.py"), "--reports", str(tmp_path),
               "--json", str(tmp_path / "out.json")]
    subprocess.run(command, check=True, capture_output=True, text=True)
    written = json.loads((tmp_path / "out.json").read_text())
    assert written["summary"]["flights"] == 1 and written["summary"]["rms_vs_direct_m"] == pytest.approx(0.3)
    refused = subprocess.run([*command[:2], "--reports", str(tmp_path / "none")], capture_output=True, text=True)
    assert refused.returncode == 2 and "run benchmarks/diagnosis.py first" in refused.stderr
