"""benchmarks/delay_share.py on made-up reports: each delay as reported and without
the lever arm's share, against the report's own per-anchor mismatch, about medians."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from rigtest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import delay_share  # noqa: E402  - the benchmark's reading of the reports


def _report(delays: dict[int, tuple[float, float]], direct: dict[int, float]) -> dict:
    """Delays as {anchor: (meters, lever arm's share)}, the direct measure per anchor."""
    findings = [{"effect": "anchor_delay", "params": {"anchor": k, "meters": m}, "lever_arm_share_m": s}
                for k, (m, s) in delays.items()]
    return {"findings": findings[:2], "not_explained": findings[2:],
            "mismatch": {"tdoa_per_anchor_m": {str(k): v for k, v in direct.items()}}}


def test_a_delay_without_its_lever_arm_share_is_compared_with_the_direct_measure() -> None:
    report = _report({0: (0.5, 0.45), 1: (-0.4, -0.42), 2: (0.0, 0.0)}, {0: 0.05, 1: 0.02, 2: 0.0})
    figures = delay_share.flight_figures(report)
    assert figures["anchors"] == 3 and figures["lever_arm_beyond_bound"]
    assert figures["largest_reported_m"] == pytest.approx(0.5)
    assert figures["largest_without_m"] == pytest.approx(0.03)                # 0.05, 0.02, 0 about 0.02
    assert figures["rms_without_vs_direct_m"] == pytest.approx(0.0, abs=1e-12)
    assert figures["rms_reported_vs_direct_m"] > 0.3
    alone = _report({0: (0.1, 0.0)}, {0: 0.1})
    assert delay_share.flight_figures(alone) is None                    # one delay says nothing relative


def test_the_benchmark_writes_its_figures_and_refuses_an_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "f1").mkdir()
    (tmp_path / "f1" / "report.json").write_text(json.dumps(_report({0: (0.3, 0.3), 1: (-0.3, -0.3)},
                                                                    {0: 0.0, 1: 0.0})))
    command = [sys.executable, str(ROOT / "benchmarks" / "delay_share.py"), "--reports", str(tmp_path),
               "--json", str(tmp_path / "out.json")]
    subprocess.run(command, check=True, capture_output=True, text=True)
    written = json.loads((tmp_path / "out.json").read_text())
    assert written["summary"]["flights"] == 1 and written["summary"]["rms_without_vs_direct_m"] == pytest.approx(0.0)
    refused = subprocess.run([*command[:2], "--reports", str(tmp_path / "none")], capture_output=True, text=True)
    assert refused.returncode == 2 and "run benchmarks/diagnosis.py first" in refused.stderr
