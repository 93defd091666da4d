"""What a bias correction does to a real flight's TDOA errors, per anchor
(rig.bias.effect), as `rig evaluate` reports it with every corrected replay."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from rigtest import run_rig

from rig.bias.dataset import flight_samples
from rig.bias.effect import correction_effect
from rig.data.importer import load_any
from rig.estimator.bias_net import DEFAULT_NETWORK, BiasNet, identity_probe_net

FLIGHT = "0422-log03"


def test_a_correction_of_nothing_changes_no_error(data_dir: Path) -> None:
    rec = load_any(data_dir / "flights" / FLIGHT)
    effect = correction_effect(rec, identity_probe_net(0, gain=0.0, form="link"))
    assert effect["tdoa_error_rms_m"]["before"] == effect["tdoa_error_rms_m"]["after"] > 0.1
    assert effect["worse_pairs"] == [] and len(effect["per_pair"]) >= 8
    assert effect["samples"] == len(flight_samples(rec, FLIGHT)) and effect["corrected_share"] == 1.0


def test_the_pairs_a_wrong_correction_makes_worse_are_named(data_dir: Path) -> None:
    rec = load_any(data_dir / "flights" / FLIGHT)
    # the link form with a range offset of 0.3 m on anchor 5 alone: every pair with anchor
    # 5 gets a constant wrong by 0.3 m, the other pairs nothing
    wrong = replace(identity_probe_net(0, gain=0.0, form="link"), anchor_offset=np.eye(16)[5] * 0.3)
    effect = correction_effect(rec, wrong)
    with_five = {k for k in effect["per_pair"] if "5" in k.split("-")}
    assert with_five and set(effect["worse_pairs"]) == with_five
    assert all(effect["per_pair"][k]["after"] > effect["per_pair"][k]["before"] + 0.05 for k in with_five)
    # an anchor the model was not trained on is left uncorrected, and not scored
    effect = correction_effect(rec, replace(wrong, anchors=[0, 1, 2, 3, 4, 6, 7]))
    assert effect["worse_pairs"] == [] and not any("5" in k.split("-") for k in effect["per_pair"])
    assert 0.5 < effect["corrected_share"] < 0.9


def test_rig_evaluate_reports_it_with_the_shipped_correction_only(tmp_path: Path, data_dir: Path) -> None:
    flight = data_dir / "flights" / FLIGHT
    proc = run_rig("evaluate", str(flight), "--json", str(tmp_path / "with.json"), check=True)
    effect = json.loads((tmp_path / "with.json").read_text())["correction_effect"]
    assert effect == json.loads(json.dumps(correction_effect(load_any(flight), BiasNet.load(DEFAULT_NETWORK))))
    assert f"RMS {effect['tdoa_error_rms_m']['before']:.3f} → {effect['tdoa_error_rms_m']['after']:.3f} m" \
        in proc.stdout
    run_rig("evaluate", str(flight), "--no-nn", "--json", str(tmp_path / "without.json"), check=True)
    assert "correction_effect" not in json.loads((tmp_path / "without.json").read_text())


def test_a_recording_it_cannot_measure_keeps_its_score(tmp_path: Path, data_dir: Path, monkeypatch,
                                                      capfd) -> None:
    import signal

    import rig.bias.effect
    import rig.cli

    def unmeasurable(rec, name):
        raise ValueError("no ground truth in flight")
    monkeypatch.setattr(rig.bias.effect, "flight_samples", unmeasurable)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        code = rig.cli.main(["evaluate", str(data_dir / "flights" / FLIGHT), "--json", str(tmp_path / "r.json")])
    finally:
        for s, handler in handlers.items():            # the rig's own handlers stay with the rig
            signal.signal(s, handler)
    result = json.loads((tmp_path / "r.json").read_text())
    assert code == 0 and result["rmse_3d"] < 0.4 and "correction_effect" not in result
    assert result["correction_effect_error"] == "ValueError: no ground truth in flight"
    assert "not measured (ValueError: no ground truth in flight)" in capfd.readouterr().out
