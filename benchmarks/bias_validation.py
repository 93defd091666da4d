"""Honest validation of the bias correction: does it transfer to flights, days, modes,
anchors and places it was not trained on? Regenerates docs/notebook/bias-validation.md,
the table of estimates in docs/bias.md and its figure, docs/img/bias_validation.png
(every split and form: 71 min on two cores before session 77 added within-0425, whose
nine networks took 5 min a form on an AMD EPYC).

    .venv/bin/python benchmarks/bias_validation.py [--forms link shared pair] [--seeds 0 1 2]
        [--splits day-0426 day-0425 mode-tdoa3 mode-tdoa2 within-0426 setup-0426 day-0422 within-0425 anchors
         region sector]
        [--json docs/notebook/bias-validation.json] [--doc PAGE]
        [--fresh] [--from-json] [--save-models DIR]

Rows are merged into --json by split, form, seed and anchor (a run of one form keeps the
others' rows); --fresh starts from none. The JSON is kept beside the page, so that
`--from-json` rewrites both pages from it without training (a test checks they agree),
and every row says the MKL branch it was trained on (`mkl_cbwr`). A run into another
JSON (an experiment) writes its page beside that JSON and leaves docs/ alone.
`--save-models DIR` keeps the networks of the day, mode and within splits, so that a
change on the estimator's side is judged on the kept rows' very networks without
training again (`model_path`).

Forms (rig train --features): link, the link form's 7 features; shared, the link form on
the features every anchor shares, with a bounded range offset per anchor; pair, the
paper's 14-feature network. Also untranslated (session 59): the link form on labels
without each flight's constant tag offset (`rig train --untranslated`), as the shipped
model was trained in sessions 59–62; reported on every split but not ranked among the forms, since
benchmarks/tag_offset.py decided it by its own rule. Forms tried and removed are not
run here; their figures are in docs/notebook/bias.md and their tags run them into this
JSON (not ranked either): offset (session 60, experiment/tag-offset-constant), the form
carrying its training flights' median tag offset as one constant, and huber (session 62,
experiment/huber-loss), the untranslated form trained on the Huber loss, and distilled
(session 65, experiment/distill), the link form's restarts distilled into one network,
refit (session 65, experiment/refit), its chosen restart trained again with the
validation flights, and six-restarts (session 65, experiment/six-restarts; on fresh
seeds in session 66, experiment/six-restarts-replication), the link form choosing among
six restarts instead of three, and installation (session 68,
experiment/installation-delays), the link network trained without each flight's anchor
delays, which the model kept per installation (its survey) and applied only to a
recording of that installation, and weight-decay (session 71, experiment/weight-decay),
the link form trained with an L2 penalty of 1e-3, and balanced-days (session 71,
experiment/balanced-days), the link form trained with every day of flights weighing the
same in the loss. benchmarks/form_rule.py judges such a form against the link rows.

Since session 69 the estimator applies only the share of the correction that the
flight's own measurements support (`trust_prior_n`; docs/reference/estimator.md), kept
by the rule in benchmarks/trust_rule.py, fixed before its first run. Every flight's row
also holds its figure with the whole correction applied (`rmse_3d_full_trust`, the
estimator before session 69) and the share applied at the end (`correction_trust`).

The protocol is fixed here, before any result is looked at:
- splits, by flight (samples 20 ms apart are not independent):
  - day-0426: trained on 0422 + 0425, tested on every 0426 flight (a new day, with
    obstacles);
  - day-0425: trained on 0426 (+ 0422), tested on every 0425 flight;
  - day-0422 (added in session 68, before its first run): trained on 0425 + 0426,
    tested on the four 0422 flights. A TDOA2 day flown apart from the others, whose
    anchor delays depart the most from the other days' (anchor 6 on log00, anchor 1
    on log01 and log02): the shared data's closest case of the issue's other-day
    flight (0607: TDOA2, another day, anchor 6's delay 0.19 m from 0426's). It
    decides nothing and is not among the splits the rule below weighs: it is the
    estimate for the other-day check, with how many flights the correction makes
    worse;
  - mode-tdoa3 / mode-tdoa2: trained on the flights of the other UWB mode only;
  - within-0426 (added in session 62, before its first run): new flights of a day the
    model was trained on, the situation of the issue's eight held-out 0426 flights,
    which the shipped model meets after training on the shared 0426 flights. The eight
    0426 flights in two folds, each holding one flight of each pair (clear, shelf,
    shelf in TDOA3, three obstacles; flat circles or sinusoidal height): fold a tests
    traj1, 4, 5, 8 and fold b traj2, 3, 6, 7, each trained on every other shared
    flight. A seed's figures are over the eight test flights of both folds. It decides
    nothing: it is the estimate, for the shipped recipe, of the issue's check on new
    0426 flights, which the day split does not make;
  - setup-0426 (added in session 82, before its first run): as within-0426, but each
    of four folds holds out both flights of one 0426 obstacle setup (clear traj1, 2;
    shelf traj3, 4; shelf in TDOA3 traj5, 6; shelf and boxes traj7, 8), so that no
    test flight's obstacles were met in training, as on the issue's held-out flights,
    some with metal. It decides nothing: a second estimate of the same check;
  - within-0425 (added in session 77, before its first run): the situation of
    within-0426, on the 0425 day: its 23 flights in three folds by flight number mod 3
    (fold a traj3, 6, …, 21; b traj1, 4, …, 22; c traj2, 5, …, 23: each fold holds TDOA2
    and TDOA3 flights, flat and sinusoidal heights), each trained on every other shared
    flight. It is the split that chooses a training change (benchmarks/form_rule.py), so
    that within-0426 stays the estimate and is not also what chooses;
  - anchors: leave-one-anchor-out, for each anchor k, no measurement involving k in
    training; tested on the held-out flights' measurements that involve k (the
    correction must not widen their error spread). Added in session 53, after the
    results of session 52 were seen (every form widened most unseen anchors): a model
    does not correct a measurement with an anchor it was not trained on. It has no
    parameter to tune and makes the check hold by construction, so the page also
    shows what each network does if made to extrapolate to the unseen anchor;
  - region: trained on the samples with the tag between 1.3 and 1.7 m high, tested on
    the samples above or below (the flights with a sinusoidal height reach 1.0–2.0 m);
  - sector (added in session 56, before its first run): every shared flight circles
    the origin at 1.5 m (1.29–1.65 m from it: 5–95 % of each flight's airborne truth),
    so no radius can be held out. Instead, for each quarter of the circle (the tag's
    bearing about the origin, from −180° in steps of 90°), trained on the samples
    outside it and tested on the test flights' samples inside it: there each anchor
    is seen from directions and distances the network did not meet. The correction
    passes if it narrows the spread in every quarter for every seed; the page reports
    every quarter and seed either way;
- within the training flights, a seeded 85:15 cut into training and validation
  flights; three initialisations each, the one kept chosen by the robust estimator's
  mean 3D RMSE on the validation flights (the shipped recipe, `rig train`);
- seeds 0, 1 and 2 (each its own cut and initialisations);
- since session 62, training on one MKL code branch (COMPATIBLE unless MKL_CBWR names
  another; each row says which, `mkl_cbwr`), so that a figure repeats on another
  machine with the same CPU; rows without it were made on their machine's own branch.
  Not on another CPU: since session 77 each row says its CPU (`cpu`, vendor family
  model). The rows without it were made on the Intel Xeon of sessions 62–76
  (GenuineIntel 6 207), where the link rows repeated to the last digit in sessions 70
  and 76; an AMD EPYC trains other networks from the same seeds. Rows are compared
  only with rows of the same CPU (benchmarks/form_rule.py);
- the estimator as shipped. Since session 83 it weights the measurements of an anchor
  whose tracked bias is large (`anchor_bias_c`, which each row made since says); the
  rows without it replay the estimator without that weighting (`anchor_bias_c` 0). The
  training recipe replays the estimator without it either way (RECIPE_ESTIMATOR);
- metrics: on the test flights, the robust estimator's 3D RMSE with and without the
  correction (mean, and how many flights the correction makes worse), and the TDOA
  error's standard deviation on the test samples before and after the correction
  (int8 weights as the board runs them); every seed is reported, then the mean and
  the spread (min–max) over seeds. Since session 57 the region and sector splits also
  report the share of their test samples outside the model's trained region (the
  cells `rig evaluate` reports against): descriptive, it decides nothing.

Nothing here is tuned on the test flights: a form is chosen by these figures, by a rule
fixed before they were seen. The day and mode splits come first: the checks that matter
are new flights and new days. Call a form's accuracy the mean, over the four day and
mode splits, of its mean 3D RMSE over seeds; a form passes the anchor check if the
correction widens no unseen anchor's spread. The shipped form is the most accurate of
those that pass, if it is within 0.01 m of the most accurate form; otherwise the most
accurate form, with the anchor check reported as failing. The
shipped model is then trained on every shared flight but a seeded 15 % kept for
validation (`rig train --all-flights`, seed 0; on the labels as measured, or without
each flight's constant tag offset with `--untranslated` if benchmarks/tag_offset.py's
rule keeps them, which on the pinned branch it does not): the checks that matter most are new
flights of the days these were flown on, and every flight of those days is data about
their anchors; this page, not a held-out share of the shared flights, is the estimate
of its transfer.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")       # two processes on two cores
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rig.bias.config import TrainConfig  # noqa: E402
from rig.bias.dataset import Samples  # noqa: E402
from rig.bias.train import MKL_BRANCH, Split, cpu_identity, fit, involves, load_or_build_dataset, split_flights  # noqa: E402
from rig.data import paths  # noqa: E402
from rig.estimator.bias_net import link_features  # noqa: E402
from rig.estimator.trained_region import outside_share  # noqa: E402
from rig.estimator.native import default_params  # noqa: E402

from bias_validation_results import (  # noqa: E402
    ENTRY_PAGE,
    ESTIMATE_SPLITS,
    FIGURE,
    FLIGHT_SPLITS,
    PAGE,
    REGION_Z,
    RESULTS,
    SECTORS,
    SELECTION_SPLITS,
    TDOA3,
    UNTRANSLATED,
    WITHIN_FOLDS,
    choose_form,
    row_key,
    summary,
    write_doc,
    write_estimates,
    write_figure,
)

CACHE = ROOT / "out" / "cache" / "all.npz"
SAVE_MODELS_ENV = "UWB_RIG_SAVE_MODELS"
FORMS = {"link": "7", "shared": "shared", "pair": "14", UNTRANSLATED: "7"}   # form -> rig train's feature set
VALIDATION_SHARE = 0.15


_samples: Samples | None = None


def cached_samples() -> Samples:
    """The dataset of every shared flight, read once per worker process."""
    global _samples
    if _samples is None:
        _samples = load_or_build_dataset(paths.flights(), CACHE)[0]
    return _samples


def flight_split(names: list[str], test: list[str], seed: int) -> Split:
    """The test flights, and the rest cut 85:15 into training and validation (seeded)."""
    return split_flights(names, seed, test, fractions=(1 - VALIDATION_SHARE, VALIDATION_SHARE))


def test_flights(split_name: str, names: list[str]) -> list[str]:
    if split_name == "day-0426":
        return [n for n in names if n.startswith("0426")]
    if split_name == "day-0425":
        return [n for n in names if n.startswith("0425")]
    if split_name == "day-0422":
        return [n for n in names if n.startswith("0422")]
    if split_name == "mode-tdoa3":
        return [n for n in names if n in TDOA3]
    if split_name == "mode-tdoa2":
        return [n for n in names if n not in TDOA3]
    for within, folds in WITHIN_FOLDS.items():
        if split_name.startswith(f"{within}-"):
            return folds[split_name.removeprefix(f"{within}-")]
    raise ValueError(split_name)


def closed_loop(flights: list[str], net) -> list[dict]:
    """The robust estimator's 3D RMSE on each flight with `net`, with the whole of its
    correction applied, and without correction."""
    from rig.data.importer import load_any
    from rig.estimator.evaluate import evaluate

    out = []
    for name in flights:
        rec = load_any(paths.data_dir() / "flights" / name)
        with_net, full, without = (evaluate(rec, model=net), evaluate(rec, model=net, full_trust=True),
                                   evaluate(rec, use_nn=False))
        out.append({"flight": name, "rmse_3d": with_net["rmse_3d"], "rmse_3d_without": without["rmse_3d"],
                    "rmse_3d_full_trust": full["rmse_3d"], "correction_trust": with_net["correction_trust"],
                    "diverged": with_net["diverged"]})
    return out


def tdoa_spread(net, samples: Samples, trained: Samples | None = None) -> dict:
    """The test samples' TDOA error spread before and after the correction, and the share
    of them outside where the model was trained (its trained_region). With the samples
    it `trained` on, a link model's spread with each link's bias clamped to the range it
    took on them too (session 58)."""
    correction = net.quantized().predict(samples.features, samples.id_a, samples.id_b)
    after = samples.label - correction
    f = samples.features
    out = {"std_before": float(np.std(samples.label)), "std_after": float(np.std(after)), "n": len(samples),
           "mean_before": float(np.mean(samples.label)), "mean_after": float(np.mean(after)),
           "outside_trained_region": outside_share(net.region, f[:, 0:3], f[:, 3:6], samples.id_a, samples.id_b)}
    if net.region is not None and len(samples):
        inside = net.region.inside(f[:, 0:3], samples.id_a) & net.region.inside(f[:, 3:6], samples.id_b)
        out["std_after_gated"] = float(np.std(samples.label - np.where(inside, correction, 0.0)))
        if not inside.all():
            out["outside"] = {"n": int(np.sum(~inside)), "std_before": float(np.std(samples.label[~inside])),
                              "std_after": float(np.std(after[~inside]))}
    if trained is not None and net.form == "link" and len(samples):
        clamped, share = clamped_correction(net.quantized(), samples, trained)
        out["std_after_clamped"], out["clamped_share"] = float(np.std(samples.label - clamped)), share
    return out


def clamped_correction(net, samples: Samples, trained: Samples) -> tuple[np.ndarray, float]:
    """A link model's correction with each link's bias held within the range it took on
    the `trained` samples' links, and the share of measurements with a link held."""
    links = np.vstack(link_features(trained.features))
    values = net.link_bias(links)
    low, high = float(values.min()), float(values.max())
    a, b = (net.link_bias(x) for x in link_features(samples.features))
    held = (a < low) | (a > high) | (b < low) | (b > high)
    correction = np.clip(b, low, high) - np.clip(a, low, high) + net.offsets(samples.id_b) - net.offsets(samples.id_a)
    correction = np.where(net.trained_on(samples.id_a) & net.trained_on(samples.id_b), correction, 0.0)
    return correction, float(held.mean())


