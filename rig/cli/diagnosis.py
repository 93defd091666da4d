"""`rig diagnose` and `rig combine-models`: why simulation and reality disagree, and one
simulation model from the models of several flights."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig.cli.common import EXIT_OK, CliError, progress, strict_option, survey_option
from rig.data.errors import read_json
from rig.data.files import write_text_whole

CHANGES_PRINTED = 12           # `rig diagnose --control`: the largest changes printed (all in report.md)


def flight_to_diagnose(path: Path, survey: Path | None, strict: bool = False):
    from rig.data.importer import load_any

    rec = load_any(path, survey, strict=strict)
    if len(rec.truth) < 10:
        raise CliError(f"{path}: no ground truth to simulate the flight from")
    return rec


def cmd_diagnose(args: argparse.Namespace) -> int:
    from rig.diagnosis import compare
    from rig.diagnosis.diagnose import diagnose
    from rig.diagnosis.report import CONTROL_DIR, REPORT_JSON, REPORT_MD, write

    rec = flight_to_diagnose(args.recording, args.survey, args.strict)      # both read before either is diagnosed
    control_rec = flight_to_diagnose(args.control, args.survey, args.strict) if args.control is not None else None
    if control_rec is None:
        result = diagnose(rec, progress=progress(desc="diagnose channels"))
        report = write(result, args.out, str(args.recording))
    else:
        both = compare.diagnose_against(rec, control_rec, str(args.control),
                                        progress=progress(desc="diagnose channels"),
                                        control_progress=progress(desc="diagnose the control"))
        if not both.against_control["same_flight"]:
            print(f"warning: {args.control} does not look like a control recording of the same flight: "
                  f"{both.against_control['how_it_differs']}", file=sys.stderr)
        write(both.control, args.out / CONTROL_DIR, str(args.control))
        result = both.diagnosis
        report = write(result, args.out, str(args.recording), both.against_control)
    print_diagnosis(result, report)
    print(f"wrote {args.out / REPORT_JSON} and {args.out / REPORT_MD}"
          + (f" (the control's report in {args.out / CONTROL_DIR})" if control_rec is not None else ""))
    return EXIT_OK


def print_diagnosis(result, report: dict) -> None:
    """The channels' mismatch, the findings, the IMU's noise and the largest changes against a control."""
    from rig.diagnosis import compare
    from rig.diagnosis.report import SENSORS, change_text
    from rig.diagnosis.wording import describe, lean_line, not_explained_line
    from rig.sim import effects as fx

    for name, c in report["channels"].items():
        print(f"{name}: mismatch {c['fit_before']:.4g} -> {c['fit_after']:.4g} ({c['samples']} samples)")
    for f in result.explained:
        print(f"  {f.effect:16s} evidence {f.evidence:9.1f}  {describe(f)}")
    if result.not_explained:
        jointly = sum(f.beyond_only_jointly for f in result.not_explained)
        print(f"  not explained ({len(result.not_explained)} fits beyond their effect's physical bound"
              + (f", {jointly} of them only jointly" if jointly else "") + ", in report.md):")
    for f in result.not_explained:
        print(f"    evidence {f.evidence:9.1f}  {not_explained_line(f)}")
    lean = lean_line(result)
    if lean:
        print(f"    {lean}")
    noise = fx.params_by_name(report["model"])
    if "imu_lowpass" in noise:
        lowpass = noise["imu_lowpass"]
        print(f"  IMU readings low-pass filtered before logging: {lowpass['accel_hz']:.0f} Hz (accelerometer), "
              f"{lowpass['gyro_hz']:.0f} Hz (gyroscope); model.json carries it")
    if "imu_resonance" in noise:
        peak = noise["imu_resonance"]
        peaks = [f"{peak[f'{s}_hz']:.1f} Hz ({name})" for s, (name, _) in SENSORS.items() if peak[f"{s}_hz"] > 0]
        print(f"  IMU noise peaks at {', '.join(peaks)}: the airframe's slow shaking; model.json carries it")
    listed = compare.by_size(report.get("against_control", {}).get("changes", []))
    for c in listed[:CHANGES_PRINTED]:
        anchors = f" {c['anchors']}" if "anchors" in c else ""
        size = f" ({c['change_std_errs']:.1f} standard errors)" if c["change_std_errs"] is not None else ""
        print(f"  against the control: {c['effect']}{anchors} named on {c['named_in']}, change {change_text(c)}{size}")
    if len(listed) > CHANGES_PRINTED:
        print(f"  against the control: {len(listed) - CHANGES_PRINTED} more in report.md")


def cmd_combine_models(args: argparse.Namespace) -> int:
    from rig.diagnosis.combine import combine, config_json, read_models, replace_fitted

    try:
        effects = combine(read_models(args.models))
        config = read_json(args.config)
    except (OSError, ValueError) as exc:
        raise CliError(str(exc)) from exc
    config = replace_fitted(config, effects)
    write_text_whole(args.config, config_json(config))
    for e in config["effects"]:
        print(f"  {e['effect']:16s} {json.dumps(e['params'])}")
    print(f"wrote {len(effects)} fitted effects of {len(args.models)} flights into {args.config}")
    return EXIT_OK


def register(sub) -> None:
    p = sub.add_parser("diagnose", help="where a simulation of the flight and the recording differ, and why",
                       description="Simulate the recording's own flight (its ground truth and anchors) with the "
                                   "simulator's physics, compare channel by channel (TDOA, accelerometer, "
                                   "gyroscope), locate the mismatch, fit the effect catalog (time_offset, "
                                   "clock_drift, anchor_position, anchor_delay, antenna_pattern, nlos, "
                                   "multipath_floor, imu_accel_bias, imu_gyro_bias, imu_accel_scale, "
                                   "imu_gyro_scale, imu_vibration_rectification, lever_arm), name those whose "
                                   "robust loss reduction pays for their parameters (simplest explanation first) "
                                   "and re-simulate, with the link bias every tag-anchor link shares (link_bias, "
                                   "its shape calibrated on the shared flights, one gain, judged after them) and "
                                   "how each anchor's ranges read while the tag sits on the floor "
                                   "(on_ground_delay). "
                                   "Writes DIR/report.json (findings sorted by evidence), DIR/report.md with "
                                   "plots and DIR/model.json (the fitted effects and the noise they leave, with "
                                   "the IMU's low-pass when its spectrum rolls off, usable as a `rig simulate` "
                                   "effect list). See docs/guide/diagnosis.md.")
    p.add_argument("recording", type=Path, help="recording (MCAP, or a flight log of the shared data)")
    survey_option(p)
    strict_option(p)
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--control", type=Path, metavar="RECORDING",
                   help="a control recording of the same flight (as it was before a change, or before effects "
                        "were injected): diagnosed too (its report in DIR/control/), and report.json's "
                        "`against_control` lists each effect's change from it (real flights carry effects of "
                        "their own; a change shows as the difference)")
    p.set_defaults(func=cmd_diagnose)
    p = sub.add_parser("combine-models", help="one simulation model from the models diagnosed on several flights",
                       description="Combine the model.json files `rig diagnose` wrote for several real flights of "
                                   "one room into the effects of a `rig simulate` config: the effects of the "
                                   "hardware and the room (delays, clocks, IMU errors, TDOA noise) named on at "
                                   "least half of the flights, each with its median parameters; path-bound ones "
                                   "(NLOS regions, displacements, patterns, lever arms) are left out; a vibration "
                                   "rectification enters as the accelerometer bias it made on its flight, an "
                                   "accelerometer scale as the bias it made there in hover. Replaces "
                                   "the config's effects, keeping its own outliers, IMU noise, rotor vibration and "
                                   "IMU low-pass (a flight's noise is its own). See docs/guide/diagnosis.md.")
    p.add_argument("models", type=Path, nargs="+", help="DIR/model.json files of `rig diagnose`")
    p.add_argument("--config", type=Path, required=True, help="the simulation config to update")
    p.set_defaults(func=cmd_combine_models)
