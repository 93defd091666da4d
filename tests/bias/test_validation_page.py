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
    assert {r["split"] for r in rows} == {*results.FLIGHT_SPLITS, *results.ESTIMATE_SPLITS, "anchors", "region", "sector"}
    assert {r["form"] for r in rows} == set(bv.FORMS)
    assert len({results.row_key(r) for r in rows}) == len(rows)


def test_the_estimates_table_needs_its_markers(tmp_path: Path, rows: list[dict]) -> None:
    page = tmp_path / "bias.md"
    page.write_text("# no table here\n")
    with pytest.raises(ValueError, match="markers"):
        results.write_estimates(rows, page)
    assert page.read_text() == "# no table here\n"


def _rows(form: str, rmse: float, worse: int, splits=results.FLIGHT_SPLITS) -> list[dict]:
    """One row per split (by default the day and mode splits) and seed: every seed alike."""
    return [{"split": split, "form": form, "seed": seed, "test": ["f"], "mean_rmse_3d": rmse,
             "mean_rmse_3d_without": 0.3, "worse_flights": worse, "tdoa": {"std_before": 0.3, "std_after": 0.25}}
            for split in splits for seed in (0, 1, 2)]


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


def _installation_rows(form: str, accuracy: float, within: float, within_worse: int, day_0422_worse: int) -> list[dict]:
    """A form's rows of every split session 68's rule weighs."""
    rows = _rows(form, accuracy, 0) + _rows(form, accuracy, day_0422_worse, ["day-0422"])
    spread = {"n": 10, "std_before": 0.3, "mean_before": 0.0, "std_after": 0.25, "mean_after": 0.0}
    for fold, seed in ((fold, seed) for fold in ("a", "b") for seed in (0, 1, 2)):
        # fold a's first `within_worse` flights made worse, on every seed; the rest at `within`
        flights = [{"flight": f"{fold}{k}", "rmse_3d": 0.31 if fold == "a" and k < within_worse else within,
                    "rmse_3d_without": 0.3} for k in range(2)]
        rows.append({"split": "within-0426", "fold": fold, "form": form, "seed": seed, "test": ["f", "g"],
                     "flights": flights, "tdoa": spread})
    return rows


@pytest.mark.parametrize("accuracy, within, within_worse, day_0422_worse, met, failed", [
    (0.214, 0.21, 0, 1, True, ""),
    (0.216, 0.21, 0, 1, False, "c"),        # 0.006 m less accurate
    (0.214, 0.21, 0, 3, False, "b"),        # as many new-day flights worse
    (0.214, 0.23, 0, 1, False, "a"),        # 0.276 × 0.23 / 0.3 = 0.212 m on the 0426 flights
    (0.214, 0.21, 1, 1, False, "a")])       # a 0426 flight made worse
def test_session_68s_rule_on_the_rows(accuracy, within, within_worse, day_0422_worse, met, failed) -> None:
    rows = _installation_rows("link", 0.210, 0.2, 0, 3) + \
        _installation_rows(results.INSTALLATION, accuracy, within, within_worse, day_0422_worse)
    verdict = results.installation_verdict(rows)
    assert verdict is not None and verdict["rule_met"] is met
    assert [k for k, ok in verdict["checks"].items() if not ok] == list(failed)
    assert verdict["figures"]["link"]["worse_new_days"] == 3.0
    assert results.installation_verdict([r for r in rows if r["split"] != "day-0422"]) is None