def form_config(form: str, **kwargs) -> TrainConfig:
    """The training configuration of a form of this page."""
    return TrainConfig.with_features(FORMS[form], untranslated=form == UNTRANSLATED, **kwargs)


def flight_split_samples(split_name: str, seed: int) -> tuple[Samples, Split]:
    """The samples a day or mode split draws on, and its seeded cut of their flights."""
    samples = cached_samples()
    names = sorted(set(samples.flight.tolist()))
    test = test_flights(split_name, names)
    if split_name == "day-0425":         # 0426 (+ 0422) only: the other direction of day-0426
        samples = samples.select(~np.char.startswith(samples.flight.astype(str), "0425") | np.isin(samples.flight, test))
        names = sorted(set(samples.flight.tolist()))
    return samples, flight_split(names, test, seed)


def run_flight_split(job: tuple) -> dict:
    split_name, form, seed, *fold = job
    samples, split = flight_split_samples(f"{split_name}-{fold[0]}" if fold else split_name, seed)
    tic = time.perf_counter()
    net, report = fit(samples, split, form_config(form, seed=seed))
    if os.environ.get(SAVE_MODELS_ENV):
        net.save(model_path(Path(os.environ[SAVE_MODELS_ENV]), split_name, form, seed, fold[0] if fold else None))
    loop = closed_loop(split.test, net)
    rmse = np.array([r["rmse_3d"] for r in loop])
    without = np.array([r["rmse_3d_without"] for r in loop])
    return {"split": split_name, "form": form, "seed": seed, "train": split.train, "validation": split.validation,
            "test": split.test, "flights": loop, "mean_rmse_3d": float(rmse.mean()),
            "mean_rmse_3d_without": float(without.mean()), "worse_flights": int(np.sum(rmse > without)),
            "tdoa": tdoa_spread(net, samples.select(np.isin(samples.flight, split.test))),
            "seconds": time.perf_counter() - tic, **({"fold": fold[0]} if fold else {})}


