"""`rig evaluate`, `rig metrics` and `rig size`: the C estimator in-process, estimates
scored against ground truth, and the estimator's footprint on the board."""

from __future__ import annotations

import argparse
from pathlib import Path

from rig.cli.common import (EXIT_FAILED, EXIT_OK, add_estimator_options, add_segment_options,
                             add_start_pose_options, anchor_weighting_params, print_accuracy, print_imu_gaps,
                             start_pose, write_json)


def cmd_metrics(args: argparse.Namespace) -> int:
    from rig.data.recording import read_recording
    from rig.estimator import metrics

    truth = read_recording(args.recording).truth
    t, pos = metrics.read_estimates(args.estimates)
    rule = metrics.SegmentRule(min_height=args.min_height, skip_after_takeoff=args.skip_after_takeoff)
    result = metrics.score(t, pos, truth, rule)
    print_accuracy(result)
    write_json(args.json, result)
    if args.plot:
        metrics.plot(t, pos, truth, args.plot, rule, title=str(args.estimates))
    return EXIT_OK


def cmd_evaluate(args: argparse.Namespace) -> int:
    from rig.data.importer import load_any
    from rig.estimator.evaluate import evaluate

    given = start_pose(args)
    rec = load_any(args.recording, args.survey, strict=args.strict)
    result = evaluate(rec, robust=not args.no_robust, use_nn=not args.no_nn, model_path=args.model,
                      full_trust=args.full_trust, start_pose=given, **anchor_weighting_params(args))
    result["recording"] = str(args.recording)
    config = ("robust" if not args.no_robust else "plain") + (" + bias network" if result["config"]["bias_net"] else "") \
        + (" + blocked-anchor weighting" if result["config"]["params"]["anchor_bias_c"] > 0 else "")
    print(f"{args.recording}: C estimator ({config}), {result['flight_seconds']:.1f} s replayed in "
          f"{result['estimator_seconds'] * 1e3:.1f} ms of estimator time")
    print_accuracy(result)
    if result["config"]["bias_net"] and "score_error" not in result:
        add_correction_effect(result, rec, args.model)
    # the update rejects by its gate or by a robust weight near zero; the rest of the
    # reasons refuse a measurement before it reaches the update (counted apart)
    by_reason = result["rejected_by_reason"]
    refused = ", ".join(f"{k} {v}" for k, v in by_reason.items() if v and k != "gate") or "none"
    print(f"TDOA: {result['tdoa_accepted']} accepted, {result['tdoa_downweighted']} down-weighted, "
          f"{result['tdoa_rejected']} rejected (gate {by_reason['gate']}, robust weight "
          f"{result['tdoa_rejected'] - by_reason['gate']}); refused before the update: {refused}; "
          f"resets {result['resets']}; diverged: {'yes' if result['diverged'] else 'no'}")
    if result["config"]["params"]["anchor_bias_c"] > 0:
        add_anchor_discounts(result, rec, args, given)
    print_imu_gaps(result)
    write_json(args.json, result)
    return EXIT_FAILED if result["diverged"] else EXIT_OK


def add_anchor_discounts(result: dict, rec, args: argparse.Namespace, given) -> None:
    """Which anchors the blocked-anchor weighting discounted, and for how much of the
    flight, into `result` (`anchor_discounted`) and printed."""
    from rig.estimator.evaluate import anchor_discounts, estimator_config

    params, model = estimator_config(not args.no_robust, not args.no_nn, args.model, None, args.full_trust,
                                     **anchor_weighting_params(args))
    result["anchor_discounted"] = shares = anchor_discounts(rec, params, model, given)
    most = sorted(((share, k) for k, share in shares.items() if share > 0), reverse=True)
    which = ", ".join(f"anchor {k} {share:.0%}" for share, k in most) or "none"
    print(f"blocked anchors: {result['tdoa_anchor_weighted']} TDOA down-weighted by the tracked range bias of "
          f"their anchors; discounted for a share of the flight: {which} (--no-anchor-weighting: none)")


