"""The `rig` command: one entry point for every job of the test rig.

Each sub-command lives in a small function below; the heavy lifting is in the
module named after the job (importer, simulate, metrics, ...).
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import logging
import signal
import sys
from pathlib import Path

import numpy as np

from rig import paths
from rig.bias_model import DEFAULT_NETWORK

log = logging.getLogger("rig")

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
CHANGES_PRINTED = 12           # `rig diagnose --control`: the largest changes printed (all in report.md)


class CliError(Exception):
    """An error to report to the user in one line, without a traceback."""


def _progress(total: int | None = None, desc: str = ""):
    """A tqdm wrapper factory that stays quiet when stderr is not a terminal."""
    from tqdm import tqdm

    def wrap(iterable):
        return tqdm(iterable, total=total, desc=desc, unit="msg", disable=not sys.stderr.isatty(),
                    mininterval=0.5, leave=False)
    return wrap


def _write_json(path: Path | None, data: dict) -> None:
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    log.info("wrote %s", path)


# ----------------------------------------------------------------------------- import

def cmd_import(args: argparse.Namespace) -> int:
    from rig.importer import import_log
    from rig.recording import write_recording

    rec = import_log(args.log, args.survey, salvage=args.salvage, uwb_mode=args.uwb_mode)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=_progress(desc="writing"))
    print(f"{args.output}: {len(rec.accel)} accel, {len(rec.gyro)} gyro, {len(rec.tdoa)} TDOA, "
          f"{len(rec.truth)} ground-truth samples, {len(rec.anchors)} anchors, mode {rec.metadata['uwb_mode']}")
    if "salvage" in rec.metadata:
        print(f"warning: salvaged a damaged log: {rec.metadata['salvage']}", file=sys.stderr)
    return EXIT_OK


# ----------------------------------------------------------------------------- simulate

def cmd_simulate(args: argparse.Namespace) -> int:
    from rig.recording import write_recording
    from rig.simulate import SimConfig, simulate

    cfg = SimConfig.load(args.config) if args.config else SimConfig()
    overrides = {
        "trajectory": args.trajectory, "duration": args.duration, "recording": args.recording,
        "survey": args.survey, "imu_hz": args.imu_hz, "tdoa_hz": args.tdoa_hz,
        "uwb_mode": args.uwb_mode, "seed": args.seed,
    }
    for key, value in overrides.items():
        if value is not None:
            setattr(cfg, key, str(value) if isinstance(value, Path) else value)
    if args.recording is not None and args.trajectory is None:
        cfg.trajectory = "recording"
    if cfg.trajectory != "recording" and not cfg.survey:
        cfg.survey = str(paths.default_survey())
    if args.noiseless:
        cfg.effects = []
    rec = simulate(cfg)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=_progress(desc="writing"))
    print(f"{args.output}: simulated {rec.time_span()[1] - rec.time_span()[0]:.1f} s, {len(rec.accel)} IMU, "
          f"{len(rec.tdoa)} TDOA ({cfg.uwb_mode}), seed {cfg.seed}")
    return EXIT_OK


# ----------------------------------------------------------------------------- diagnosis

def _effects_argument(text: str) -> list[dict]:
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


def cmd_diagnose(args: argparse.Namespace) -> int:
    from rig import compare
    from rig import effects as fx
    from rig.diagnose import diagnose
    from rig.diagnosis_report import CONTROL_DIR, REPORT_JSON, REPORT_MD, SENSORS, change_text, describe, write

    rec = _flight_to_diagnose(args.recording, args.survey)      # both read before either is diagnosed
    control_rec = _flight_to_diagnose(args.control, args.survey) if args.control is not None else None
    control, differs, control_samples = None, None, None
    if control_rec is not None:
        differs = compare.flight_difference(rec, control_rec)
        if differs:
            print(f"warning: {args.control} does not look like a control recording of the same flight: {differs}",
                  file=sys.stderr)
        control_result = diagnose(control_rec, progress=_progress(desc="diagnose the control"))
        control = write(control_result, args.out / CONTROL_DIR, str(args.control))
        control_samples = compare.TdoaSamples.of(control_result)
    result = diagnose(rec, progress=_progress(desc="diagnose channels"))
    report = write(result, args.out, str(args.recording), control, differs, control_samples)
    for name, c in report["channels"].items():
        print(f"{name}: mismatch {c['fit_before']:.4g} -> {c['fit_after']:.4g} ({c['samples']} samples)")
    for f in result.findings:
        print(f"  {f.effect:16s} evidence {f.evidence:9.1f}  {describe(f)}")
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
    print(f"wrote {args.out / REPORT_JSON} and {args.out / REPORT_MD}"
          + (f" (the control's report in {args.out / CONTROL_DIR})" if control else ""))
    return EXIT_OK


def _flight_to_diagnose(path: Path, survey: Path | None):
    from rig.importer import load_any

    rec = load_any(path, survey)
    if len(rec.truth) < 10:
        raise CliError(f"{path}: no ground truth to simulate the flight from")
    return rec


def cmd_combine_models(args: argparse.Namespace) -> int:
    from rig.fitted_model import combine, read_models, replace_fitted

    try:
        effects = combine(read_models(args.models))
        config = json.loads(args.config.read_text())
    except (OSError, ValueError) as exc:
        raise CliError(str(exc)) from exc
    config = replace_fitted(config, effects)
    args.config.write_text(_config_json(config))
    for e in config["effects"]:
        print(f"  {e['effect']:16s} {json.dumps(e['params'])}")
    print(f"wrote {len(effects)} fitted effects of {len(args.models)} flights into {args.config}")
    return EXIT_OK


def _config_json(config: dict) -> str:
    """One effect per line: a config a person reads and diffs."""
    head = {k: v for k, v in config.items() if k != "effects"}
    lines = [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    effects = ",\n".join(f"    {json.dumps(e)}" for e in config.get("effects", []))
    return "{\n" + "\n".join(lines) + '\n  "effects": [\n' + effects + "\n  ]\n}\n"


def cmd_inject(args: argparse.Namespace) -> int:
    from rig.effects import effects_from_json
    from rig.importer import load_any
    from rig.recording import write_recording
    from rig.simulate import inject

    effects = _effects_argument(args.effects)
    try:
        effects_from_json(effects)
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    rec = inject(load_any(args.recording, args.survey), effects, seed=args.seed)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_recording(rec, args.output, progress=_progress(desc="writing"))
    print(f"{args.output}: {args.recording} with {', '.join(e['effect'] for e in effects)}")
    return EXIT_OK


# ----------------------------------------------------------------------------- metrics

def _load_estimates(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Estimates from a CSV (t,x,y,z with a header line) or from an MCAP `estimate` topic."""
    from rig.recording import read_topics

    if path.suffix == ".mcap":
        messages, _ = read_topics(path)
        topics = [t for t in messages if "estimate" in t]
        if not topics:
            raise CliError(f"{path} has no topic with 'estimate' in its name")
        msgs = messages[topics[0]]
        return (np.array([m["t"] for m in msgs], float),
                np.array([[m["position"][c] for c in "xyz"] for m in msgs], float))
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise CliError(f"cannot read estimates from {path}: {exc}") from exc
    if data.shape[1] < 4:
        raise CliError(f"{path}: expected columns t,x,y,z")
    return data[:, 0], data[:, 1:4]


