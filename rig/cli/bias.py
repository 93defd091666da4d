"""`rig train`: the TDOA bias network from the shared flights; `rig calibrate`: the
physical link-bias model fitted to them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.bias.config import FEATURES_FROM, SELECT_BY, TrainConfig
from rig.cli.common import EXIT_OK, CliError, anchor_ids, positive, progress, write_json
from rig.data import paths
from rig.data.paths import SHIPPED_BIAS_NET as DEFAULT_NETWORK
from rig.estimator.bias_net import FORMS


def cmd_train(args: argparse.Namespace) -> int:
    from rig.bias.config import DEFAULT_FEATURE_SET, FEATURE_SETS
    from rig.bias.train import provenance_path, run_training, trained_on

    flights = _matching_flights(args.flights)
    if args.apart_from:
        try:
            apart = trained_on(args.apart_from)
        except ValueError as exc:
            raise CliError(str(exc)) from exc
        flights = [f for f in flights if f.name not in apart]
    if not flights:
        raise CliError(f"no flight matches {args.flights or 'all'} apart from {args.apart_from}'s training flights")
    if args.restarts < 1:
        raise CliError(f"--restarts must be at least 1, got {args.restarts}")
    feature_set = args.features or DEFAULT_FEATURE_SET[args.form]
    if FEATURE_SETS[feature_set][0] != args.form:
        raise CliError(f"--features {feature_set} is a {FEATURE_SETS[feature_set][0]} form's set, "
                       f"not the {args.form} form's")
    try:
        config = TrainConfig.with_features(feature_set, seed=args.seed, restarts=args.restarts,
                                           select_by=args.select_by, max_epochs=args.max_epochs,
                                           untranslated=args.untranslated)
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    try:
        prov = run_training(flights, args.out, test_prefixes=args.test, all_flights=args.all_flights,
                            exclude_anchors=args.exclude_anchors or [], config=config,
                            dataset_cache=args.dataset_cache, command=["rig", *sys.argv[1:]],
                            progress=progress(desc="training", total=None), features_from=args.features_from,
                            minus_link_bias=args.minus_link_bias)
    except ValueError as exc:
        raise CliError(str(exc)) from exc
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


def _matching_flights(prefixes: list[str] | None) -> list[Path]:
    flights = [f for f in paths.flights() if any(f.name.startswith(p) for p in prefixes)] if prefixes \
        else paths.flights()
    if not flights:
        raise CliError(f"no flight in {paths.data_dir() / 'flights'} matches {prefixes or 'all'}")
    return flights


def cmd_calibrate(args: argparse.Namespace) -> int:
    from rig.bias.calibrate import calibrate, load_flights
    from rig.sim.effects import LINK_TERMS

    if args.bootstrap < 0:
        raise CliError(f"--bootstrap must be 0 or more, got {args.bootstrap}")
    flights = _matching_flights(args.flights)
    rows = load_flights(flights, progress=progress(desc="flights", total=len(flights)))
    result = calibrate(rows, bootstrap=args.bootstrap, seed=args.seed,
                       progress=progress(desc="resampling flights", total=args.bootstrap))
    std = result["tdoa_error_std_m"]
    print(f"{len(rows)} flights, {result['samples']} measurements: TDOA error std {std['before']:.3f} m, "
          f"{std['after_delays']:.3f} m after each flight's delays, {std['after_link']:.3f} m after the link bias too")
    for name in LINK_TERMS:
        term = result["terms"][name]
        flag = "" if term["within_bound"] else f"  BEYOND the physical bound of {result['bound_m']} m"
        print(f"  {name:14s} {term['value_m']:+.3f} m ± {term['spread_m']:.3f}{flag}")
    write_json(args.out, result)
    print(f"wrote {args.out}")
    return EXIT_OK


def register(sub) -> None:
    register_calibrate(sub)
    register_train(sub)


def register_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="fit the physical link-bias model to the shared flights",
                       description="Fit the range bias every tag-anchor link shares (the anchor's antenna "
                                   "pattern, the tag's and the airframe's, the received power; the simulator's "
                                   "`link_bias` effect) to flights with ground truth, with each flight's anchor "
                                   "delays alongside, robustly; the spread of each coefficient over flights "
                                   "resampled with replacement. Writes the effects (link_bias and the mean "
                                   "anchor delays) ready for a `rig simulate` config.")
    p.add_argument("--flights", nargs="+", metavar="PREFIX", help="use flights whose names start with these")
    p.add_argument("--bootstrap", type=int, default=20, help="resamplings of the flights for the spread")
    p.add_argument("--seed", type=int, default=0, help="seeds the resampling")
    p.add_argument("--out", type=Path, default=Path("link_bias.json"))
    p.set_defaults(func=cmd_calibrate)


def register_train(sub) -> None:
    p = sub.add_parser("train", help="train the TDOA bias network on the shared flights (torch, CPU)",
                       description="Build the dataset (14 features from the C feature code at the estimator's own "
                                   "pose, label = measured - true TDOA, |error| <= 1 m, in flight), split by "
                                   "flight 70/15/15, train the network (link form: 7-20-20-20-1 on each link's 7 "
                                   "of them; pair form: 14-30-30-30-1) with early stopping from a few "
                                   "initialisations, keep the one the estimator does best with on the validation "
                                   "flights and write the model JSON and a provenance file. Seeded, and "
                                   "reproducible to the byte on the same CPU (the provenance names it).")
    p.add_argument("--flights", nargs="+", metavar="PREFIX", help="use flights whose names start with these")
    p.add_argument("--apart-from", type=Path, metavar="MODEL",
                   help="leave out the flights this model (a `rig train` output) trained on, so that it can be "
                        "tested on what this one learns (how recordings/room_bias_net.json is made)")
    p.add_argument("--test", nargs="+", metavar="PREFIX",
                   help="these flights are the test set (default: a seeded 15%% of the flights)")
    p.add_argument("--all-flights", action="store_true",
                   help="hold no flight out for testing: every flight but the validation ones trains (how the "
                        "shipped model is made; its transfer is measured by benchmarks/bias_validation.py)")
    p.add_argument("--exclude-anchors", type=anchor_ids, metavar="K,K", help="leave these anchors out of training; test on them "
                   "(the model leaves measurements with an anchor it was not trained on uncorrected)")
    p.add_argument("--form", choices=FORMS, default=TrainConfig().form,
                   help="link (default): one network of a tag-anchor link's 7 features, TDOA bias = g(B) - g(A); "
                        "pair: a network of the measurement's 14 features (the paper's form)")
    p.add_argument("--features", choices=("14", "10", "7", "shared"),
                   help="pair form: 14 (default) or 10, without the anchors' orientation (the tag's angles in "
                        "each anchor's frame); link form: 7 (default) or shared, only what every anchor shares "
                        "(the tag's angles in the anchor's frame, the anchor's elevation from the tag) with a "
                        "bounded range offset per anchor")
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
    p.add_argument("--max-epochs", type=positive(int), default=TrainConfig().max_epochs)
    p.add_argument("--out", type=Path, default=DEFAULT_NETWORK)
    p.add_argument("--dataset-cache", type=Path, help="reuse (or write) the dataset here (.npz)")
    p.add_argument("--minus-link-bias", action="store_true",
                   help="learn what the calibrated link bias (rig/sim/effects/link_bias.json) leaves of each error: "
                        "the simulator's learned_bias beside its link_bias (restarts chosen by --select-by mse)")
    p.add_argument("--untranslated", action="store_true",
                   help="remove each flight's constant tag offset from its labels, so the correction carries none "
                        "(no flight can tell one from where the tag really is; shipped in sessions 59-62, not "
                        "kept since: docs/notebook/bias.md)")
    p.set_defaults(func=cmd_train)
