"""The validation pages are what their kept results say: rewritten from
docs/notebook/bias-validation.json by benchmarks/bias_validation.py, the notebook page and
docs/bias.md's table of estimates come out the same, and every row on them was trained
on the MKL branch `rig train` pins."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
from rigtest import ROOT

from rig.bias.train import MKL_BRANCH

sys.path.insert(0, str(ROOT / "benchmarks"))
import bias_validation as bv
import bias_validation_results as results


@pytest.fixture(scope="module")
def rows() -> list[dict]:
    return json.loads(results.RESULTS.read_text())["rows"]


def test_the_pages_are_rewritten_from_their_kept_results(tmp_path: Path, rows: list[dict]) -> None:
    page, entry = tmp_path / "page.md", tmp_path / "bias.md"
    shutil.copy(results.ENTRY_PAGE, entry)
    bv.write_pages(rows, page, entry)
    hint = "run .venv/bin/python benchmarks/bias_validation.py --from-json"
    assert page.read_text() == results.PAGE.read_text(), hint
    assert entry.read_text() == results.ENTRY_PAGE.read_text(), hint


def test_every_row_is_of_the_protocol_on_the_pinned_branch(rows: list[dict]) -> None:
    assert {r.get("mkl_cbwr") for r in rows} == {MKL_BRANCH}
    assert {r["split"] for r in rows} == {*results.FLIGHT_SPLITS, *results.ESTIMATE_SPLITS, *results.SELECTION_SPLITS,
                                          "anchors", "region", "sector"}
    # every form but an experiment's, which runs into its own JSON
    assert {r["form"] for r in rows} == {f for f in bv.FORMS if f not in results.NOT_RANKED} | {results.UNTRANSLATED}
    assert len({results.row_key(r) for r in rows}) == len(rows)


def test_each_setup_fold_holds_out_both_flights_of_one_0426_setup_which_within_0426_splits() -> None:
    names = [f"0426-traj{k}" for k in range(1, 9)] + ["0425-traj1"]
    held = {fold: bv.test_flights(f"setup-0426-{fold}", names) for fold in results.SETUP_0426_FOLDS}
    assert sorted(f for fold in held.values() for f in fold) == sorted(names[:8])     # every 0426 flight once
    for fold, flights in held.items():
        first, second = sorted(int(f.removeprefix("0426-traj")) for f in flights)
        assert (first % 2, second) == (1, first + 1), fold       # a setup is flown as traj 2k-1 and 2k
        assert all(len(set(flights) & set(within)) == 1 for within in results.WITHIN_0426_FOLDS.values()), fold
    assert all(f in results.TDOA3 for f in held["shelf-tdoa3"])


def test_the_estimates_table_needs_its_markers(tmp_path: Path, rows: list[dict]) -> None:
    page = tmp_path / "bias.md"
    page.write_text("# no table here\n")
    with pytest.raises(ValueError, match="markers"):
        results.write_estimates(rows, page)
    assert page.read_text() == "# no table here\n"


def _rows(form: str, rmse: float, worse: int) -> list[dict]:
    """One row per day and mode split and seed: every seed alike."""
    return [{"split": split, "form": form, "seed": seed, "test": ["f"], "mean_rmse_3d": rmse,
             "mean_rmse_3d_without": 0.3, "worse_flights": worse, "tdoa": {"std_before": 0.3, "std_after": 0.25}}
            for split in results.FLIGHT_SPLITS for seed in (0, 1, 2)]


@pytest.mark.parametrize("untranslated, worse, met", [(0.214, 1, True),     # within 0.005 m, fewer worse
                                                      (0.216, 1, False),    # 0.006 m less accurate
                                                      (0.214, 2, False)])   # as many flights worse
def test_session_59s_rule_on_the_rows(untranslated: float, worse: int, met: bool) -> None:
    rows = _rows("link", 0.210, 2) + _rows(results.UNTRANSLATED, untranslated, worse)
    verdict = results.untranslated_verdict(rows)
    assert verdict is not None and verdict["rule_met"] is met
    assert verdict["worse_flights"] == {"link": 8.0, results.UNTRANSLATED: 4.0 * worse}
    assert results.untranslated_verdict(rows[:-1]) is not None        # a seed short still has every split
    assert results.untranslated_verdict([r for r in rows if r["split"] != "day-0426"]) is None



def _flight_rows(form: str, rmse: float, without: float = 0.25, worse_on: tuple[str, ...] = (),
                 seeds: tuple[int, ...] = (0, 1, 2), at: dict[str, float] | None = None) -> list[dict]:
    """Rows with flights, as the closed-loop splits write them: one flight a split and
    seed, `rmse` everywhere but on the splits `at` names, above `without` on the splits in
    `worse_on`."""
    splits = (*results.FLIGHT_SPLITS, *results.ESTIMATE_SPLITS, *results.SELECTION_SPLITS)
    at = at or {}
    return [{"split": split, "form": form, "seed": seed,
             "flights": [{"flight": "f", "rmse_3d": at.get(split, rmse) + (without if split in worse_on else 0.0),
                          "rmse_3d_without": without}]}
            for split in splits for seed in seeds]


@pytest.mark.parametrize("rmse, worse_on, kept", [
    (0.194, (), True),                    # 0.006 m more accurate
    (0.197, (), False),                   # 0.003 m: not enough
    (0.194, ("within-0426",), False),     # a new flight of a trained day made worse
    (0.194, ("day-0426",), False),        # more flights worse
])
def test_the_rule_of_sessions_71_to_76_on_made_up_rows(rmse: float, worse_on: tuple, kept: bool) -> None:
    import form_rule

    verdict = form_rule.verdict_71(_flight_rows("link", 0.200), _flight_rows("x", rmse, worse_on=worse_on))
    assert verdict["kept"] is kept
    assert verdict["accuracy_m"]["link"] == pytest.approx(0.200)


@pytest.mark.parametrize("at, worse_on, fresh, kept", [
    ({"within-0425": 0.194}, (), 0.194, True),                       # 0.006 m lower where it chooses, on both seed sets
    ({"within-0425": 0.194}, (), 0.197, False),                      # not again on fresh seeds
    ({"within-0425": 0.194}, (), None, False),                       # the replication not run
    ({"within-0425": 0.197}, (), 0.194, False),                      # 0.003 m: not enough
    ({"within-0425": 0.194, "day-0426": 0.204, "day-0425": 0.203}, (), 0.194, False),   # a new day 0.0035 m higher
    ({"within-0425": 0.194, "day-0426": 0.203}, (), 0.194, True),    # 0.0015 m higher: within its tolerance
    ({"within-0425": 0.194}, ("within-0426",), 0.194, False),        # a new flight of 0426 made worse
    ({"within-0425": 0.194}, ("within-0425",), 0.194, False),        # more flights worse where it chooses
    ({"within-0425": 0.194}, ("day-0426", "day-0425"), 0.194, False),   # two more flights worse on new days
    ({"within-0425": 0.194, "mode-tdoa3": 0.250, "day-0422": 0.240}, (), 0.194, True),   # these decide nothing
])
def test_the_rule_of_session_77_on_made_up_rows(at: dict, worse_on: tuple, fresh: float | None, kept: bool) -> None:
    import form_rule

    link = _flight_rows("link", 0.200) + _flight_rows("link", 0.200, seeds=(3, 4, 5))
    form = _flight_rows("x", 0.200, worse_on=worse_on, at=at)
    if fresh is not None:
        form += _flight_rows("x", 0.200, seeds=(3, 4, 5), at={"within-0425": fresh})
    verdict = form_rule.verdict_77(link, form)
    assert verdict["kept"] is kept
    assert verdict["4"] is (None if fresh is None else fresh < 0.195)


def test_the_form_rule_says_which_flights_moved_and_which_each_side_made_worse() -> None:
    import form_rule

    def rows(form: str, figures: dict[str, tuple[float, ...]]) -> list[dict]:
        return [{"split": "within-0425", "form": form, "seed": seed,
                 "flights": [{"flight": name, "rmse_3d": values[seed], "rmse_3d_without": 0.20}
                             for name, values in figures.items()]}
                for seed in (0, 1, 2)]

    link = rows("link", {"a": (0.19, 0.19, 0.19), "b": (0.15, 0.15, 0.15), "c": (0.21, 0.19, 0.19)})
    form = rows("x", {"a": (0.18, 0.21, 0.19), "b": (0.12, 0.12, 0.12), "c": (0.19, 0.19, 0.19)})
    changes = form_rule.flight_changes(link, form, "within-0425")
    assert [c["flight"] for c in changes] == ["b", "c", "a"]                  # largest change first
    assert changes[0]["change_m"] == pytest.approx(-0.03)
    assert changes[2]["worse_seeds"] == {"form": [1], "link": []}
    assert changes[1]["worse_seeds"] == {"form": [], "link": [0]}
    line = form_rule.describe_flights(changes)
    assert line.startswith("moved most: b -0.030 m") and "a worse on seeds [1] (link [])" in line
    assert "b worse" not in line
    assert form_rule.flight_changes(link, form, "day-0426") == []


def test_the_form_rule_compares_a_replications_link_rows_from_its_own_json(tmp_path: Path) -> None:
    import subprocess

    both = tmp_path / "replication.json"
    both.write_text(json.dumps({"rows": _flight_rows("link", 0.210) + _flight_rows("x", 0.200)}))
    command = [sys.executable, str(ROOT / "benchmarks" / "form_rule.py"), "--form", "x", "--json", str(both)]
    against_own = subprocess.run([*command, "--link-json", str(both)], capture_output=True, text=True, check=True)
    verdict = json.loads(against_own.stdout.splitlines()[-1])
    assert verdict["rule"] == 77 and verdict["4"] is None and not verdict["kept"]    # no fresh seeds run
    assert verdict["new_day"]["link"][0] == pytest.approx(0.210)
    by_71 = subprocess.run([*command, "--link-json", str(both), "--rule", "71"], capture_output=True, text=True,
                           check=True)
    verdict = json.loads(by_71.stdout.splitlines()[-1])
    assert verdict["kept"] and verdict["accuracy_m"]["link"] == pytest.approx(0.210)
    alone = tmp_path / "x.json"
    alone.write_text(json.dumps({"rows": _flight_rows("x", 0.200)}))
    refused = subprocess.run([*command[:-2], "--json", str(alone), "--link-json", str(alone)],
                             capture_output=True, text=True)
    assert refused.returncode == 2 and "no rows of the link form" in refused.stderr


def test_the_form_rule_compares_rows_of_one_cpu_only(tmp_path: Path) -> None:
    import subprocess

    elsewhere = [{**row, "cpu": "AuthenticAMD 25 17"} for row in _flight_rows("x", 0.200)]
    kept_rows, experiment = tmp_path / "kept.json", tmp_path / "x.json"
    kept_rows.write_text(json.dumps({"rows": _flight_rows("link", 0.210)}))       # made on the earlier CPU
    experiment.write_text(json.dumps({"rows": elsewhere}))
    command = [sys.executable, str(ROOT / "benchmarks" / "form_rule.py"), "--form", "x", "--json", str(experiment),
               "--link-json", str(kept_rows), "--rule", "71"]
    refused = subprocess.run(command, capture_output=True, text=True)
    assert refused.returncode == 2 and "no link rows of the CPU AuthenticAMD 25 17" in refused.stderr
    same_cpu = [{**row, "cpu": "AuthenticAMD 25 17"} for row in _flight_rows("link", 0.210)]
    experiment.write_text(json.dumps({"rows": elsewhere + same_cpu}))
    verdict = json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout.splitlines()[-1])
    assert verdict["kept"] and verdict["accuracy_m"]["link"] == pytest.approx(0.210)


@pytest.mark.parametrize("lower, day_0422, kept", [
    (0.196, 0.200, 0.3),                  # 0.004 m more accurate: the lower value replaces 0.4
    (0.198, 0.200, 0.4),                  # 0.002 m: not enough
    (0.196, 0.203, 0.4),                  # the other-day proxy 0.003 m worse
])
def test_the_parameter_rule_on_made_up_rows(lower: float, day_0422: float, kept: float) -> None:
    import param_transfer

    rows = _flight_rows("link", 0.200)
    for row in rows:
        for flight in row["flights"]:
            at_lower = day_0422 if row["split"] == "day-0422" else lower
            flight["by_level"] = {"0.3": at_lower, "0.4": 0.200, "0.55": 0.210}
            flight["without_by_level"] = {"0.3": 0.25, "0.4": 0.25, "0.55": 0.25}
    assert param_transfer.verdict(rows, (0.3, 0.4, 0.55), 0.4)["value"] == kept


def test_the_cpu_comparison_on_made_up_rows() -> None:
    import cpu_repeat

    kept = _flight_rows("link", 0.210)                                            # made on the earlier CPU
    other = [{**row, "cpu": "AuthenticAMD 25 17"} for row in _flight_rows("link", 0.214, worse_on=("day-0422",))]
    result = cpu_repeat.compare(kept, other, form="link")
    assert list(result["splits"]) == [results.EARLIER_CPU, "AuthenticAMD 25 17"]
    assert result["splits"]["AuthenticAMD 25 17"]["day-0422"]["worse"] == 1.0
    assert result["estimates_0426"][results.EARLIER_CPU]["pooled_m"] == pytest.approx(0.276 * 0.210 / 0.25)
    assert result["estimates_0426"][results.EARLIER_CPU]["per_mode_m"] is None       # no TDOA3 flight among them
    assert "m pooled, no flight of one mode per mode" in "\n".join(cpu_repeat.table(result))
    assert "| within-0426 | 0.2100 m (0.2100–0.2100), 0.0 | 0.2140 m (0.2140–0.2140), 0.0 | +0.0040 m |" \
        in cpu_repeat.table(result)


def test_the_other_cpus_rows_are_of_another_cpu_and_cover_the_estimates(rows: list[dict]) -> None:
    import subprocess

    import cpu_repeat

    other = json.loads(cpu_repeat.OTHER_CPU_ROWS.read_text())["rows"]
    assert {results.row_cpu(r) for r in other} == {"AuthenticAMD 25 17"}
    assert {(r["split"], r["seed"]) for r in other} >= {(s, seed) for s in cpu_repeat.SPLITS[1:] for seed in (0, 1, 2)}
    printed = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "cpu_repeat.py")],
                             capture_output=True, text=True, check=True).stdout
    assert "0426 check from AuthenticAMD 25 17's within-0426 rows" in printed


def test_the_figure_draws_every_flight_split_of_the_shipped_recipe(tmp_path: Path) -> None:
    figure = tmp_path / "bias_validation.png"
    made_up = [{**row, "test": ["f"]} for row in _flight_rows("link", 0.2)]
    results.write_figure(made_up, figure, form="link")
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
    nothing = tmp_path / "none.png"
    results.write_figure(made_up, nothing, form="pair")       # no rows of that form: no figure, no error
    assert not nothing.exists()