def _segment_rule(args: argparse.Namespace):
    from rig.metrics import SegmentRule

    return SegmentRule(min_height=args.min_height, skip_after_takeoff=args.skip_after_takeoff)


def cmd_metrics(args: argparse.Namespace) -> int:
    from rig import metrics
    from rig.recording import read_recording

    truth = read_recording(args.recording).truth
    t, pos = _load_estimates(args.estimates)
    rule = _segment_rule(args)
    result = metrics.score(t, pos, truth, rule)
    _print_accuracy(result)
    _write_json(args.json, result)
    if args.plot:
        metrics.plot(t, pos, truth, args.plot, rule, title=str(args.estimates))
    return EXIT_OK


def _print_accuracy(result: dict) -> None:
    if "score_error" in result:
        print(f"not scored: {result['score_error']}")
        return
    x, y, z = result["rmse_xyz"]
    print(f"RMSE 3D {result['rmse_3d']:.3f} m (x {x:.3f}, y {y:.3f}, z {z:.3f}); "
          f"p95 {result['p95_3d']:.3f} m, max {result['max_3d']:.3f} m over {result['n_scored']} estimates")


# ----------------------------------------------------------------------------- evaluate

def cmd_evaluate(args: argparse.Namespace) -> int:
    from rig.evaluate import evaluate
    from rig.importer import load_any

    rec = load_any(args.recording, args.survey)
    result = evaluate(rec, robust=not args.no_robust, use_nn=not args.no_nn, model_path=args.model)
    result["recording"] = str(args.recording)
    config = ("robust" if not args.no_robust else "plain") + (" + bias network" if result["config"]["bias_net"] else "")
    print(f"{args.recording}: C estimator ({config}), {result['flight_seconds']:.1f} s replayed in "
          f"{result['estimator_seconds'] * 1e3:.1f} ms of estimator time")
    _print_accuracy(result)
    # the update rejects by its gate or by a robust weight near zero; the rest of the
    # reasons refuse a measurement before it reaches the update (counted apart)
    by_reason = result["rejected_by_reason"]
    refused = ", ".join(f"{k} {v}" for k, v in by_reason.items() if v and k != "gate") or "none"
    print(f"TDOA: {result['tdoa_accepted']} accepted, {result['tdoa_downweighted']} down-weighted, "
          f"{result['tdoa_rejected']} rejected (gate {by_reason['gate']}, robust weight "
          f"{result['tdoa_rejected'] - by_reason['gate']}); refused before the update: {refused}; "
          f"resets {result['resets']}; diverged: {'yes' if result['diverged'] else 'no'}")
    _write_json(args.json, result)
    return EXIT_FAILED if result["diverged"] else EXIT_OK


# ----------------------------------------------------------------------------- train

