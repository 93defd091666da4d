"""How report.md and `rig diagnose` word a finding: its standard errors follow its
parameters, as report.json gives them (a noise-level finding has none), and a fit
beyond its physical bound says by how many of them."""

from __future__ import annotations

from rig.diagnosis.findings import Finding
from rig.diagnosis.wording import describe


def _finding(effect: str, params: dict, std_err: dict | None) -> Finding:
    return Finding(effect, "tdoa", [], params, 40.0, 1.0, 0.9, {}, std_err=std_err)


def test_a_fitted_finding_gives_its_standard_errors() -> None:
    lever = _finding("lever_arm", {"offset_m": [0.45, -0.2, 0.1]}, {"offset_m": [0.131, 0.1249, 0.27]})
    assert describe(lever).endswith("(standard error [0.13, 0.12, 0.27])")
    delay = _finding("anchor_delay", {"anchor": 3, "meters": 0.24}, {"meters": 0.0671})
    assert "(standard error 0.067)" in describe(delay)
    drift = _finding("clock_drift", {"ppm": -287.0}, {"ppm": 543.2})
    assert "(standard error 543)" in describe(drift)


def test_an_nlos_gives_its_mean_shifts_and_a_noise_level_finding_none() -> None:
    nlos = _finding("nlos", {"anchor": 0, "fraction": 0.5, "mean_excess_m": 0.3,
                             "region": {"min": [0, 0, 0], "max": [1, 1, 1]}}, {"mean_shift_m": 0.021})
    assert "(standard error of its mean shift 0.021)" in describe(nlos)
    floor = _finding("multipath_floor", {"height_m": 0.6, "std_m": 0.2}, None)
    assert "standard error" not in describe(floor)


def test_a_fit_beyond_its_bound_says_by_how_many_standard_errors() -> None:
    """The lever arm's bound is 0.15 m: 0.45 m with a standard error of 0.12 m is 2.5 beyond."""
    lever = _finding("lever_arm", {"offset_m": [0.45, -0.2, 0.1]}, {"offset_m": [0.12, 0.1, 0.2]})
    lever.beyond_bound = True
    assert "(0.45 against 0.15, 2.5 standard errors beyond)" in describe(lever)
    lever.beyond_bound = False
    assert "standard errors beyond" not in describe(lever)