def model_path(directory: Path, split_name: str, form: str, seed: int, fold: str | None = None) -> Path:
    """Where --save-models keeps a day, mode or within split's network, so that an
    estimator-side change can be judged on the very networks of the kept rows without
    training them again (training is deterministic on the pinned MKL branch)."""
    return directory / f"{split_name}{'-' + fold if fold else ''}.{form}.seed{seed}.json"


def run_anchor_split(job: tuple) -> dict:
    anchor, form, seed = job
    samples = cached_samples()
    names = sorted(set(samples.flight.tolist()))
    split = split_flights(names, seed)
    config = form_config(form, seed=seed, select_by="mse")
    net, report = fit(samples, split, config, exclude_anchors=[anchor])
    test = samples.select(np.isin(samples.flight, split.test) & involves(samples, [anchor]))
    return {"split": "anchors", "anchor": anchor, "form": form, "seed": seed, "tdoa": tdoa_spread(net, test),
            "tdoa_extrapolated": tdoa_spread(replace(net, anchors=None), test)}


def run_region_split(job: tuple) -> dict:
    _, form, seed = job
    samples = cached_samples()
    z = samples_height(samples)
    inside = (z >= REGION_Z[0]) & (z <= REGION_Z[1])
    names = sorted(set(samples.flight.tolist()))
    split = split_flights(names, seed)
    net, _ = fit(samples.select(inside), split, form_config(form, seed=seed, select_by="mse"))
    test = samples.select(~inside & np.isin(samples.flight, split.test))
    trained = samples.select(inside & np.isin(samples.flight, split.train))
    return {"split": "region", "form": form, "seed": seed, "tdoa": tdoa_spread(net, test, trained)}