def cmd_train(args: argparse.Namespace) -> int:
    from rig.train import FEATURE_SETS, TrainConfig, provenance_path, run_training, trained_on

    flights = [f for f in paths.flights() if any(f.name.startswith(p) for p in args.flights)] \
        if args.flights else paths.flights()
    if args.apart_from:
        try:
            apart = trained_on(args.apart_from)
        except ValueError as exc:
            raise CliError(str(exc)) from exc
        flights = [f for f in flights if f.name not in apart]
    if not flights:
        raise CliError(f"no flight in {paths.data_dir() / 'flights'} matches {args.flights or 'all'}"
                       + (f" apart from {args.apart_from}'s training flights" if args.apart_from else ""))
    if args.restarts < 1:
        raise CliError(f"--restarts must be at least 1, got {args.restarts}")
    config = TrainConfig(seed=args.seed, restarts=args.restarts, select_by=args.select_by,
                         max_epochs=args.max_epochs, features=FEATURE_SETS[args.features])
    anchors = [int(a) for a in args.exclude_anchors.split(",")] if args.exclude_anchors else []
    prov = run_training(flights, args.out, test_prefixes=args.test, exclude_anchors=anchors, config=config,
                        dataset_cache=args.dataset_cache, command=["rig", *sys.argv[1:]],
                        progress=_progress(desc="training", total=None), features_from=args.features_from)
    t = prov["training"]
    print(f"trained on {len(prov['split']['train'])} flights ({prov['samples']['train']} samples), "
          f"{len(t['restarts'])} restarts in {t['seconds']:.0f} s; kept restart {t['restart']} by {t['selected_by']} "
          f"({t[t['selected_by']]:.3f}; best epoch {t['best_epoch']} of {t['epochs']})")
    for part in ("validation", "test"):
        stats = prov[part]
        if stats:
            print(f"{part}: TDOA error mean {stats['before']['mean']:+.3f} -> {stats['after']['mean']:+.3f} m, "
                  f"std {stats['before']['std']:.3f} -> {stats['after']['std']:.3f} m "
                  f"(int8 {stats['after_int8']['std']:.3f} m)")
    print(f"wrote {args.out} and {provenance_path(args.out)}")
    return EXIT_OK


# ----------------------------------------------------------------------------- replay

def _board_link(target: str, session, board: str):
    """The rig reaches boards only through a bridge: a remote one (zenoh:NAME) over the
    session, or an in-process one tapping a local board's link onto the session."""
    from bridge.zenoh_link import TapLink, ZenohLink
    from rig import transport

    if target.startswith("zenoh:"):
        return ZenohLink(session, target[len("zenoh:"):]).open()
    return TapLink(transport.open_target(target), session, board)


def _replay(recording: Path, target: str, out: Path, *, use_nn: bool = True, robust: bool = True,
            model_path: Path | None = None, start: float | None = None, duration: float | None = None,
            lookahead: int = 0, speed: float | None = None, report: bool = True, session=None,
            board: str = "local", survey: Path | None = None) -> dict:
    """Replay into one target through its bridge (on zenoh `session`, or a private one);
    write OUT/run.mcap (as it goes, finished on every exit path), OUT/metrics.json (also
    after a board failure, with the error) and the report."""
    import time

    from bridge.zenoh_link import open_session

    from rig import replay, transport
    from rig.evaluate import estimator_config
    from rig.importer import load_any
    from rig.runrecord import RUN_FILE, RunRecorder

    rec = load_any(recording, survey)
    params, model = estimator_config(robust, use_nn, model_path)
    out.mkdir(parents=True, exist_ok=True)
    recorder = RunRecorder(out / RUN_FILE)
    info = {"recording": str(recording), "target": target, "bias_net": model is not None, "robust": robust,
            "lookahead": lookahead, "mode": "lockstep" if speed is None else "realtime"}
    began, run, error, own, link = time.monotonic(), None, None, session is None, None
    try:
        session = session or open_session()
        link = _board_link(target, session, board)
        run = replay.run(link, rec, params, model, start=start, duration=duration, lookahead=lookahead,
                         speed=speed, progress=_progress(desc=f"replay {target}", total=None), recorder=recorder)
    except transport.LinkError as exc:
        error, run = str(exc), getattr(exc, "session", None)
        recorder.status(run.t0 if run else 0.0, "rig", -1, error)
    finally:
        recorder.close()         # first: the record is whole whatever the link's teardown does
        try:
            if link is not None:
                info["bytes_sent"] = link.bytes_sent
                link.close()
        finally:
            if own and session is not None:
                session.close()
    wall = time.monotonic() - began
    result = _score_run(run, rec)
    info.setdefault("bytes_sent", 0)       # the link never opened
    result.update(info)
    result.update({"wall_seconds": wall, "speed": result["n_estimates"] * replay.BUDGET_SECONDS / wall,
                   "run_record": str(out / RUN_FILE), "run_record_error": recorder.failed, "error": error})
    _write_json(out / "metrics.json", result)
    if error is not None:
        raise CliError(f"{error} (kept: {out / RUN_FILE}, {out / 'metrics.json'} with "
                       f"{result['n_estimates']} estimates)")
    timing = result["timing"]
    print(f"{recording} -> {target}: {result['n_estimates']} estimates in {wall:.1f} s "
          f"({result['speed']:.2f}x real time, {info['bytes_sent'] / max(1, result['n_estimates']):.0f} B a window)")
    _print_accuracy(result)
    print(f"timing ({timing['unit']}): window p50 {timing['window_p50']:.0f}, p99 {timing['window_p99']:.0f}, "
          f"max {timing['window_max']:.0f} = {timing['window_max_fraction_of_budget']:.1%} of the "
          f"{timing['budget']:.0f} budget; overruns {timing['overruns']}")
    if "realtime" in result:
        rt, lat = result["realtime"], result["realtime"]["latency_ms"] or {"p50": np.nan, "p99": np.nan, "max": np.nan}
        print(f"real time x{rt['speed']:g}: latency p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms, max "
              f"{lat['max']:.1f} ms; late windows {rt['late_windows']} (deadline {rt['deadline_ms']:.1f} ms), "
              f"missed windows {rt['missed_windows']}")
    if report:
        from rig.report import write_report

        print(f"wrote {out / 'metrics.json'}, {out / RUN_FILE} and {write_report(out)}")
    else:
        print(f"wrote {out / 'metrics.json'} and {out / RUN_FILE}")
    if recorder.failed:
        raise CliError(recorder.failed)
    return result


