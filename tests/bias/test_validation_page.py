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
import bias_validation as bv  # noqa: E402
import bias_validation_results as results  # noqa: E402


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
    assert {r["split"] for r in rows} == {*results.FLIGHT_SPLITS, "within-0426", "anchors", "region", "sector"}
    assert {r["form"] for r in rows} == set(bv.FORMS)
    assert len({results.row_key(r) for r in rows}) == len(rows)


def test_the_estimates_table_needs_its_markers(tmp_path: Path, rows: list[dict]) -> None:
    page = tmp_path / "bias.md"
    page.write_text("# no table here\n")
    with pytest.raises(ValueError, match="markers"):
        results.write_estimates(rows, page)
    assert page.read_text() == "# no table here\n"