def run_sector_split(job: tuple) -> dict:
    sector, form, seed = job
    samples = cached_samples()
    inside = samples_sector(samples) == sector
    names = sorted(set(samples.flight.tolist()))
    split = split_flights(names, seed)
    net, _ = fit(samples.select(~inside), split, form_config(form, seed=seed, select_by="mse"))
    test = samples.select(inside & np.isin(samples.flight, split.test))
    trained = samples.select(~inside & np.isin(samples.flight, split.train))
    return {"split": "sector", "sector": sector, "form": form, "seed": seed, "tdoa": tdoa_spread(net, test, trained)}


def samples_position(samples: Samples) -> np.ndarray:
    """The tag's position at each sample (the estimator's, as the features are): anchor
    A's position less its relative position."""
    from rig.data.importer import load_any

    anchors = {}
    for name in sorted(set(samples.flight.tolist())):
        rec = load_any(paths.data_dir() / "flights" / name)
        anchors[name] = {a.id: np.asarray(a.position, float) for a in rec.anchors}
    a = np.array([anchors[f][int(k)] for f, k in zip(samples.flight, samples.id_a)])
    return a - samples.features[:, :3]


def samples_height(samples: Samples) -> np.ndarray:
    return samples_position(samples)[:, 2]


def samples_sector(samples: Samples) -> np.ndarray:
    """Which quarter of the circle the tag is in at each sample: 0..SECTORS-1 by its
    bearing about the origin, from -180 degrees."""
    return bearing_sector(samples_position(samples))