def _score_run(run, rec) -> dict:
    """Accuracy and timing of what the board answered; a run cut short before the
    scored segment still reports its estimates and timing, without accuracy."""
    from rig import replay
    from rig.metrics import MetricsError

    if run is None or not run.estimates:
        return {"n_estimates": 0}
    try:
        return replay.score(run, rec)
    except MetricsError as exc:
        return {"n_estimates": len(run.estimates), "timing": replay.timing_summary(run), "score_error": str(exc)}


def _assertions(result: dict, max_rmse: float | None, max_budget: float | None,
                figure: str = "window_max") -> list[str]:
    """What failed of an accuracy bar (m) and a budget bar (fraction of the 10 ms budget,
    on the timing `figure`: the worst window unless said otherwise)."""
    failed = []
    if max_rmse is not None and "rmse_3d" not in result:
        failed.append(f"no rmse_3d to compare with {max_rmse} m ({result.get('score_error')})")
    elif max_rmse is not None and not result["rmse_3d"] <= max_rmse:
        failed.append(f"rmse_3d {result['rmse_3d']:.3f} m > {max_rmse} m")
    timing = result["timing"]
    fraction = timing[figure] / timing["budget"]
    if max_budget is not None and not fraction <= max_budget:
        name = "worst window" if figure == "window_max" else figure.replace("_", " ")
        failed.append(f"{name} {fraction:.1%} of the budget > {max_budget:.1%}")
    return failed


def _deadline_failures(result: dict) -> list[str]:
    rt = result.get("realtime")
    if rt is None:
        return ["--assert-deadlines needs --mode realtime"]
    return [f"{rt[key]} {key.replace('_', ' ')}" for key in ("late_windows", "missed_windows") if rt[key]]


def cmd_replay(args: argparse.Namespace) -> int:
    from bridge.zenoh_link import open_session

    if not args.speed > 0:
        raise CliError(f"--speed must be a positive number, not {args.speed}")

    session = open_session(None, args.zenoh_listen, args.zenoh_connect)
    try:
        result = _replay(args.recording, args.target, args.out, use_nn=not args.no_nn, robust=not args.no_robust,
                         model_path=args.model, start=args.start, duration=args.duration,
                         lookahead=args.lookahead, speed=args.speed if args.mode == "realtime" else None,
                         session=session, board=args.board, survey=args.survey)
    finally:
        session.close()
    failed = _assertions(result, args.assert_rmse, args.assert_budget)
    if args.assert_deadlines:
        failed += _deadline_failures(result)
    for reason in failed:
        print(f"rig replay: assertion failed: {reason}", file=sys.stderr)
    return EXIT_FAILED if failed else EXIT_OK


# ----------------------------------------------------------------------------- size

def cmd_size(args: argparse.Namespace) -> int:
    from rig.footprint import measure

    result = measure()
    est = result["estimator"]
    budget = est["budget"]
    print(f"estimator (Cortex-M4F, -Os): flash {est['flash']} B of {budget['flash']} B budget; "
          f"RAM {est['ram']} B of {budget['ram']} B (static {est['static_ram']} B + stack {est['stack']} B "
          f"via {' > '.join(est['stack_chain'])})")
    fw = result["firmware"]
    print(f"firmware image (-O2, static): flash {fw['flash']} B, RAM {fw['ram']} B (text {fw['text']}, "
          f"data {fw['data']}, bss {fw['bss']})")
    _write_json(args.json, result)
    within = est["flash"] <= budget["flash"] and est["ram"] <= budget["ram"]
    return EXIT_OK if within else EXIT_FAILED


# ----------------------------------------------------------------------------- report

def cmd_report(args: argparse.Namespace) -> int:
    from rig.report import write_report

    print(f"wrote {write_report(args.dir)}")
    return EXIT_OK


# ----------------------------------------------------------------------------- zenoh: router, watch

