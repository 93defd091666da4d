"""`rig diagnose` as a user runs it: the report contract (report.json, report.md,
model.json), the comparison against a control, bad input refused clearly."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
from diagnosis_cases import CASES, keyed
from rigtest import RIG

from rig.data.paths import default_recording

pytestmark = pytest.mark.slow        # left out of `make test-fast`


def test_cli_writes_the_report_contract(tmp_path: Path, survey) -> None:
    recording = tmp_path / "sim.mcap"
    subprocess.run([*RIG, "simulate", "--trajectory", "circle-sine", "--survey", str(survey), "--duration", "20",
                    "-o", str(recording)], check=True, capture_output=True)
    injected = tmp_path / "injected.mcap"
    subprocess.run([*RIG, "inject", str(recording), "--effects",
                    '[{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.3}}]', "-o", str(injected)],
                   check=True, capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(injected), "--out", str(tmp_path / "d")], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    evidence = [f["evidence"] for f in report["findings"]]
    assert evidence == sorted(evidence, reverse=True)
    for f in report["findings"]:
        assert {"effect", "channel", "params", "evidence", "fit_before", "fit_after", "where"} <= set(f)
    delay = next(f for f in report["findings"] if f["effect"] == "anchor_delay" and f["anchors"] == [2])
    assert abs(delay["params"]["meters"] - 0.3) < 0.05
    markdown = (tmp_path / "d" / "report.md").read_text()
    assert "anchor_delay" in markdown and "![" in markdown
    assert report["mismatch"]["tdoa_per_pair_m"] and "## Where they differ" in markdown
    assert "(mismatch_regions.png)" in markdown
    assert re.search(r"\*\*Anchors\*\*, how long each one's ranges read, largest first: 2: \+0\.[23]", markdown)
    for image in (tmp_path / "d").glob("*.png"):
        assert image.stat().st_size > 1000
    written = json.loads((tmp_path / "d" / "model.json").read_text())
    assert len(written["vibration_rms_mps2"]) == 3 and min(written["vibration_rms_mps2"]) > 0   # for combine-models
    model = written["effects"]
    # the model fits the named effects jointly; a finding is estimated given the simpler
    # explanations only: the two agree where no richer look-alike shares the signal
    fitted = next(e for e in model if e["effect"] == "anchor_delay" and e["params"]["anchor"] == 2)
    assert fitted["params"]["meters"] == pytest.approx(delay["params"]["meters"], abs=0.01)


def test_cli_diagnoses_against_a_control_recording(tmp_path: Path, survey) -> None:
    """`rig diagnose REC --control CONTROL`: the control's own report in DIR/control/,
    and each effect's change from it: a delay the control already has, grown on the
    recording, is reported as its growth; a time offset named on the recording only,
    from the control's own estimate of it below its bar; an NLOS added over half of
    the room (a list of effects too long for a file name, given inline), from the
    control's estimate in the region found."""
    simulated, control, recording = (tmp_path / name for name in ("sim.mcap", "control.mcap", "rec.mcap"))
    subprocess.run([*RIG, "simulate", "--trajectory", "circle-sine", "--survey", str(survey), "--duration", "20",
                    "-o", str(simulated)], check=True, capture_output=True)
    for source, target, effects in (
            (simulated, control, [{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.3}}]),
            (control, recording, [{"effect": "anchor_delay", "params": {"anchor": 2, "meters": 0.15}},
                                  {"effect": "anchor_delay", "params": {"anchor": 6, "meters": -0.25}},
                                  {"effect": "time_offset", "params": {"seconds": 0.05}},
                                  {"effect": "nlos", "params": CASES["nlos"][0] | {"anchor": 4}}])):
        subprocess.run([*RIG, "inject", str(source), "--effects", json.dumps(effects), "-o", str(target)],
                       check=True, capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(control), "--out", str(tmp_path / "d")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    own = json.loads((tmp_path / "d" / "control" / "report.json").read_text())
    assert own["recording"] == str(control) and "against_control" not in own
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert report["against_control"]["recording"] == str(control)
    assert report["against_control"]["same_flight"] and "does not look like" not in proc.stderr   # injected: same truth
    listed = keyed(report["against_control"]["changes"])
    grown = listed[("anchor_delay", (2,))]
    assert grown["named_in"] == "both" and grown["change"]["meters"] == pytest.approx(0.15, abs=0.04)
    assert grown["recording"]["meters"] - grown["control"]["meters"] == pytest.approx(grown["change"]["meters"])
    added = listed[("anchor_delay", (6,))]
    assert added["change"]["meters"] == pytest.approx(-0.25, abs=0.04)
    late = listed[("time_offset", ())]            # on the recording only: from the control's own, unnamed
    below_bar = keyed(own["unnamed_estimates"])[("time_offset", ())]
    assert late["named_in"] == "recording" and late["control_unnamed"] == below_bar["params"]
    assert late["change"]["seconds"] == pytest.approx(late["recording"]["seconds"] - below_bar["params"]["seconds"])
    assert late["change"]["seconds"] == pytest.approx(0.05, rel=0.35)
    excess = listed[("nlos", (4,))]
    assert excess["named_in"] == "recording" and CASES["nlos"][1](excess["change"], None)
    assert grown["size"] == pytest.approx(abs(grown["change"]["meters"]))
    assert 0 < grown["told_apart_from"] < grown["size"]       # a delay of 0.15 m over 20 s: well beyond the noise
    assert "against the control: anchor_delay [2] named on both" in proc.stdout
    markdown = (tmp_path / "d" / "report.md").read_text()
    assert "## Against the control recording" in markdown and "| told apart from |" in markdown
    other = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(default_recording()),
                            "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert other.returncode == 0, other.stderr                  # another flight: compared, and said so
    assert "does not look like a control recording of the same flight" in other.stderr
    against = json.loads((tmp_path / "o" / "report.json").read_text())["against_control"]
    assert not against["same_flight"] and "m from the recording's (median)" in against["how_it_differs"]
    assert "The control does not look like the same flight" in (tmp_path / "o" / "report.md").read_text()
    missing = subprocess.run([*RIG, "diagnose", str(recording), "--control", str(tmp_path / "none.mcap"),
                              "--out", str(tmp_path / "e")], capture_output=True, text=True)
    assert missing.returncode == 2 and "none.mcap does not exist" in missing.stderr
    assert not (tmp_path / "e").exists()          # neither diagnosed: both are read first


def test_bad_effects_are_refused_clearly(tmp_path: Path) -> None:
    proc = subprocess.run([*RIG, "inject", "recordings/default.mcap", "--effects",
                           '[{"effect": "warp_drive", "params": {}}]', "-o", str(tmp_path / "x.mcap")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown effect 'warp_drive'" in proc.stderr
    assert not (tmp_path / "x.mcap").exists()
    proc = subprocess.run([*RIG, "inject", "recordings/default.mcap", "--effects",
                           '[{"effect": "learned_bias", "params": {"network": "no/such/net.json"}}]',
                           "-o", str(tmp_path / "x.mcap")], capture_output=True, text=True)
    assert proc.returncode == 2 and "no bias network at no/such/net.json" in proc.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_the_cli_says_the_imu_was_low_pass_filtered_and_shook(tmp_path: Path, survey) -> None:
    """`rig diagnose` names the low-pass and the noise's peak on its console too, and
    model.json carries them, so `rig simulate` can fly the model."""
    config = tmp_path / "sim.json"
    config.write_text(json.dumps({"trajectory": "circle-sine", "duration": 20.0, "survey": str(survey), "effects": [
        {"effect": "imu_noise", "params": {"accel_std": 0.5, "gyro_std": 0.05}},
        {"effect": "imu_resonance", "params": {"gyro_std": [0.1, 0.1, 0.0], "gyro_hz": 7.0, "gyro_q": 3.0}},
        {"effect": "imu_lowpass", "params": {"accel_hz": 30.0, "gyro_hz": 80.0}}]}))
    subprocess.run([*RIG, "simulate", "--config", str(config), "-o", str(tmp_path / "sim.mcap")], check=True,
                   capture_output=True)
    proc = subprocess.run([*RIG, "diagnose", str(tmp_path / "sim.mcap"), "--out", str(tmp_path / "d")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    said = re.search(r"IMU readings low-pass filtered before logging: (\d+) Hz \(accelerometer\)", proc.stdout)
    assert said and 27 <= int(said.group(1)) <= 33, proc.stdout
    peak = re.search(r"IMU noise peaks at ([\d.]+) Hz \(gyroscope\)", proc.stdout)
    assert peak and 6.3 <= float(peak.group(1)) <= 7.7, proc.stdout
    model = json.loads((tmp_path / "d" / "model.json").read_text())["effects"]
    lowpass = next(e["params"] for e in model if e["effect"] == "imu_lowpass")
    assert lowpass["accel_hz"] == pytest.approx(30.0, rel=0.1)
    assert any(e["effect"] == "imu_resonance" for e in model)
    config.write_text(json.dumps({"trajectory": "circle-sine", "duration": 5.0, "survey": str(survey),
                                  "effects": model}))
    subprocess.run([*RIG, "simulate", "--config", str(config), "-o", str(tmp_path / "again.mcap")], check=True,
                   capture_output=True)