def bearing_sector(position: np.ndarray) -> np.ndarray:
    """The quarter of the circle of each position (n, 3): by its bearing about the origin."""
    bearing = np.arctan2(position[:, 1], position[:, 0])
    return np.minimum(((bearing + np.pi) / (2 * np.pi) * SECTORS).astype(int), SECTORS - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--forms", nargs="+", choices=list(FORMS), default=list(FORMS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--splits", nargs="+",
                        default=[*FLIGHT_SPLITS, *ESTIMATE_SPLITS, *SELECTION_SPLITS, "anchors", "region", "sector"])
    parser.add_argument("--json", type=Path, default=RESULTS)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--doc", type=Path, default=None,
                        help="the notebook page written from the results (default: the notebook's, for the kept "
                             "results; else beside --json)")
    parser.add_argument("--from-json", action="store_true", help="write the page from --json, training nothing")
    parser.add_argument("--fresh", action="store_true", help="drop the rows already in --json")
    parser.add_argument("--save-models", type=Path, metavar="DIR",
                        help="keep each day, mode and within split's network in DIR (model_path)")
    args = parser.parse_args()
    # only the kept results write the notebook page and docs/bias.md's table; a run into
    # another JSON (an experiment, a tag) writes its page beside it
    kept = args.json.resolve() == RESULTS.resolve()
    args.doc = args.doc or (PAGE if kept else args.json.with_suffix(".md"))
    entry = ENTRY_PAGE if kept else None
    figure = FIGURE if kept else args.json.with_suffix(".png")
    if args.from_json:
        if not args.json.is_file():
            parser.error(f"--from-json: {args.json} does not exist (run without --from-json to make it)")
        rows = json.loads(args.json.read_text())["rows"]
        write_pages(rows, args.doc, entry)
        write_figure(rows, figure)
        return
    if args.save_models:
        args.save_models.mkdir(parents=True, exist_ok=True)
        os.environ[SAVE_MODELS_ENV] = str(args.save_models.resolve())     # the workers inherit it
    cached_samples()         # built once, before the workers read it
    # the workers train on this MKL branch (rig.bias.train.import_torch), said in every row
    os.environ.setdefault("MKL_CBWR", MKL_BRANCH)
    jobs = []
    for split_name in args.splits:
        for form in args.forms:
            for seed in args.seeds:
                if split_name == "anchors":
                    jobs += [(run_anchor_split, (k, form, seed)) for k in range(8)] if seed == args.seeds[0] else []
                elif split_name == "region":
                    jobs.append((run_region_split, (split_name, form, seed)))
                elif split_name == "sector":
                    jobs += [(run_sector_split, (k, form, seed)) for k in range(SECTORS)]
                elif split_name in WITHIN_FOLDS:
                    jobs += [(run_flight_split, (split_name, form, seed, fold)) for fold in WITHIN_FOLDS[split_name]]
                else:
                    jobs.append((run_flight_split, (split_name, form, seed)))
    rows = [] if args.fresh or not args.json.exists() else json.loads(args.json.read_text())["rows"]
    with Pool(args.workers) as pool:
        pending = [pool.apply_async(fn, (job,)) for fn, job in jobs]
        for p in pending:
            row = {**p.get(), "mkl_cbwr": os.environ["MKL_CBWR"], "cpu": cpu_identity(),
                   "anchor_bias_c": default_params().anchor_bias_c}
            rows = [r for r in rows if row_key(r) != row_key(row)] + [row]
            brief = {k: row[k] for k in ("split", "form", "seed", "mean_rmse_3d", "mean_rmse_3d_without",
                                         "worse_flights", "anchor", "sector", "fold") if k in row}
            print(json.dumps({**brief, "tdoa": row["tdoa"]}), flush=True)
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps({"rows": rows, "summary": summary(rows)}, indent=1) + "\n")
    for line in summary(rows):
        print(json.dumps(line))
    print(json.dumps(choose_form(rows)))
    write_pages(rows, args.doc, entry)
    write_figure(rows, figure)


def write_pages(rows: list[dict], doc: Path = PAGE, entry: Path | None = ENTRY_PAGE) -> None:
    """The notebook page (with this module's protocol) and, unless `entry` is None,
    docs/bias.md's estimates."""
    write_doc(rows, doc, protocol=__doc__.split("The protocol is fixed here, before any result is looked at:\n")[1].strip())
    if entry is not None:
        write_estimates(rows, entry)


if __name__ == "__main__":
    main()