def cmd_router(args: argparse.Namespace) -> int:
    import threading

    from bridge.zenoh_link import open_session, wait_interruptibly

    session = open_session("router", args.listen, [])
    print(f"router listening on {', '.join(args.listen)}", flush=True)
    try:
        wait_interruptibly(threading.Event(), args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        session.close()
    return EXIT_OK


def cmd_watch(args: argparse.Namespace) -> int:
    from bridge.zenoh_link import EstimateCounter, open_session, wait_interruptibly

    session = open_session(None, [], args.connect)
    counter = EstimateCounter(session, args.board, args.count).start()
    try:
        print("watching", flush=True)
        wait_interruptibly(counter.done, args.timeout)
    except KeyboardInterrupt:
        pass
    finally:
        counter.stop()
        session.close()
    result = {"counts": counter.counts, "last": counter.last}
    _write_json(args.json, result)
    for board, n in sorted(counter.counts.items()):
        print(f"{board}: {n} estimates")
    return EXIT_OK if args.count is None or sum(counter.counts.values()) >= args.count else EXIT_FAILED


# ----------------------------------------------------------------------------- farm

def _farm_jobs(recordings: list[Path], targets: list[str]) -> list[tuple[Path, str]]:
    if len(recordings) == 1 or len(targets) == 1:
        return [(r, t) for r in recordings for t in targets]
    if len(recordings) != len(targets):
        raise CliError("give one recording, one target, or as many recordings as targets")
    return list(zip(recordings, targets))


def cmd_farm(args: argparse.Namespace) -> int:
    """Many boards at once: one router session here, one bridge process per board, every
    replay through zenoh in parallel; each job writes OUT/boardK/ (run.mcap, metrics.json,
    report.html) and OUT/farm.json sums them up."""
    import subprocess
    from concurrent.futures import ThreadPoolExecutor

    from bridge.zenoh_link import open_session
    from rig.report import write_report

    jobs = _farm_jobs(args.recordings, args.target or ["native"])
    session = open_session("router", [args.listen], [])
    bridges = [subprocess.Popen([sys.executable, "-m", "bridge", "--target", target, "--name", f"board{k}",
                                 "--connect", args.listen], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
               for k, (_, target) in enumerate(jobs)]

    def job(k: int) -> dict:
        recording, target = jobs[k]
        try:
            result = _replay(recording, f"zenoh:board{k}", args.out / f"board{k}", use_nn=not args.no_nn,
                             duration=args.duration, report=False, session=session, board=f"board{k}")
        except Exception as exc:  # one board's failure must not take the others down
            result = {"error": str(exc)}
        return {**result, "board": f"board{k}", "recording": str(recording), "target": target,
                "via": f"zenoh:board{k}"}

    try:
        with ThreadPoolExecutor(max_workers=len(jobs)) as pool:
            results = list(pool.map(job, range(len(jobs))))
    finally:
        for proc in bridges:
            proc.terminate()
        for proc in bridges:
            proc.wait(timeout=10)
        session.close()
    for k, r in enumerate(results):
        if (args.out / f"board{k}" / "run.mcap").exists():
            write_report(args.out / f"board{k}")
        state = r.get("error") or f"RMSE {r['rmse_3d']:.3f} m, {r['n_estimates']} estimates"
        print(f"board{k} ({r['target']}, {r['recording']}): {state}")
    _write_json(args.out / "farm.json", {"jobs": results})
    return EXIT_FAILED if any(r.get("error") for r in results) else EXIT_OK


# ----------------------------------------------------------------------------- bench

def cmd_bench(args: argparse.Namespace) -> int:
    from rig import bench
    from rig.importer import load_any
    from rig.transport import LinkError

    rec = load_any(args.recording)
    baseline = None if args.update_baseline else bench.load_baseline(args.baseline)
    start, duration = (args.start, args.duration) if baseline is None else bench.run_settings(baseline)
    binaries = {"native": args.program, "qemu": args.firmware}
    current = []
    for target in args.targets.split(","):
        try:
            current.append(bench.measure(target, rec, start, duration, binaries.get(target)))
        except LinkError as exc:
            raise CliError(str(exc)) from exc
    document = bench.baseline_document(current, str(args.recording), start, duration)
    if baseline is None:
        _write_json(args.baseline, document)
        for f in current:
            print(f"{f.target} ({f.unit}): " + ", ".join(f"{k} {v:.0f}" for k, v in f.values.items()))
        print(f"wrote baseline {args.baseline}")
        return EXIT_OK
    thresholds = dict(bench.THRESHOLDS)
    if args.threshold is not None:
        thresholds = {unit: args.threshold for unit in thresholds}
    rows = bench.compare(current, baseline, thresholds)
    print(f"{'target':7} {'figure':17} {'unit':12} {'baseline':>10} {'current':>10} {'ratio':>7}")
    for r in rows:
        flag = "  REGRESSED" if r["regressed"] else ("" if r["compared"] else "  (not compared)")
        print(f"{r['target']:7} {r['figure']:17} {r['unit']:12} {r['baseline']:10.0f} {r['current']:10.0f} "
              f"{r['ratio']:7.3f}{flag}")
    regressed = [r for r in rows if r["regressed"]]
    _write_json(args.json, {**document, "baseline": str(args.baseline), "comparison": rows,
                            "regressions": len(regressed)})
    for r in regressed:
        print(f"rig bench: {r['target']} {r['figure']} regressed by {r['ratio'] - 1:.1%} "
              f"(threshold {r['threshold']:.0%})", file=sys.stderr)
    return EXIT_FAILED if regressed else EXIT_OK


# ----------------------------------------------------------------------------- demo (main job)

DEMO_TARGETS = ("native", "qemu")
# the default recording carries the room's measured effects (docs/diagnosis.md): the
# robust estimator without the bias network gets 0.18-0.35 m (median 0.27) on the real
# flights of that room (docs/accuracy.md), 0.30 m on it
DEMO_MAX_RMSE_M = 0.40
DEMO_MAX_BUDGET = 0.20
# The real-time bar is the worst window under QEMU, whose instruction counts are
# deterministic. The native program's wall clock also counts the host scheduler's
# preemptions: its worst window is 50-100x its p99 on a quiet machine and crossed the
# bar when other work shared the two cores, so there the p99 is judged (it still
# catches any slowdown of the estimator itself).
DEMO_BUDGET_FIGURE = {"native": "window_p99", "qemu": "window_max"}
DEMO_AGREEMENT_M = 0.002


def cmd_demo(args: argparse.Namespace) -> int:
    """The README's main job: the default recording into the native program and the QEMU
    firmware in lock-step, accuracy and timing asserted, the two targets compared."""
    results, failed = {}, []
    for target in DEMO_TARGETS:
        results[target] = _replay(args.recording, target, args.out / target, use_nn=args.nn)
        failed += [f"{target}: {r}" for r in _assertions(results[target], DEMO_MAX_RMSE_M, DEMO_MAX_BUDGET,
                                                                   DEMO_BUDGET_FIGURE[target])]
    gap = abs(results["native"]["rmse_3d"] - results["qemu"]["rmse_3d"])
    print(f"native and QEMU RMSE differ by {gap * 1e3:.2f} mm")
    if gap > DEMO_AGREEMENT_M:
        failed.append(f"native and QEMU disagree by {gap * 1e3:.1f} mm")
    for reason in failed:
        print(f"rig demo: check failed: {reason}", file=sys.stderr)
    return EXIT_FAILED if failed else EXIT_OK


# ----------------------------------------------------------------------------- parser

def build_parser() -> argparse.ArgumentParser:
    from rig.bias_dataset import FEATURES_FROM
    from rig.train import SELECT_BY, TrainConfig

    parser = argparse.ArgumentParser(
        prog="rig",
        description="uwb-rig: replay UWB TDOA + IMU flights into the onboard estimator, "
                    "simulate flights, score estimates against ground truth.",
        epilog=f"Real flights are read from $UWB_RIG_DATA (default {paths.DEFAULT_DATA_DIR}).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("import", help="convert a Crazyflie uSD event log + anchor survey to MCAP",
                       description="Decode a Crazyflie uSD event log (version 2), verify magic, version and "
                                   "CRC-32, attach the surveyed anchors and write an MCAP recording in SI units.")
    p.add_argument("log", type=Path, help="uSD event log file")
    p.add_argument("--survey", type=Path, required=True, help="anchor survey (anchor_MMDD.txt)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    p.add_argument("--salvage", action="store_true",
                   help="import the valid prefix of a truncated or corrupted log (with a warning)")
    p.add_argument("--uwb-mode", choices=("TDOA2", "TDOA3"), help="override the inferred UWB mode")
    p.set_defaults(func=cmd_import)

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

    p = sub.add_parser("diagnose", help="where a simulation of the flight and the recording differ, and why",
                       description="Simulate the recording's own flight (its ground truth and anchors) with the "
                                   "simulator's physics, compare channel by channel (TDOA, accelerometer, "
                                   "gyroscope), locate the mismatch, fit the effect catalog (time_offset, "
                                   "clock_drift, anchor_position, anchor_delay, antenna_pattern, nlos, "
                                   "multipath_floor, imu_accel_bias, imu_gyro_bias, imu_accel_scale, "
                                   "imu_gyro_scale, imu_vibration_rectification, lever_arm), name those whose "
                                   "robust loss reduction pays for their parameters (simplest explanation first) "
                                   "and re-simulate, with how each anchor's ranges read while the tag sits on the "
                                   "floor (on_ground_delay). "
                                   "Writes DIR/report.json (findings sorted by evidence), DIR/report.md with "
                                   "plots and DIR/model.json (the fitted effects and the noise they leave, with "
                                   "the IMU's low-pass when its spectrum rolls off, usable as a `rig simulate` "
                                   "effect list). See docs/diagnosis.md.")
    p.add_argument("recording", type=Path, help="recording (MCAP, or a flight log of the shared data)")
    _survey_option(p)
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
                                   "IMU low-pass (a flight's noise is its own). See docs/diagnosis.md.")
    p.add_argument("models", type=Path, nargs="+", help="DIR/model.json files of `rig diagnose`")
    p.add_argument("--config", type=Path, required=True, help="the simulation config to update")
    p.set_defaults(func=cmd_combine_models)

    p = sub.add_parser("inject", help="a recording as if effects of the catalog had been present",
                       description="Add catalog effects to a recording (real or simulated): TDOA values change "
                                   "by what the effects change in the simulator along the ground truth, UWB "
                                   "stamps move with timing effects, IMU effects act on the recorded readings. "
                                   "The recording keeps its own noise and effects (use it as the control).")
    p.add_argument("recording", type=Path, help="recording (MCAP, or a flight log of the shared data)")
    _survey_option(p)
    p.add_argument("--effects", required=True,
                   help='JSON text or file: [{"effect": "anchor_delay", "params": {"anchor": 3, "meters": 0.1}}]')
    p.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    p.add_argument("--seed", type=int, default=0, help="seed of random effects (nlos, noise)")
    p.set_defaults(func=cmd_inject)

    p = sub.add_parser("metrics", help="score an estimate stream against a recording's ground truth",
                       description="Align estimates with ground truth (interpolated), keep the flight segment, "
                                   "report 3D/per-axis RMSE, max and percentiles.")
    p.add_argument("recording", type=Path, help="recording with the ground truth")
    p.add_argument("--estimates", type=Path, required=True, help="CSV t,x,y,z or MCAP with an estimate topic")
    p.add_argument("--json", type=Path, help="write the metrics here")
    p.add_argument("--plot", type=Path, help="write a PNG of trajectory and error here")
    _add_segment_options(p)
    p.set_defaults(func=cmd_metrics)

    p = sub.add_parser("evaluate", help="replay a recording through the C estimator (in-process) and score it",
                       description="Run the real C estimator (native library) over a recording from take-off: "
                                   "IMU-driven error-state EKF, TDOA updates, bias network, robust update. "
                                   "Writes rmse_3d, rmse_xyz, diverged and measurement counts. Exit status 1 "
                                   "when the estimate diverged.")
    _add_estimator_options(p)
    p.add_argument("--json", type=Path, help="write the metrics here")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("train", help="train the TDOA bias network on the shared flights (torch, CPU)",
                       description="Build the dataset (14 features from the C feature code at the estimator's own "
                                   "pose, label = measured - true TDOA, |error| <= 1 m, in flight), split by "
                                   "flight 70/15/15, train the 14-30-30-30-1 network with early stopping from a "
                                   "few initialisations, keep the one the estimator does best with on the "
                                   "validation flights and write the model JSON and a provenance file. Seeded "
                                   "and reproducible.")
    p.add_argument("--flights", nargs="+", metavar="PREFIX", help="use flights whose names start with these")
    p.add_argument("--apart-from", type=Path, metavar="MODEL",
                   help="leave out the flights this model (a `rig train` output) trained on, so that it can be "
                        "tested on what this one learns (how recordings/room_bias_net.json is made)")
    p.add_argument("--test", nargs="+", metavar="PREFIX",
                   help="these flights are the test set (default: a seeded 15%% of the flights)")
    p.add_argument("--exclude-anchors", metavar="K,K", help="leave these anchors out of training; test on them")
    p.add_argument("--features", choices=("14", "10"), default="14",
                   help="10 drops the anchors' orientation (the tag's angles in each anchor's frame)")
    p.add_argument("--features-from", choices=FEATURES_FROM, default=FEATURES_FROM[0],
                   help="the tag pose the features are computed from: the estimator's own (a replay without "
                        "correction; what the network sees in flight) or the ground truth")
    p.add_argument("--seed", type=int, default=0, help="seeds the flight split and the initialisations")
    p.add_argument("--restarts", type=int, default=TrainConfig().restarts,
                   help="train from this many initialisations and keep the best on the validation flights "
                        "(default %(default)s)")
    p.add_argument("--select-by", choices=SELECT_BY, default=SELECT_BY[0],
                   help="choose the kept restart by the robust estimator's mean 3D RMSE replaying the validation "
                        "flights with it (default), or by the validation TDOA error (no replay; always used "
                        "with --exclude-anchors)")
    p.add_argument("--max-epochs", type=int, default=TrainConfig().max_epochs)
    p.add_argument("--out", type=Path, default=DEFAULT_NETWORK)
    p.add_argument("--dataset-cache", type=Path, help="reuse (or write) the dataset here (.npz)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("farm", help="replay into many boards in parallel through zenoh (one bridge per board)",
                       description="Open a zenoh router session here, start one `bridge` process per board "
                                   "(connected to it), and replay every job through zenoh at once. Jobs: each "
                                   "recording on each target when either list has one entry, else pairwise. "
                                   "Writes OUT/boardK/{run.mcap,metrics.json,report.html} and OUT/farm.json.")
    p.add_argument("recordings", type=Path, nargs="+")
    p.add_argument("--target", action="append", help="repeatable: native, native-udp, qemu, serial:URL, ...")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--duration", type=float, help="seconds of each recording to replay")
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="the router's endpoint (default %(default)s)")
    p.add_argument("--no-nn", action="store_true", help="without the bias network")
    p.set_defaults(func=cmd_farm)

    p = sub.add_parser("router", help="a zenoh router (a Python session in router mode) for boards and rigs",
                       description="Run a zenoh router on explicit endpoints (no multicast scouting) until "
                                   "Ctrl-C: bridges, replays and watchers on other processes or hosts connect to it.")
    p.add_argument("--listen", action="append", required=True, metavar="ENDPOINT", help="e.g. tcp/0.0.0.0:7447")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=cmd_router)

    p = sub.add_parser("watch", help="subscribe to boards' estimates on zenoh and count them",
                       description="Subscribe to rig/board/BOARD/estimate through a router and count what arrives; "
                                   "exit when --count estimates arrived (exit 1 if they did not within --timeout).")
    p.add_argument("--connect", action="append", required=True, metavar="ENDPOINT")
    p.add_argument("--board", default="*", help="board name or * (default)")
    p.add_argument("--count", type=int, help="stop after this many estimates")
    p.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds")
    p.add_argument("--json", type=Path, help="write the counts and the last estimate of each board")
    p.set_defaults(func=cmd_watch)

    p = sub.add_parser("report", help="write DIR/report.html from a replay's run.mcap and metrics.json",
                       description="The trajectory against ground truth, the error over time, per-anchor "
                                   "innovation statistics and the window-cost histogram against the budget, as "
                                   "one self-contained HTML page (also written at the end of every replay).")
    p.add_argument("dir", type=Path, help="a replay's output directory")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("bench", help="per-call and per-window cost on native and QEMU against a baseline",
                       description="Replay a fixed segment in strict lock-step into the native program (ns) and "
                                   "the QEMU firmware (instructions, deterministic), print per-call and per-window "
                                   "figures and compare them with the committed baseline; exit 1 when a figure "
                                   "grew by more than its threshold (instructions 5%%, ns 50%%).")
    p.add_argument("recording", type=Path, nargs="?", default=paths.default_recording(),
                   help="recording (default: the shipped default recording)")
    p.add_argument("--targets", default="native,qemu", help="comma-separated: native, qemu (default both)")
    p.add_argument("--baseline", type=Path, default=paths.BENCH_BASELINE, help="baseline file (default: the "
                   "committed benchmarks/baseline.json)")
    p.add_argument("--update-baseline", action="store_true", help="measure and write the baseline instead")
    p.add_argument("--start", type=float, help="segment start when writing a baseline (default: take-off)")
    p.add_argument("--duration", type=float, default=20.0, help="segment length when writing a baseline")
    p.add_argument("--threshold", type=float, metavar="FRACTION", help="one threshold for every unit")
    p.add_argument("--json", type=Path, default=Path("out/bench.json"), help="figures and comparison")
    p.add_argument("--program", type=Path, help="native program to measure (default: build it)")
    p.add_argument("--firmware", type=Path, help="firmware ELF to measure (default: build it)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("replay", help="replay a recording into a board (native, QEMU or serial) in lock-step",
                       description="Build what the target needs, start it (native program on a pty, firmware in "
                                   "QEMU netduinoplus2) or open the port (serial:URL, any pyserial URL), "
                                   "handshake, configure, then stream IMU and TDOA one 10 ms window at a time, "
                                   "waiting for each estimate. Writes DIR/metrics.json (accuracy, timing).")
    _add_estimator_options(p)
    p.add_argument("--target", default="native",
                   help="native (program on a pty), native-udp (its UDP endpoint through cflib's udp:// driver), "
                        "qemu, serial:URL (any pyserial URL), crazyflie:URI (cflib radio://, usb://, udp://) or "
                        "zenoh:NAME (a board served by a `bridge` process); default native")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--start", type=float, help="start time on the recording's clock (default 1 s before take-off)")
    p.add_argument("--duration", type=float, help="seconds to replay (default: to the end)")
    p.add_argument("--board", default="local", help="board name on zenoh for a local target (default local)")
    p.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help="zenoh endpoint (a router, e.g. tcp/127.0.0.1:7447) where boards and subscribers meet")
    p.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                   help="zenoh endpoint to listen on (subscribers connect here)")
    p.add_argument("--lookahead", type=int, default=0, metavar="N",
                   help="windows sent ahead of the awaited estimate (default 0: strict lock-step). Estimates "
                        "are identical; the link's idle time shrinks, but receive interrupts then land inside "
                        "measured calls (a few instructions each)")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                   help="lockstep (default): send a window, wait for its estimate, so results do not depend on "
                        "link or host speed. realtime: send each window when the recording's clock says it is "
                        "due whatever the board does; measures input-to-estimate latency and counts late "
                        "windows (estimate after the next window was due), missed windows and overruns")
    p.add_argument("--speed", type=float, default=1.0, metavar="X",
                   help="real-time mode: play the recording's clock X times faster (default 1)")
    p.add_argument("--assert-rmse", type=float, metavar="M", help="exit 1 when rmse_3d exceeds M metres")
    p.add_argument("--assert-budget", type=float, metavar="FRACTION",
                   help="exit 1 when the worst window exceeds FRACTION of the 10 ms budget")
    p.add_argument("--assert-deadlines", action="store_true",
                   help="real-time mode: exit 1 when any window is late or missed")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("size", help="flash, RAM and stack of the estimator for the STM32F405",
                       description="Build the estimator for Cortex-M4F and report flash and RAM (static + worst "
                                   "stack) from arm-none-eabi-size and -fstack-usage. Exit status 1 when over "
                                   "the budget (13 kB flash, 12 kB RAM).")
    p.add_argument("--json", type=Path, help="write the figures here")
    p.set_defaults(func=cmd_size)

    p = sub.add_parser("demo", help="the main job: the default recording into the native and QEMU targets",
                       description="Replay the default recording into the native program and the STM32F405 "
                                   "firmware in QEMU in lock-step; assert RMSE <= 0.40 m, the worst 10 ms window "
                                   "under QEMU (the p99 window of the native program, whose wall clock counts "
                                   "the host's preemptions) <= 20%% of the budget and native/QEMU agreement "
                                   "within 2 mm; write "
                                   "OUT/<target>/metrics.json. The estimator runs with the shipped bias network: the "
                                   "default recording carries a pose-dependent bias learned from real flights the "
                                   "shipped network did not train on.")
    p.add_argument("--recording", type=Path, default=paths.default_recording())
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--nn", action=argparse.BooleanOptionalAction, default=True,
                   help="correct with the shipped bias network (default; --no-nn: the robust estimator alone)")
    p.set_defaults(func=cmd_demo)
    return parser


def _add_estimator_options(p: argparse.ArgumentParser) -> None:
    """The recording and the estimator configuration, shared by evaluate and replay."""
    p.add_argument("recording", type=Path, nargs="?", default=paths.default_recording(),
                   help="MCAP recording or shared flight log (default: the shipped default recording)")
    _survey_option(p)
    p.add_argument("--no-nn", action="store_true", help="no bias-network correction")
    p.add_argument("--no-robust", action="store_true", help="plain EKF update instead of M-estimation")
    p.add_argument("--model", type=Path, help="bias network JSON (default: the shipped model)")


def _survey_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--survey", type=Path, help="anchor survey of a flight log (default: anchor_MMDD.txt of the "
                                               "log's day, beside its flights directory or in the shared data)")


def _add_segment_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--min-height", type=float, default=0.3, help="score only above this height (m)")
    p.add_argument("--skip-after-takeoff", type=float, default=5.0, help="seconds after take-off not scored")


def main(argv: list[str] | None = None) -> int:
    from rig.errors import USER_ERRORS

    # a rig that seems stuck says where: `kill -USR1 PID` prints every thread's stack
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (CliError, *USER_ERRORS) as exc:
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"rig {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
