"""`rig simulate` and `rig inject`: flights from the simulator, and recordings as if
effects of the catalog had been present."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from rig.cli.common import EXIT_OK, CliError, progress, survey_option
from rig.data import paths


def cmd_simulate(args: argparse.Namespace) -> int:
    from rig.data.recording import write_recording
    from rig.sim.simulate import SimConfig, simulate

    cfg = SimConfig.load(args.config) if args.config else SimConfig()
    if args.trajectory is not None and args.trajectory != cfg.trajectory and cfg.trajectory_params:
        # the config's parameters describe its own trajectory, not the one asked for
        print(f"--trajectory {args.trajectory}: the config's trajectory_params (for {cfg.trajectory}) are not used")
        cfg.trajectory_params = {}
    overrides = {
        "trajectory": args.trajectory, "duration": args.duration, "recording": args.recording,
        "survey": args.survey, "imu_hz": args.imu_hz, "tdoa_hz": args.tdoa_hz,
        "uwb_mode": args.uwb_mode, "seed": args.seed,
    }
    cfg = dataclasses.replace(cfg, **{key: str(value) if isinstance(value, Path) else value   # checked again
                                      for key, value in overrides.items() if value is not None})
    if args.recording is not None and args.trajectory is None:
        cfg.trajectory = "recording"
    if cfg.trajectory != "recording" and not cfg.survey:
        cfg.survey = str(paths.default_survey())
    if args.noiseless:
        cfg.effects = []
    rec = simulate(cfg)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=progress(desc="writing"))
    print(f"{args.output}: simulated {rec.time_span()[1] - rec.time_span()[0]:.1f} s, {len(rec.accel)} IMU, "
          f"{len(rec.tdoa)} TDOA ({cfg.uwb_mode}), seed {cfg.seed}")
    return EXIT_OK


def effects_argument(text: str) -> list[dict]:
    """Effects as JSON text or a JSON file: a list, one effect, or {"effects": [...]}.
    Text that starts as JSON does is JSON (a long list is no file name: asking the file
    system about it fails)."""
    try:
        data = json.loads(text if text.lstrip()[:1] in ("[", "{") else Path(text).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CliError(f"--effects: neither a JSON file nor JSON text ({exc})") from exc
    if isinstance(data, dict):
        data = data.get("effects", [data])
    if not isinstance(data, list) or not all(isinstance(e, dict) and "effect" in e for e in data):
        raise CliError('--effects: expected [{"effect": NAME, "params": {...}}, ...]')
    return data


def cmd_inject(args: argparse.Namespace) -> int:
    from rig.data.importer import load_any
    from rig.data.recording import write_recording
    from rig.sim.effects import effects_from_json
    from rig.sim.simulate import inject

    effects = effects_argument(args.effects)
    try:
        effects_from_json(effects)
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    rec = inject(load_any(args.recording, args.survey), effects, seed=args.seed)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=progress(desc="writing"))
    print(f"{args.output}: {args.recording} with {', '.join(e['effect'] for e in effects)}")
    return EXIT_OK


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate IMU + TDOA along a trajectory",
                       description="Simulate a flight: parametric trajectory or a recording's ground truth, "
                                   "anchors from a survey or the recording, effects from a JSON config. "
                                   "Deterministic for a seed.")
    p.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    p.add_argument("--config", type=Path, help="simulation config JSON (see recordings/default.sim.json)")
    p.add_argument("--trajectory", choices=("circle", "circle-sine", "smooth-random", "recording"))
    p.add_argument("--duration", type=float, help="seconds of pattern flight (parametric trajectories)")
    p.add_argument("--recording", type=Path, help="fly this recording's ground truth (MCAP, or a flight log of the "
                   "shared data) past its anchors")
    p.add_argument("--survey", type=Path, help="anchor survey file")
    p.add_argument("--imu-hz", type=float)
    p.add_argument("--tdoa-hz", type=float)
    p.add_argument("--uwb-mode", choices=("TDOA2", "TDOA3"))
    p.add_argument("--seed", type=int)
    p.add_argument("--noiseless", action="store_true", help="no effects at all: ideal sensors")
    p.set_defaults(func=cmd_simulate)
    p = sub.add_parser("inject", help="a recording as if effects of the catalog had been present",
                       description="Add catalog effects to a recording (real or simulated): TDOA values change "
                                   "by what the effects change in the simulator along the ground truth, UWB "
                                   "stamps move with timing effects, IMU effects act on the recorded readings. "
                                   "The recording keeps its own noise and effects (use it as the control).")
    p.add_argument("recording", type=Path, help="recording (MCAP, or a flight log of the shared data)")
    survey_option(p)
    p.add_argument("--effects", required=True,
                   help='JSON text or file: [{"effect": "anchor_delay", "params": {"anchor": 3, "meters": 0.1}}]')
    p.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    p.add_argument("--seed", type=int, default=0, help="seed of random effects (nlos, noise)")
    p.set_defaults(func=cmd_inject)
