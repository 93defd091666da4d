"""benchmarks/concealed.py's three judges on one case: a lever arm added to a flight
whose own lever arm is beyond the airframe's bound. The suite and a check reading both
reports find the change; a check reading report.json's `findings` alone cannot, since
both fits are listed as not explained."""

from __future__ import annotations

import sys

import pytest
from rigtest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import concealed  # noqa: E402  - the benchmark's judges

PARAMS, CHECK = concealed.cases.CASES["lever_arm"]


def _lever_arm(offset_m: list[float], beyond: bool) -> dict:
    fit = {"effect": "lever_arm", "channel": "tdoa", "params": {"offset_m": offset_m}, "evidence": 40.0,
           "fit_before": 1.0, "fit_after": 0.9, "where": {}, "std_err": {"offset_m": [0.01, 0.01, 0.01]},
           "not_identified": []}
    return {**fit, "beyond_physical_bound": True} if beyond else fit


def _verdicts(own_m: list[float], own_beyond: bool) -> dict[str, bool]:
    added = [o + p for o, p in zip(own_m, PARAMS["offset_m"])]
    found = concealed.cases.keyed([_lever_arm(added, own_beyond)])
    control = {"findings": [_lever_arm(own_m, own_beyond)], "unnamed": [], "in_place": []}
    return {how: concealed.judge(found, control, "lever_arm", PARAMS, CHECK, True, None, None, how)[0]
            for how in concealed.JUDGES}


@pytest.mark.parametrize("own_m, beyond, in_findings", [([0.02, -0.01, 0.0], False, True),
                                                        ([0.3, -0.2, 0.1], True, False)])
def test_a_change_of_a_fit_beyond_bound_is_seen_only_by_the_judges_reading_both_lists(
        own_m: list[float], beyond: bool, in_findings: bool) -> None:
    verdicts = _verdicts(own_m, beyond)
    assert verdicts == {"suite": True, "reports": True, "findings": in_findings}


def test_a_wrong_change_is_missed_by_every_judge() -> None:
    found = concealed.cases.keyed([_lever_arm([0.3, -0.2, 0.1], True)])     # nothing added
    control = {"findings": [_lever_arm([0.3, -0.2, 0.1], True)], "unnamed": [], "in_place": []}
    assert not any(concealed.judge(found, control, "lever_arm", PARAMS, CHECK, True, None, None, how)[0]
                   for how in concealed.JUDGES)
