"""The rows of benchmarks/bias_validation.py: summed over seeds and folds, judged by the
protocol's rule (choose_form), and written as the notebook page
(docs/notebook/bias-validation.md) and the table of docs/bias.md. Trains nothing: the
protocol, its splits and its runs are bias_validation.py's, which imports this.

    .venv/bin/python benchmarks/bias_validation.py --from-json      # both pages from the kept rows
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.bias.train import MKL_BRANCH

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "notebook" / "bias-validation.md"
RESULTS = PAGE.with_suffix(".json")        # every row the page shows, kept beside it
ENTRY_PAGE = ROOT / "docs" / "bias.md"     # its table of estimates is written from the rows
FIGURE = ROOT / "docs" / "img" / "bias_validation.png"   # each test flight with and without correction

FLIGHT_SPLITS = ("day-0426", "day-0425", "mode-tdoa3", "mode-tdoa2")   # the splits the rule weighs
ESTIMATE_SPLITS = ("within-0426", "setup-0426", "day-0422")   # flight splits that estimate a held-out check, weighing nothing
# the split that chooses a training change (benchmarks/form_rule.py, session 77): new
# flights of a trained day, as within-0426, on the other day with many flights, so that
# the 0426 estimate is not also what chooses; folds by flight number mod 3, fixed before
# its first run (each holds TDOA2 and TDOA3 flights, flat and sinusoidal heights)
SELECTION_SPLITS = ("within-0425",)
WITHIN_0426_FOLDS = {"a": ["0426-traj1", "0426-traj4", "0426-traj5", "0426-traj8"],
                     "b": ["0426-traj2", "0426-traj3", "0426-traj6", "0426-traj7"]}
WITHIN_0425_FOLDS = {fold: [f"0425-traj{n}" for n in range(1, 24) if n % 3 == rest]
                     for fold, rest in (("a", 0), ("b", 1), ("c", 2))}
# new obstacle setups of a trained day (session 82): each fold holds out both flights of one
# 0426 setup, which within-0426 splits between training and test
SETUP_0426_FOLDS = {"clear": ["0426-traj1", "0426-traj2"], "shelf": ["0426-traj3", "0426-traj4"],
                    "shelf-tdoa3": ["0426-traj5", "0426-traj6"], "boxes": ["0426-traj7", "0426-traj8"]}
WITHIN_FOLDS = {"within-0426": WITHIN_0426_FOLDS, "within-0425": WITHIN_0425_FOLDS,
                "setup-0426": SETUP_0426_FOLDS}   # split -> its folds
REGION_Z = (1.3, 1.7)            # the training band of the region split (tag height, m)
SECTORS = 4                      # the sector split's quarters of the circle
ACCURACY_TOLERANCE_M = 0.01
# the CPU of the rows made before rows said theirs (session 77): a training's figures
# repeat on its CPU only, so rows are compared with rows of one CPU
EARLIER_CPU = "GenuineIntel 6 207"
# the link form trained on labels without each flight's constant tag offset (`rig train
# --untranslated`): not a form of its own, so it does not take part in choose_form; session
# 59's rule (benchmarks/tag_offset.py) decides whether it replaces the link form's labels
UNTRANSLATED = "untranslated"
UNTRANSLATED_TOLERANCE_M = 0.005
# and rows of forms tried and removed, if a tag runs them into the JSON (session 60's
# "offset": experiment/tag-offset-constant; session 62's "huber": experiment/huber-loss;
# session 65's "distilled": experiment/distill, "refit": experiment/refit and
# "six-restarts": experiment/six-restarts and, on fresh seeds, experiment/six-restarts-replication;
# session 68's "installation": experiment/installation-delays; session 71's "weight-decay":
# experiment/weight-decay and "balanced-days": experiment/balanced-days; session 73's
# "corrected-features": experiment/corrected-features and, on fresh seeds,
# experiment/corrected-features-replication; session 76's "weight-average", cc3dcd2, and
# judged again in session 77 by the split that chooses, 0901f37; session 78's "per-second",
# every second of flight weighing the same, 135ebab; session 79's "narrow", 10 neurons wide, 95f3ca1)
NOT_RANKED = (UNTRANSLATED, "offset", "huber", "distilled", "refit", "six-restarts", "installation", "weight-decay",
              "balanced-days", "corrected-features", "weight-average", "per-second", "narrow")


def merge_folds(rows: list[dict]) -> list[dict]:
    """A split run in folds (WITHIN_FOLDS) as one row per form and seed, over the test
    flights of all its folds; a seed whose folds are not all run is left out."""
    merged, whole = [], [r for r in rows if "fold" not in r]
    for key in sorted({(r["split"], r["form"], r["seed"]) for r in rows if "fold" in r}):
        folds = sorted((r for r in rows if "fold" in r and (r["split"], r["form"], r["seed"]) == key),
                       key=lambda r: r["fold"])
        if {r["fold"] for r in folds} != set(WITHIN_FOLDS[key[0]]):
            continue
        flights = [f for r in folds for f in r["flights"]]
        rmse = np.array([f["rmse_3d"] for f in flights])
        without = np.array([f["rmse_3d_without"] for f in flights])
        merged.append({"split": key[0], "form": key[1], "seed": key[2], "test": [t for r in folds for t in r["test"]],
                       "flights": flights, "mean_rmse_3d": float(rmse.mean()),
                       "mean_rmse_3d_without": float(without.mean()), "worse_flights": int(np.sum(rmse > without)),
                       "tdoa": pooled_spread([r["tdoa"] for r in folds])})
    return whole + merged


def pooled_spread(parts: list[dict]) -> dict:
    """The TDOA error spread before and after over the samples of several test sets."""
    n = np.array([p["n"] for p in parts], float)
    out = {"n": int(n.sum())}
    for when in ("before", "after"):
        mean = np.array([p[f"mean_{when}"] for p in parts])
        second = np.array([p[f"std_{when}"] ** 2 for p in parts]) + mean ** 2
        grand = float(n @ mean / n.sum())
        out[f"std_{when}"] = float(np.sqrt(n @ second / n.sum() - grand ** 2))
        out[f"mean_{when}"] = grand
    return out


def summary(rows: list[dict]) -> list[dict]:
    """Per split and form: mean and min–max over seeds."""
    rows = merge_folds(rows)
    out = []
    for key in sorted({(r["split"], r["form"]) for r in rows}):
        group = [r for r in rows if (r["split"], r["form"]) == key]
        entry = {"split": key[0], "form": key[1], "runs": len(group)}
        for name in ("mean_rmse_3d", "mean_rmse_3d_without", "worse_flights"):
            if name in group[0]:
                values = [r[name] for r in group]
                entry[name] = {"mean": float(np.mean(values)), "min": float(min(values)), "max": float(max(values))}
        after = [r["tdoa"]["std_after"] for r in group]
        before = [r["tdoa"]["std_before"] for r in group]
        entry["tdoa_std"] = {"before": float(np.mean(before)), "after_mean": float(np.mean(after)),
                             "after_min": float(min(after)), "after_max": float(max(after))}
        out.append(entry)
    return out


def choose_form(rows: list[dict]) -> dict:
    """The protocol's choice (module docstring): each form's accuracy (the mean over the
    four day and mode splits of its mean 3D RMSE over seeds), whether it passes the
    anchor check (no unseen anchor's spread widened), and the form to ship."""
    forms = {}
    for entry in summary([r for r in rows if r["split"] in FLIGHT_SPLITS and r["form"] not in NOT_RANKED]):
        forms.setdefault(entry["form"], {})[entry["split"]] = entry["mean_rmse_3d"]["mean"]
    table = {}
    for form, by_split in forms.items():
        if set(by_split) != set(FLIGHT_SPLITS):
            continue
        anchors = [r["tdoa"] for r in rows if r["split"] == "anchors" and r["form"] == form]
        widened = sum(t["std_after"] > t["std_before"] for t in anchors)
        table[form] = {"accuracy_m": float(np.mean(list(by_split.values()))), "anchors_run": len(anchors),
                       "anchors_widened": int(widened), "passes_anchor_check": len(anchors) == 8 and widened == 0}
    if not table:
        return {"forms": {}, "ship": None}
    best = min(table, key=lambda f: table[f]["accuracy_m"])
    passing = [f for f in table if table[f]["passes_anchor_check"]]
    ship = best
    if passing:
        candidate = min(passing, key=lambda f: table[f]["accuracy_m"])
        if table[candidate]["accuracy_m"] <= table[best]["accuracy_m"] + ACCURACY_TOLERANCE_M:
            ship = candidate
    return {"forms": table, "ship": ship, "anchor_check_met": table[ship]["passes_anchor_check"]}


def untranslated_verdict(rows: list[dict]) -> dict | None:
    """Session 59's rule (benchmarks/tag_offset.py), on these rows: the untranslated labels
    replace the link form's only if their accuracy (as choose_form's) is within 0.005 m of
    the link form's and they make fewer flights worse (the sum over the four day and mode
    splits of the mean over seeds). None until both have every split."""
    accuracy, worse = {}, {}
    for form in ("link", UNTRANSLATED):
        entries = summary([r for r in rows if r["form"] == form and r["split"] in FLIGHT_SPLITS])
        if {e["split"] for e in entries} != set(FLIGHT_SPLITS):
            return None
        accuracy[form] = float(np.mean([e["mean_rmse_3d"]["mean"] for e in entries]))
        worse[form] = float(sum(e["worse_flights"]["mean"] for e in entries))
    met = accuracy[UNTRANSLATED] <= accuracy["link"] + UNTRANSLATED_TOLERANCE_M and worse[UNTRANSLATED] < worse["link"]
    return {"accuracy_m": accuracy, "worse_flights": worse, "rule_met": met}


def shipped_recipe(rows: list[dict]) -> str:
    """The rows that stand for the shipped model: the chosen form, or its untranslated
    labels if session 59's rule keeps them."""
    verdict = untranslated_verdict(rows)
    return UNTRANSLATED if verdict and verdict["rule_met"] else choose_form(rows)["ship"]


def row_key(row: dict) -> tuple:
    return row["split"], row["form"], row.get("seed"), row.get("anchor"), row.get("sector"), row.get("fold")


SPLIT_WORDS = {"day-0426": "trained on 0422 + 0425, tested on the 0426 flights",
               "day-0425": "trained on 0426 + 0422, tested on the 0425 flights",
               "day-0422": "trained on 0425 + 0426, tested on the 0422 flights",
               "mode-tdoa3": "trained on TDOA2 flights, tested on the TDOA3 flights",
               "mode-tdoa2": "trained on TDOA3 flights, tested on the TDOA2 flights",
               "within-0426": "trained on every other flight, 0426 flights among them, tested on 0426 flights (two folds)",
               "setup-0426": "trained on every other flight, 0426 flights among them, tested on both 0426 flights "
                             "of one obstacle setup (four folds)",
               "within-0425": "trained on every other flight, 0425 flights among them, tested on 0425 flights "
                              "(three folds; chooses training changes, benchmarks/form_rule.py)",
               "anchors": "each anchor left out of training, tested on its pairs in the test flights",
               "region": f"trained with the tag {REGION_Z[0]}–{REGION_Z[1]} m high, tested above and below",
               "sector": "each quarter of the circle left out of training, tested there"}


def row_cpu(row: dict) -> str:
    """The CPU a row was trained on (rig.bias.train.cpu_identity)."""
    return row.get("cpu", EARLIER_CPU)


def branch_sentence(rows: list[dict]) -> str:
    """Which MKL branch and CPU the rows were trained on: torch's BLAS picks its kernels
    by CPU unless pinned (rig.bias.train.MKL_BRANCH), and the figures move with it and
    with the CPU itself."""
    branches = sorted({r.get("mkl_cbwr", "unpinned") for r in rows})
    if branches == [MKL_BRANCH]:
        words = f"Every row was trained on MKL's {MKL_BRANCH} branch (`mkl_cbwr`), as `rig train` trains"
    else:
        words = "The rows were trained on MKL branches " + ", ".join(branches) + " (`mkl_cbwr`): they may differ by branch"
    cpus = {}
    for r in rows:
        cpus.setdefault(row_cpu(r), set()).add(r["split"])
    if len(cpus) == 1:
        return f"{words}, on one CPU ({next(iter(cpus))})."
    others = "; ".join(f"{cpu}: {', '.join(sorted(splits))}" for cpu, splits in sorted(cpus.items()) if cpu != EARLIER_CPU)
    return (f"{words}, on the CPU {EARLIER_CPU} unless the row says another (`cpu`; {others}). A training "
            "repeats on its CPU only: rows of different CPUs are not compared.")


def _anchor_cell(row: dict) -> str:
    """A row of session 52 or before corrected the unseen anchor: its figure is the
    extrapolation, and how the model runs now was not measured on it."""
    t, extrapolated = row["tdoa"], row.get("tdoa_extrapolated")
    if extrapolated is None:
        return f"{t['std_before']:.3f} → not run / {t['std_after']:.3f} m"
    return f"{t['std_before']:.3f} → {t['std_after']:.3f} / {extrapolated['std_after']:.3f} m"


def write_doc(rows: list[dict], doc: Path, protocol: str) -> None:
    """The notebook page: the protocol (bias_validation.py's docstring) and every figure."""
    lines = ["# Bias correction: validation by transfer", "",
             "Regenerated by `.venv/bin/python benchmarks/bias_validation.py` (71 min on two cores, and 5 min a form more for within-0425; it "
             "writes every row to `bias-validation.json` beside this page, and `--from-json` rewrites the page "
             "from it). " + branch_sentence(rows), "",
             "## Protocol", "", protocol, "",
             "## Closed loop: the robust estimator's 3D RMSE on the test flights", "",
             "With correction: the share of it each flight supports, as the estimator applies it since session 69; "
             "the whole correction: as it applied it before (`rmse_3d_full_trust`).", "",
             "| split | form | with correction: mean (min–max over seeds) | the whole correction | without "
             "| flights worse, of | TDOA std before → after |",
             "|---|---|---|---|---|---|---|"]
    flight_rows = merge_folds([r for r in rows if "mean_rmse_3d" in r])
    for entry in summary(flight_rows):
        group = [r for r in flight_rows if (r["split"], r["form"]) == (entry["split"], entry["form"])]
        m, w, worse, s = entry["mean_rmse_3d"], entry["mean_rmse_3d_without"], entry["worse_flights"], entry["tdoa_std"]
        lines.append(f"| {SPLIT_WORDS[entry['split']]} | {entry['form']} | {m['mean']:.3f} m ({m['min']:.3f}–{m['max']:.3f}) "
                     f"| {_whole(group)} | {w['mean']:.3f} m | {worse['mean']:.1f} (max {worse['max']:.0f}) "
                     f"of {len(group[0]['test'])} "
                     f"| {s['before']:.3f} → {s['after_mean']:.3f} m ({s['after_min']:.3f}–{s['after_max']:.3f}) |")
    lines += ["", "Per seed:", "", "| split | form | seed | with | without | worse |", "|---|---|---|---|---|---|"]
    for r in sorted(flight_rows, key=lambda r: (r["split"], r["form"], r["seed"])):
        lines.append(f"| {r['split']} | {r['form']} | {r['seed']} | {r['mean_rmse_3d']:.3f} | "
                     f"{r['mean_rmse_3d_without']:.3f} | {r['worse_flights']} |")
    for split in ESTIMATE_SPLITS:
        lines += per_flight_lines([r for r in flight_rows if r["split"] == split])
    anchors = [r for r in rows if r["split"] == "anchors"]
    if anchors:
        lines += ["", "## Leave-anchor-out: TDOA error spread on the unseen anchor's pairs", "",
                  "Before → as the model runs (it does not correct an anchor it was not trained on) / "
                  "if the network extrapolated to it.", "",
                  "| anchor | " + " | ".join(f"{f}: before → as run / extrapolated" for f in sorted({r['form'] for r in anchors}))
                  + " |", "|---|" + "---|" * len({r["form"] for r in anchors})]
        for k in sorted({r["anchor"] for r in anchors}):
            cells = []
            for form in sorted({r["form"] for r in anchors}):
                hit = [r for r in anchors if r["anchor"] == k and r["form"] == form]
                cells.append(_anchor_cell(hit[0]) if hit else "")
            lines.append(f"| {k} | " + " | ".join(cells) + " |")
    choice = choose_form(rows)
    if choice["forms"]:
        lines += ["", "## The choice, by the rule fixed above", "",
                  "| form | accuracy: mean over the day and mode splits | unseen anchors widened | anchor check |",
                  "|---|---|---|---|"]
        for form, c in sorted(choice["forms"].items(), key=lambda kv: kv[1]["accuracy_m"]):
            lines.append(f"| {form} | {c['accuracy_m']:.3f} m | {c['anchors_widened']} of {c['anchors_run']} "
                         f"| {'passes' if c['passes_anchor_check'] else 'fails'} |")
        lines += ["", f"Shipped: **{choice['ship']}**" + ("" if choice["anchor_check_met"] else
                  " — the most accurate form; no form within "
                  f"{ACCURACY_TOLERANCE_M:.2f} m of it passes the anchor check, which stays failing") + "."]
        verdict = untranslated_verdict(rows)
        if verdict:
            a, w = verdict["accuracy_m"], verdict["worse_flights"]
            lines += ["", f"Its labels, by session 59's rule (benchmarks/tag_offset.py: the untranslated rows replace "
                      f"the link form's only if within {UNTRANSLATED_TOLERANCE_M} m of its accuracy and with fewer "
                      f"flights worse): untranslated {a[UNTRANSLATED]:.4f} m and {w[UNTRANSLATED]:.2f} flights worse, "
                      f"link {a['link']:.4f} m and {w['link']:.2f}: "
                      + ("**met**, the shipped model is trained untranslated (`rig train --all-flights --untranslated`)."
                         if verdict["rule_met"] else "**not met**, the shipped model is trained on the labels as "
                         "measured (`rig train --all-flights`).")]
    region = [r for r in rows if r["split"] == "region"]
    planned = {("anchors", form, k) for form in {r["form"] for r in rows} for k in range(8)}
    missing = sorted(planned - {("anchors", r["form"], r["anchor"]) for r in anchors})
    if missing:
        by_form = {form: [str(k) for _, f, k in missing if f == form] for form in sorted({f for _, f, _ in missing})}
        lines += ["", "Not run: " + "; ".join(f"the {form} form without anchor {', '.join(ks)}"
                                               for form, ks in by_form.items()) + "."]
    if not region:
        lines += ["", "## Leave-region-out", "", "Not run yet (the protocol's last split)."]
    if region:
        lines += ["", "## Leave-region-out: TDOA error spread where the tag flew outside the training band", "",
                  "Samples, and the share of them outside the model's trained region, in brackets. " + GATED_NOTE, "",
                  "| form | seed | before → after |", "|---|---|---|"]
        for r in sorted(region, key=lambda r: (r["form"], r["seed"])):
            lines.append(f"| {r['form']} | {r['seed']} | {r['tdoa']['std_before']:.3f} → {r['tdoa']['std_after']:.3f}"
                         f"{_gated(r['tdoa'])} m ({r['tdoa']['n']} samples{_flagged(r['tdoa'])}) |")
        clamped = clamp_lines(region, "seeds")
        lines += ["", *clamped] if clamped else []
    lines += sector_lines([r for r in rows if r["split"] == "sector"])
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("\n".join(lines) + "\n")
    print(f"wrote {doc}")


def _whole(group: list[dict]) -> str:
    """The mean over seeds of a split's mean 3D RMSE with the whole correction applied,
    or a dash for rows run before session 69 without it."""
    flights = [[f.get("rmse_3d_full_trust") for f in r["flights"]] for r in group]
    if any(v is None for seed in flights for v in seed):
        return "—"
    return f"{np.mean([np.mean(seed) for seed in flights]):.3f} m"


def per_flight_lines(rows: list[dict]) -> list[str]:
    """Per form and test flight: the 3D RMSE with and without the correction (mean over
    seeds) and on how many seeds the correction made it worse."""
    if not rows:
        return []
    lines = ["", f"Per flight, {SPLIT_WORDS[rows[0]['split']]}: mean over seeds.", "",
             "| form | flight | with | without | worse on seeds |", "|---|---|---|---|---|"]
    for form in sorted({r["form"] for r in rows}):
        runs = [f for r in rows if r["form"] == form for f in r["flights"]]
        for flight in sorted({f["flight"] for f in runs}):
            hit = [f for f in runs if f["flight"] == flight]
            worse = sum(f["rmse_3d"] > f["rmse_3d_without"] for f in hit)
            lines.append(f"| {form} | {flight} | {np.mean([f['rmse_3d'] for f in hit]):.3f} | "
                         f"{np.mean([f['rmse_3d_without'] for f in hit]):.3f} | {worse} of {len(hit)} |")
    return lines


GATED_NOTE = ("After the slash, the spread if the correction abstained outside that region (session 58; "
              "not kept, docs/notebook/bias.md).")


def _gated(tdoa: dict) -> str:
    """The spread with the correction zeroed outside the trained region, if measured."""
    return f" / {tdoa['std_after_gated']:.3f}" if "std_after_gated" in tdoa else ""


def _flagged(tdoa: dict, before: str = "; ", after: str = "") -> str:
    """The share of the test samples outside the model's trained region, if measured
    (rows of runs before session 57 lack it)."""
    share = tdoa.get("outside_trained_region")
    return "" if share is None else f"{before}{share:.0%} outside{after}"


def sector_lines(sector: list[dict]) -> list[str]:
    """The sector split's table: per form and quarter, the spread before → after for
    each seed, and whether the correction narrowed it in every quarter and seed."""
    if not sector:
        return []
    seeds = sorted({r["seed"] for r in sector})
    lines = ["", "## Leave-sector-out: TDOA error spread in the quarter of the circle left out of training", "",
             "Quarters by the tag's bearing about the origin: 0 from −180°, 1 from −90°, 2 from 0°, 3 from 90°. "
             "In brackets: the share of the quarter's test samples outside the model's trained region. " + GATED_NOTE,
             "",
             "| form | quarter | " + " | ".join(f"seed {s}: before → after" for s in seeds) + " |",
             "|---|---|" + "---|" * len(seeds)]
    for form in sorted({r["form"] for r in sector}):
        for k in range(SECTORS):
            cells = []
            for seed in seeds:
                hit = [r["tdoa"] for r in sector if (r["form"], r["sector"], r["seed"]) == (form, k, seed)]
                cells.append(f"{hit[0]['std_before']:.3f} → {hit[0]['std_after']:.3f}{_gated(hit[0])} m"
                             f"{_flagged(hit[0], ' (', ')')}" if hit else "not run")
            lines.append(f"| {form} | {k} | " + " | ".join(cells) + " |")
    lines.append("")
    for form in sorted({r["form"] for r in sector}):
        runs = [r["tdoa"] for r in sector if r["form"] == form]
        narrowed = sum(t["std_after"] < t["std_before"] for t in runs)
        gated = [t for t in runs if "std_after_gated" in t]
        lines.append(f"- {form}: narrowed in {narrowed} of {len(runs)} quarters × seeds "
                     f"({'passes' if narrowed == len(runs) == SECTORS * len(seeds) else 'does not pass'} "
                     "the rule fixed above)"
                     + (f"; abstaining outside the trained region, in {sum(t['std_after_gated'] < t['std_before'] for t in gated)}"
                        f" of {len(gated)}, mean {np.mean([t['std_after'] for t in gated]):.3f} → "
                        f"{np.mean([t['std_after_gated'] for t in gated]):.3f} m." if gated else "."))
    lines += clamp_lines(sector, "quarters × seeds")
    return lines


def clamp_lines(rows: list[dict], runs: str) -> list[str]:
    """Per form, what holding each link's bias within its trained range did (session 58)."""
    lines = []
    for form in sorted({r["form"] for r in rows}):
        held = [r["tdoa"] for r in rows if r["form"] == form and "std_after_clamped" in r["tdoa"]]
        if held:
            lines.append(
                f"- {form}, each link's bias held within its trained range (not kept, docs/notebook/bias.md): "
                f"narrowed in {sum(t['std_after_clamped'] < t['std_before'] for t in held)} of {len(held)} {runs}, "
                f"mean {np.mean([t['std_after'] for t in held]):.4f} → "
                f"{np.mean([t['std_after_clamped'] for t in held]):.4f} m; a link held in "
                f"{min(t['clamped_share'] for t in held):.1%}–{max(t['clamped_share'] for t in held):.1%} "
                "of the measurements.")
    return lines


# The figures on the flights we do not have, beside each of our estimates
HELD_OUT = {
    "within-0426": "the pair network shipped before: 0.276 → 0.224 m (19 %); 6 of those 8 flights are TDOA3 "
                   "with obstacles, against 2 of 8 in our split",
    "setup-0426": "the same held-out flights; their obstacles include metal, which no shared flight has. "
                  "Here each test flight's obstacle setup is new to the network, as there",
    "day": "0607: 0.318 → 0.298 m with the pair network",
    "mode": "—",
    "anchors": "—",
    "place": "0607 flies 0.26–1.85 m from the centre, off the training circle",
}
HELD_OUT_0426_WITHOUT_M, TARGET_0426_M = 0.276, 0.20   # the check on the eight 0426 flights
# the same eight by UWB mode: 2 TDOA2 flights at 0.262 m and 6 TDOA3 at 0.280 m without correction
HELD_OUT_0426_BY_MODE = {"TDOA2": (2, 0.262), "TDOA3": (6, 0.280)}
TDOA3 = tuple(f"0425-traj{k}" for k in range(13, 24)) + ("0426-traj5", "0426-traj6")   # the shared TDOA3 flights
ESTIMATES_BEGIN, ESTIMATES_END = "<!-- estimates: begin -->", "<!-- estimates: end -->"


def _gain(entry: dict) -> str:
    m, w = entry["mean_rmse_3d"], entry["mean_rmse_3d_without"]["mean"]
    change = 1 - m["mean"] / w
    return f"{w:.3f} → {m['mean']:.3f} m ({m['min']:.3f}–{m['max']:.3f}), {abs(change):.0%} {'lower' if change >= 0 else 'higher'}"


def _worse(entry: dict, n_test: int) -> str:
    worse = entry["worse_flights"]
    return f"{worse['mean']:.1f} of {n_test} flights worse (max {worse['max']:.0f})"


def estimate_lines(rows: list[dict]) -> list[str]:
    """docs/bias.md's table: the shipped recipe's rows of every split, each beside the
    held-out figure it estimates."""
    recipe = shipped_recipe(rows)
    shipped = [r for r in rows if r["form"] == recipe]
    flight_rows = merge_folds([r for r in shipped if "mean_rmse_3d" in r])
    entries = {e["split"]: e for e in summary(flight_rows)}
    n_test = {s: len(next(r["test"] for r in flight_rows if r["split"] == s)) for s in entries}
    lines = [f"| check | our estimate: the shipped recipe ({recipe} rows), mean over seeds (min–max) | "
             "what was measured on the held-out flights |", "|---|---|---|"]
    for split, check in (("within-0426", "new flights of a trained day"),
                         ("setup-0426", "new obstacle setups of a trained day")):
        if split in entries:
            lines.append(f"| {check} (0426; {split}) | "
                         f"{_check_0426(entries[split], [r for r in flight_rows if r['split'] == split])} |")
    day_splits = [s for s in ("day-0426", "day-0425", "day-0422") if s in entries]
    days = [f"{_gain(entries[s])} on {s[4:]}, {_worse(entries[s], n_test[s])}" for s in day_splits]
    if "day-0422" in entries:
        days.append("on 0422 made worse: " + _worse_flights([r for r in flight_rows if r["split"] == "day-0422"]))
    held_out = HELD_OUT["day"]
    pair_0422 = summary([r for r in rows if r["form"] == "pair" and r["split"] == "day-0422"])
    if pair_0422:
        held_out += (f"; trained here on 0425 + 0426, the pair form goes {_gain(pair_0422[0])} on 0422: "
                     "0422 is the harsher case")
    if days:
        lines.append(f"| a new day ({', '.join(day_splits)}) | {'; '.join(days)} | {held_out} |")
    modes = [f"{word}: {_gain(entries[s])}, {_worse(entries[s], n_test[s])}"
             for s, word in (("mode-tdoa3", "TDOA2 → TDOA3"), ("mode-tdoa2", "TDOA3 → TDOA2")) if s in entries]
    if modes:
        lines.append(f"| a new UWB mode | {'; '.join(modes)} | {HELD_OUT['mode']} |")
    anchors = [r for r in shipped if r["split"] == "anchors"]
    if anchors:
        widened = sum(r["tdoa"]["std_after"] > r["tdoa"]["std_before"] for r in anchors)
        lines.append(f"| an anchor not trained on (anchors) | left uncorrected (it abstains): its pairs' spread widened on "
                     f"{widened} of {len(anchors)} anchors | {HELD_OUT['anchors']} |")
    sector = [r["tdoa"] for r in shipped if r["split"] == "sector"]
    region = [r["tdoa"] for r in shipped if r["split"] == "region"]
    if sector or region:
        parts = ([f"narrows the TDOA spread in {sum(t['std_after'] < t['std_before'] for t in sector)} of "
                  f"{len(sector)} quarters × seeds left out (sector)"] if sector else []) + \
                ([f"above and below the {REGION_Z[0]}–{REGION_Z[1]} m band: spread "
                  f"{np.mean([t['std_before'] for t in region]):.3f} → {np.mean([t['std_after'] for t in region]):.3f} m "
                  "(region)"] if region else [])
        lines.append(f"| where the tag never flew in training | {'; '.join(parts)} | {HELD_OUT['place']} |")
    return lines


def _check_0426(entry: dict, rows: list[dict]) -> str:
    """An estimate split's cells for the issue's 0426 check: its gain and the flights it
    made worse, and the gain applied to the held-out flights, pooled and per UWB mode."""
    gain = 1 - entry["mean_rmse_3d"]["mean"] / entry["mean_rmse_3d_without"]["mean"]
    expected = HELD_OUT_0426_WITHOUT_M * (1 - gain)
    return (f"{_gain(entry)}; made worse: {_worse_flights(rows)} | {HELD_OUT[entry['split']]}. Our gain, if it held "
            f"on their {HELD_OUT_0426_WITHOUT_M:.3f} m, gives {expected:.3f} m: "
            f"{'above' if expected > TARGET_0426_M else 'under'} the {TARGET_0426_M:.2f} m asked. {_by_mode(rows)}")


def _by_mode(rows: list[dict]) -> str:
    """An estimate split's gain per UWB mode (mean over seeds of the flights' mean RMSE), applied
    to the held-out flights of that mode: the estimate if the gain follows the mode."""
    gains, held, counts = {}, 0.0, {}
    for mode, (n, without) in HELD_OUT_0426_BY_MODE.items():
        runs = [f for r in rows for f in r["flights"] if (f["flight"] in TDOA3) == (mode == "TDOA3")]
        counts[mode] = len({f["flight"] for f in runs})
        gains[mode] = 1 - np.mean([f["rmse_3d"] for f in runs]) / np.mean([f["rmse_3d_without"] for f in runs])
        held += n * without * (1 - gains[mode])
    expected = held / sum(n for n, _ in HELD_OUT_0426_BY_MODE.values())
    return (f"Per mode (TDOA2 {gains['TDOA2']:.0%} lower on {counts['TDOA2']} of our flights, TDOA3 "
            f"{gains['TDOA3']:.0%} on {counts['TDOA3']}) on their 2 TDOA2 and 6 TDOA3 flights: {expected:.3f} m, "
            f"{'above' if expected > TARGET_0426_M else 'under'} it; our TDOA3 figure rests on two flights")


def _worse_flights(rows: list[dict]) -> str:
    """Each test flight the correction made worse, on how many of the seeds."""
    runs = [f for r in rows for f in r["flights"]]
    worse = {}
    for flight in sorted({f["flight"] for f in runs}):
        hit = [f for f in runs if f["flight"] == flight]
        if n := sum(f["rmse_3d"] > f["rmse_3d_without"] for f in hit):
            worse[flight] = f"{flight} on {n} of {len(hit)} seeds"
    return ", ".join(worse.values()) or "no flight on any seed"


def write_estimates(rows: list[dict], page: Path = ENTRY_PAGE) -> None:
    """Rewrite the table between docs/bias.md's markers from the rows."""
    text = page.read_text()
    if ESTIMATES_BEGIN not in text or ESTIMATES_END not in text:
        raise ValueError(f"{page} has no {ESTIMATES_BEGIN} … {ESTIMATES_END} markers")
    before, rest = text.split(ESTIMATES_BEGIN, 1)
    after = rest.split(ESTIMATES_END, 1)[1]
    page.write_text(before + ESTIMATES_BEGIN + "\n" + "\n".join(estimate_lines(rows)) + "\n" + ESTIMATES_END + after)
    print(f"wrote {page}")


# the panels of the figure: the flight splits of the shipped recipe, the estimates first
FIGURE_SPLITS = ("within-0426", "within-0425", "day-0426", "day-0425", "day-0422", "mode-tdoa3", "mode-tdoa2")


def write_figure(rows: list[dict], path: Path = FIGURE, form: str | None = None) -> None:
    """Each test flight's 3D RMSE with the correction of `form` (default: the shipped
    recipe's) against without, one panel per flight split, one mark per seed: a mark
    above the diagonal is a flight the correction made worse."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recipe = form or shipped_recipe(rows)
    shipped = [r for r in rows if r["form"] == recipe and "flights" in r]
    splits = [s for s in FIGURE_SPLITS if any(r["split"] == s for r in shipped)]
    if not splits:      # a run of splits the recipe is not chosen on, or of other splits only
        print(f"no figure: the rows hold no flight split of the form {recipe!r}")
        return
    columns = 4
    fig, axes = plt.subplots(-(-len(splits) // columns), columns, figsize=(10, 5.6), squeeze=False)
    values = [f[k] for r in shipped for f in r["flights"] for k in ("rmse_3d", "rmse_3d_without")]
    low, top = 0.9 * min(values), 1.05 * max(values)
    for ax, split in zip(axes.flat, splits):
        for seed, marker in zip(sorted({r["seed"] for r in shipped if r["split"] == split}), "o^s"):
            flights = [f for r in shipped if r["split"] == split and r["seed"] == seed for f in r["flights"]]
            ax.scatter([f["rmse_3d_without"] for f in flights], [f["rmse_3d"] for f in flights], s=12,
                       marker=marker, alpha=0.7, label=f"seed {seed}")
        ax.plot([low, top], [low, top], color="grey", linewidth=0.8)
        ax.set(xlim=(low, top), ylim=(low, top), title=split, aspect="equal")
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("without correction (m)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(f"with the {recipe} correction (m)", fontsize=8)
    for ax in list(axes.flat)[len(splits):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="upper left")
    fig.suptitle("Each test flight's 3D RMSE, one mark per seed: above the diagonal, the correction made it worse",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")