def add_correction_effect(result: dict, rec, model_path: Path | None) -> None:
    """The correction's effect on the recording's TDOA errors, into `result` and printed. It
    adds to the score and must not cost it: a recording it cannot measure says why
    (`correction_effect_error`) and the score stands."""
    from rig.bias.effect import correction_effect
    from rig.data.errors import InputError
    from rig.estimator.evaluate import load_model

    try:
        result["correction_effect"] = effect = correction_effect(rec, load_model(model_path))
    except (InputError, ValueError, IndexError) as exc:
        result["correction_effect_error"] = f"{type(exc).__name__}: {exc}"
        print(f"the whole bias correction on the TDOA errors: not measured ({result['correction_effect_error']})")
        return
    print_correction_effect(effect)


def print_correction_effect(effect: dict | None, most: int = 5) -> None:
    """The correction's effect on the TDOA errors, and the pairs it makes worse, the worst first."""
    if effect is None:
        return
    rms, pairs = effect["tdoa_error_rms_m"], effect["per_pair"]
    worse = [f"{k} ({pairs[k]['before']:.3f} → {pairs[k]['after']:.3f} m)" for k in effect["worse_pairs"][:most]]
    more = len(effect["worse_pairs"]) - len(worse)
    print(f"the whole bias correction on the TDOA errors (against the ground truth): RMS {rms['before']:.3f} → "
          f"{rms['after']:.3f} m; " + (f"larger on anchor pairs {', '.join(worse)}"
                                       + (f" and {more} more" if more > 0 else "") + " (compare with --no-nn)"
                                       if worse else f"smaller on every one of the {len(pairs)} anchor pairs"))


def cmd_size(args: argparse.Namespace) -> int:
    from rig.estimator.footprint import measure

    result = measure()
    est = result["estimator"]
    budget = est["budget"]
    print(f"estimator (Cortex-M4F, -Os): flash {est['flash']} B of {budget['flash']} B budget; "
          f"RAM {est['ram']} B of {budget['ram']} B (static {est['static_ram']} B + stack {est['stack']} B "
          f"via {' > '.join(est['stack_chain'])})")
    fw = result["firmware"]
    print(f"firmware image (-O2, static): flash {fw['flash']} B, RAM {fw['ram']} B (text {fw['text']}, "
          f"data {fw['data']}, bss {fw['bss']})")
    write_json(args.json, result)
    within = est["flash"] <= budget["flash"] and est["ram"] <= budget["ram"]
    return EXIT_OK if within else EXIT_FAILED


def register(sub) -> None:
    p = sub.add_parser("metrics", help="score an estimate stream against a recording's ground truth",
                       description="Align estimates with ground truth (interpolated), keep the flight segment, "
                                   "report 3D/per-axis RMSE, max and percentiles.")
    p.add_argument("recording", type=Path, help="recording with the ground truth")
    p.add_argument("--estimates", type=Path, required=True, help="CSV t,x,y,z or MCAP with an estimate topic")
    p.add_argument("--json", type=Path, help="write the metrics here")
    p.add_argument("--plot", type=Path, help="write a PNG of trajectory and error here")
    add_segment_options(p)
    p.set_defaults(func=cmd_metrics)
    p = sub.add_parser("evaluate", help="replay a recording through the C estimator (in-process) and score it",
                       description="Run the real C estimator (native library) over a recording from take-off: "
                                   "IMU-driven error-state EKF, TDOA updates, bias network, robust update. "
                                   "Writes rmse_3d, rmse_xyz, diverged and measurement counts. Exit status 1 "
                                   "when the estimate diverged.")
    add_estimator_options(p)
    add_start_pose_options(p, then="the estimator starts there at the usual time, level, and is scored as ever "
                                   "(how it converges from a misplaced start)")
    p.add_argument("--json", type=Path, help="write the metrics here")
    p.set_defaults(func=cmd_evaluate)
    p = sub.add_parser("size", help="flash, RAM and stack of the estimator for the STM32F405",
                       description="Build the estimator for Cortex-M4F and report flash and RAM (static + worst "
                                   "stack) from arm-none-eabi-size and -fstack-usage. Exit status 1 when over "
                                   "the budget (13 kB flash, 12 kB RAM).")
    p.add_argument("--json", type=Path, help="write the figures here")
    p.set_defaults(func=cmd_size)
