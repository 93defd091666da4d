"""The hardware-in-the-loop commands: `rig replay`, `rig demo`, `rig bench`, `rig report`,
`rig farm`, and the zenoh helpers `rig router` and `rig watch`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    BoardError,
    CliError,
    add_estimator_options,
    add_start_pose_options,
    no_anchor_weighting_option,
    no_nn_option,
    print_accuracy,
    print_imu_gaps,
    positive,
    progress,
    start_pose,
    write_json,
)
from rig.data import paths


def replay_into(recording: Path, target: str, out: Path, estimator, junit: Path | None = None, **options) -> dict:
    """One replay job (rig.hil.job) with its summary printed; a board that failed is a
    one-line error that names what was kept (and, with `junit`, a failed testcase)."""
    from rig.hil.checks import replay_cases, write_junit
    from rig.hil.job import JobFailed, replay_job

    try:
        result = replay_job(recording, target, out, estimator, progress=progress(desc=f"replay {target}"),
                            on_scored=print_score, **options)
    except JobFailed as exc:
        if junit is not None:
            write_junit(junit, "rig.replay", [replay_cases(target, [], exc.result)])
        raise BoardError(str(exc)) from exc
    print_written(result, report=options.get("report", True))
    if result["run_record_error"]:
        raise CliError(result["run_record_error"])
    return result


def print_replay(result: dict, report: bool = True) -> None:
    """What a replay measured, in a few lines, and what it wrote."""
    print_score(result)
    print_written(result, report)


def print_score(result: dict) -> None:
    """What a replay measured, in a few lines (before its files are written)."""
    import math

    timing = result.get("timing")
    if not timing:
        print(f"{result['recording']} -> {result['target']}: no estimate")
        return
    print(f"{result['recording']} -> {result['target']}: {result['n_estimates']} estimates in "
          f"{result['loop_seconds']:.2f} s ({result['speed']:.2f}x real time, "
          f"{result['bytes_sent'] / max(1, result['n_estimates']):.0f} B up and "
          f"{result.get('bytes_received', 0) / max(1, result['n_estimates']):.0f} B down a window; "
          f"{result['wall_seconds']:.1f} s with start-up and the run record)")
    print_accuracy(result)
    print_imu_gaps(result)
    print_timing(timing)
    if "realtime" in result:
        rt = result["realtime"]
        lat = rt["latency_ms"] or {"p50": math.nan, "p99": math.nan, "max": math.nan}
        slowest = f" ({rt['slowest_t_us'] / 1e6:.2f} s in)" if rt.get("slowest_t_us") is not None else ""
        print(f"real time x{rt['speed']:g}: latency p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms, max "
              f"{lat['max']:.1f} ms{slowest}; late windows {rt['late_windows']} (deadline {rt['deadline_ms']:.1f} ms), "
              f"missed windows {rt['missed_windows']}")
    lost = result.get("board_link", {})
    if lost.get("bytes_dropped") or lost.get("frames_bad"):
        print(f"board link: {lost['frames_bad']} corrupt frames, {lost['bytes_dropped']} bytes dropped "
              f"({', '.join(f'{m}: {n}' for m, n in lost['reports'].items())})")


def print_timing(timing: dict) -> None:
    if not timing.get("windows"):          # compact answers cut short before the first full one
        print("timing: no full answer came")
        return
    every = timing.get("full_answer_every", 1)
    print(f"timing ({timing['unit']}{f', the worst of every {every} windows' if every > 1 else ''}): window p50 "
          f"{timing['window_p50']:.0f}, p99 {timing['window_p99']:.0f}, max {timing['window_max']:.0f} = "
          f"{timing['window_max_fraction_of_budget']:.1%} of the {timing['budget']:.0f} budget; overruns "
          f"{timing['overruns']}")


def print_written(result: dict, report: bool = True) -> None:
    out = Path(result["run_record"]).parent
    if report:
        print(f"wrote {out / 'metrics.json'}, {out / 'run.mcap'} and {out / 'report.html'}")
    else:
        print(f"wrote {out / 'metrics.json'} and {out / 'run.mcap'}")


def estimator_choice(args: argparse.Namespace):
    from rig.hil.job import EstimatorChoice

    return EstimatorChoice(use_nn=not args.no_nn, robust=not getattr(args, "no_robust", False),
                           model_path=getattr(args, "model", None), full_trust=getattr(args, "full_trust", False),
                           anchor_weighting=not getattr(args, "no_anchor_weighting", False))


def cmd_replay(args: argparse.Namespace) -> int:
    from rig.hil.checks import checks, replay_cases, write_junit
    from rig.hil.job import check_options
    from rig.hil.zenoh import open_session

    check_options(args.target, args.board, args.start, args.duration, args.lookahead, args.speed,
                  args.full_answer_every, args.late_allowed)
    pose = start_pose(args)
    session = open_session(None, args.zenoh_listen, args.zenoh_connect)
    try:
        result = replay_into(args.recording, args.target, args.out, estimator_choice(args), start=args.start,
                             duration=args.duration, lookahead=args.lookahead,
                             full_answer_every=args.full_answer_every,
                             speed=args.speed if args.mode == "realtime" else None, session=session,
                             board=args.board, survey=args.survey, junit=args.junit_xml, strict=args.strict,
                             start_pose=pose)
    finally:
        session.close()
    asserted = checks(result, args.assert_rmse, args.assert_budget, deadlines=args.assert_deadlines,
                      late_allowed=args.late_allowed)
    if args.junit_xml:
        write_junit(args.junit_xml, "rig.replay", [replay_cases(args.target, asserted, result)])
    failed = [c.message for c in asserted if not c.passed]
    for reason in failed:
        print(f"rig replay: assertion failed: {reason}", file=sys.stderr)
    return EXIT_FAILED if failed else EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """The README's main job: the default recording into the native program and the QEMU
    firmware in lock-step, accuracy and timing asserted, the two targets compared."""
    from rig.hil.checks import demo
    from rig.hil.job import EstimatorChoice

    estimator = EstimatorChoice(use_nn=args.nn)
    _, gap, failed = demo(args.recording, args.out,
                          lambda recording, target, out: replay_into(recording, target, out, estimator))
    print(f"native and QEMU RMSE differ by {gap * 1e3:.2f} mm")
    for reason in failed:
        print(f"rig demo: check failed: {reason}", file=sys.stderr)
    return EXIT_FAILED if failed else EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from rig.hil.report import write_report
    from rig.hil.runrecord import RUN_FILE, finish_run_record

    record = args.dir / RUN_FILE
    if args.finish:
        print(f"{record}: {finish_run_record(record)}")
    print(f"wrote {write_report(args.dir)}")
    return EXIT_OK


def cmd_farm(args: argparse.Namespace) -> int:
    """Many boards at once (rig.hil.farm); exit 1 when any board failed."""
    from rig.hil.checks import replay_cases, write_junit
    from rig.hil.farm import FARM_FILE, farm_jobs, run_farm

    try:
        jobs = farm_jobs(args.recordings, args.target or ["native"])
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    results = run_farm(jobs, args.out, args.listen, estimator_choice(args), args.duration,
                       on_replayed=lambda result: print_replay(result, report=False), start_pose=start_pose(args))
    for k, r in enumerate(results):
        print(f"board{k} ({r['target']}, {r['recording']}): {farm_state(r)}")
    print(f"wrote {args.out / FARM_FILE}")
    if args.junit_xml:
        write_junit(args.junit_xml, "rig.farm", [replay_cases(f"board{k}", [], r) for k, r in enumerate(results)])
        print(f"wrote {args.junit_xml}")
    return EXIT_FAILED if any(r.get("error") for r in results) else EXIT_OK


def farm_state(result: dict) -> str:
    """One board's line in the farm's summary: its error, else its score (or why none)."""
    if result.get("error"):
        return result["error"]
    score = f"RMSE {result['rmse_3d']:.3f} m" if "rmse_3d" in result else f"not scored ({result['score_error']})"
    return f"{score}, {result['n_estimates']} estimates"


def cmd_bench(args: argparse.Namespace) -> int:
    from rig.data.importer import load_any
    from rig.hil import bench
    from rig.hil.links import LinkError

    unknown = [t for t in args.targets.split(",") if t not in bench.TARGETS]
    if unknown:
        raise CliError(f"rig bench measures {' and '.join(bench.TARGETS)}, not {', '.join(map(repr, unknown))}")
    rec = load_any(args.recording)
    baseline = None if args.update_baseline else bench.load_baseline(args.baseline)
    if baseline is not None:
        try:
            bench.check_same_recording(baseline, args.recording)
        except ValueError as exc:
            raise CliError(str(exc)) from None
    start, duration = (args.start, args.duration) if baseline is None else bench.run_settings(baseline)
    binaries = {"native": args.program, "qemu": args.firmware}
    current = []
    for target in args.targets.split(","):
        try:
            current.append(bench.measure(target, rec, start, duration, binaries.get(target)))
        except LinkError as exc:
            if args.junit_xml and baseline is not None:
                from rig.hil.checks import Check, write_junit

                write_junit(args.junit_xml, "rig.bench", [(target, [Check("replay", False, str(exc))], 0.0)])
            raise BoardError(str(exc)) from exc
    document = bench.baseline_document(current, args.recording, start, duration)
    if baseline is None:
        write_json(args.baseline, document)
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
    write_json(args.json, {**document, "baseline": str(args.baseline), "comparison": rows,
                           "regressions": len(regressed)})
    if args.junit_xml:
        from rig.hil.checks import write_junit

        write_junit(args.junit_xml, "rig.bench", bench_cases(rows))
    for r in regressed:
        print(f"rig bench: {r['target']} {r['figure']} regressed by {r['ratio'] - 1:.1%} "
              f"(threshold {r['threshold']:.0%})", file=sys.stderr)
    return EXIT_FAILED if regressed else EXIT_OK


def bench_cases(rows: list[dict]) -> list:
    """One testcase per figure of each target: the current figure against the baseline's
    and its threshold (figures the bench does not compare pass, saying so)."""
    from rig.hil.checks import Check

    groups: dict[str, list] = {}
    for r in rows:
        bar = f"baseline {r['baseline']:.0f}, threshold +{r['threshold']:.0%}" if r["compared"] else "not compared"
        groups.setdefault(r["target"], []).append(Check(
            r["figure"], not r["regressed"], f"{r['current']:.0f} {r['unit']} (ratio {r['ratio']:.3f}; {bar})"))
    return [(target, group, 0.0) for target, group in groups.items()]


def cmd_router(args: argparse.Namespace) -> int:
    import threading

    from rig.hil.zenoh import open_session, wait_interruptibly

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
    from rig.hil.zenoh import EstimateCounter, open_session, wait_interruptibly

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
    write_json(args.json, result)
    for board, n in sorted(counter.counts.items()):
        print(f"{board}: {n} estimates")
    return EXIT_OK if args.count is None or sum(counter.counts.values()) >= args.count else EXIT_FAILED


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a recording into a board (native, QEMU or serial) in lock-step",
                       description="Build what the target needs, start it (native program on a pty, firmware in "
                                   "QEMU netduinoplus2) or open the port (serial:URL, any pyserial URL), "
                                   "handshake, configure, then stream IMU and TDOA one 10 ms window at a time, "
                                   "waiting for each estimate. Writes DIR/metrics.json (accuracy, timing).")
    add_estimator_options(p)
    p.add_argument("--target", default="native",
                   help="native (program on a pty), native-udp (its UDP endpoint through cflib's udp:// driver), "
                        "qemu (the STM32F405 firmware in QEMU, through the bulk link), qemu-usart (the same through "
                        "its emulated USART), serial:URL (any pyserial URL), crazyflie:URI (cflib radio://, usb://, udp://) or "
                        "zenoh:NAME (a board served by a `bridge` process); default native")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--start", type=float, help="start time on the recording's clock (default 1 s before take-off)")
    p.add_argument("--duration", type=float, help="seconds to replay (default: to the end)")
    add_start_pose_options(p)
    p.add_argument("--board", default="local", help="board name on zenoh for a local target (default local)")
    p.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help="zenoh endpoint (a router, e.g. tcp/127.0.0.1:7447) where boards and subscribers meet")
    p.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                   help="zenoh endpoint to listen on (subscribers connect here)")
    p.add_argument("--lookahead", type=int, metavar="N",
                   help="windows kept in flight ahead of the one awaited, with the same answers (default: "
                        "2 on the native program, else 0: strict lock-step). The link's idle time shrinks, but "
                        "a board's receive interrupts then land inside measured calls")
    p.add_argument("--full-answer-every", type=int, default=1, metavar="N",
                   help="compact answers: the board's counters and timing with every N-th window's estimate "
                        "(and the last one's), the timing then of the most expensive window since the last; the "
                        "other windows get the estimate and attitude only, half the bytes down (for links "
                        "with few packets a second, as a Crazyflie radio). Same estimates; default 1, "
                        "every answer full")
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
                   help="real-time mode: exit 1 when any window is missed or late (see --late-allowed)")
    p.add_argument("--late-allowed", type=float, default=0.0, metavar="FRACTION",
                   help="with --assert-deadlines: tolerate late windows up to FRACTION of those sent (default 0; "
                        "a shared CI host stalls the rig or QEMU for a few ms now and then). A missed window "
                        "always fails")
    p.add_argument("--junit-xml", type=Path, metavar="FILE",
                   help="write a JUnit XML report: one testcase for the board and one per assertion, a failure "
                        "carrying the measured figure and its bar")
    p.set_defaults(func=cmd_replay)
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
    p.add_argument("--threshold", type=positive(float), metavar="FRACTION", help="one threshold for every unit")
    p.add_argument("--json", type=Path, default=Path("out/bench.json"), help="figures and comparison")
    p.add_argument("--program", type=Path, help="native program to measure (default: build it)")
    p.add_argument("--firmware", type=Path, help="firmware ELF to measure (default: build it)")
    p.add_argument("--junit-xml", type=Path, metavar="FILE",
                   help="write a JUnit XML report: one testcase per figure of each target, a regression "
                        "failing with its figure, the baseline's and the threshold")
    p.set_defaults(func=cmd_bench)
    p = sub.add_parser("report", help="write DIR/report.html from a replay's run.mcap and metrics.json",
                       description="The trajectory against ground truth, the error over time, per-anchor "
                                   "innovation statistics and the window-cost histogram against the budget, as "
                                   "one self-contained HTML page (also written at the end of every replay).")
    p.add_argument("dir", type=Path, help="a replay's output directory")
    p.add_argument("--finish", action="store_true",
                   help="first finish an unfinished run.mcap (a rig killed with SIGKILL, a power loss): cut it at "
                        "its last whole record and close it, so that any MCAP reader opens it")
    p.set_defaults(func=cmd_report)
    p = sub.add_parser("farm", help="replay into many boards in parallel through zenoh (one bridge per board)",
                       description="Open a zenoh router session here, start one `bridge` process per board "
                                   "(connected to it), and replay every job through zenoh at once. Jobs: each "
                                   "recording on each target when either list has one entry, else pairwise. "
                                   "Writes OUT/boardK/{run.mcap,metrics.json,report.html} and OUT/farm.json.")
    p.add_argument("recordings", type=Path, nargs="+")
    add_start_pose_options(p)
    p.add_argument("--target", action="append", help="repeatable: native, native-udp, qemu, serial:URL, ...")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--duration", type=float, help="seconds of each recording to replay")
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="the router's endpoint (default %(default)s)")
    no_nn_option(p)
    no_anchor_weighting_option(p)
    p.add_argument("--junit-xml", type=Path, metavar="FILE",
                   help="write a JUnit XML report: one testcase per board (its replay ran to its end), a "
                        "failure carrying its error")
    p.set_defaults(func=cmd_farm)
    p = sub.add_parser("router", help="a zenoh router (a Python session in router mode) for boards and rigs",
                       description="Run a zenoh router on explicit endpoints (no multicast scouting) until "
                                   "Ctrl-C: bridges, replays and watchers on other processes or hosts connect to it.")
    p.add_argument("--listen", action="append", required=True, metavar="ENDPOINT", help="e.g. tcp/0.0.0.0:7447")
    p.add_argument("--duration", type=positive(float), help="stop after this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=cmd_router)
    p = sub.add_parser("watch", help="subscribe to boards' estimates on zenoh and count them",
                       description="Subscribe to rig/board/BOARD/estimate through a router and count what arrives; "
                                   "exit when --count estimates arrived (exit 1 if they did not within --timeout).")
    p.add_argument("--connect", action="append", required=True, metavar="ENDPOINT")
    p.add_argument("--board", default="*", help="board name or * (default)")
    p.add_argument("--count", type=positive(int), help="stop after this many estimates")
    p.add_argument("--timeout", type=positive(float), default=600.0, help="give up after this many seconds")
    p.add_argument("--json", type=Path, help="write the counts and the last estimate of each board")
    p.set_defaults(func=cmd_watch)
