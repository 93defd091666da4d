"""`rig bench` catches a slowdown: a baseline measured on the firmware as built, then the
same estimator sources compiled without optimisation (a real, injected slowdown) must
fail the comparison, while the unchanged firmware passes it; and figures of another
recording are refused, not compared."""

from __future__ import annotations

import json
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
from rigtest import run_rig

from rig.data import paths
from rig.estimator import native

pytestmark = pytest.mark.slow        # left out of `make test-fast`


def _slow_firmware() -> Path:
    subprocess.run(["make", "-s", "-C", str(native.ESTIMATOR_DIR), "BUILD=build/slow", "OPT=-O0", "firmware"],
                   check=True, capture_output=True)
    return native.ESTIMATOR_DIR / "build" / "slow" / "stm32f405" / "firmware.elf"


def test_bench_passes_unchanged_firmware_and_catches_an_injected_slowdown(tmp_path: Path) -> None:
    baseline = tmp_path / "baseline.json"
    run_rig("bench", "--targets", "qemu", "--duration", "3", "--update-baseline", "--baseline", str(baseline),
            check=True)
    assert json.loads(baseline.read_text())["targets"]["qemu"]["unit"] == "instructions"

    same = run_rig("bench", "--targets", "qemu", "--baseline", str(baseline), "--json", str(tmp_path / "same.json"))
    assert same.returncode == 0, same.stdout + same.stderr
    rows = json.loads((tmp_path / "same.json").read_text())["comparison"]
    assert len(rows) == 6 and all(r["compared"] and not r["regressed"] for r in rows)

    other = paths.data_dir() / "flights" / "0426-traj1"
    elsewhere = run_rig("bench", str(other), "--targets", "qemu", "--baseline", str(baseline))
    assert elsewhere.returncode not in (0, 1), elsewhere.stdout + elsewhere.stderr     # refused, not compared
    assert f"{other} is not that recording" in elsewhere.stderr

    junit = tmp_path / "junit.xml"
    slow = run_rig("bench", "--targets", "qemu", "--baseline", str(baseline), "--firmware", str(_slow_firmware()),
                   "--json", str(tmp_path / "slow.json"), "--junit-xml", str(junit))
    assert slow.returncode == 1
    assert "regressed" in slow.stderr
    report = json.loads((tmp_path / "slow.json").read_text())
    regressed = {r["figure"] for r in report["comparison"] if r["regressed"]}
    assert {"predict_p50", "tdoa_update_mean", "window_max"} <= regressed
    cases = {c.get("name"): c for c in ElementTree.parse(junit).getroot().iter("testcase")}  # one per figure
    assert set(cases) == {r["figure"] for r in report["comparison"]}
    failed = {name for name, c in cases.items() if c.find("failure") is not None}
    assert failed == regressed
    assert "threshold +5%" in cases["window_max"].find("failure").get("message")
