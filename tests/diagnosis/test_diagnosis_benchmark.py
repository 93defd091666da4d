"""benchmarks/diagnosis.py's summary lines on made-up reports: the bound check splits
what `not_explained` holds into fits beyond their bound and fits within it (left out
of the model beside one beyond it), and the figures the page's summary quotes."""

from __future__ import annotations

import importlib.util

from rigtest import ROOT

_spec = importlib.util.spec_from_file_location("diagnosis_benchmark", ROOT / "benchmarks" / "diagnosis.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _report(before: float, after: float, offset_s: float | None, not_explained: list[dict]) -> dict:
    findings = [{"effect": "time_offset", "params": {"seconds": offset_s}}] if offset_s is not None else []
    return {"channels": {"tdoa": {"fit_before": before, "fit_after": after}}, "findings": findings,
            "not_explained": not_explained}


def test_the_bound_check_tells_fits_beyond_their_bound_from_those_left_out_beside_them() -> None:
    far = {"effect": "anchor_position", "params": {"anchor": 1, "offset_m": [2.0, 0.0, 0.0]}}
    plausible = {"effect": "anchor_delay", "params": {"anchor": 5, "meters": -0.07}}
    text = bench.bound_check({"a": _report(1.0, 0.5, -0.05, [far, plausible])})
    assert "0 of 1 on 1 flights" in text and "2 fits are under `not_explained`: 1 beyond it, 1 within it" in text


def test_the_summary_figures_are_the_fit_gained_and_the_offsets_named_and_modelled() -> None:
    reports = {"a": _report(0.5, 0.4, -0.04, []), "b": _report(0.5, 0.25, None, []), "c": _report(0.4, 0.3, -0.06, [])}
    models = {"a": {"effects": [{"effect": "time_offset", "params": {"seconds": -0.03}}]}, "b": {"effects": []},
              "c": {"effects": []}}
    text = bench.in_short(reports, models)
    assert "by 20%–50% (median 25%)" in text
    assert "named on 2 flights, median -50 ms" in text and "model on 1, median -30 ms" in text
