"""What a replay must meet: accuracy and budget bars, real-time deadlines, and the
main job's checks (`rig demo`: the default recording into native and QEMU)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEMO_TARGETS = ("native", "qemu")
# the default recording carries the room's measured effects (docs/guide/diagnosis.md): the
# robust estimator without the bias network gets 0.18-0.35 m (median 0.27) on the real
# flights of that room (docs/notebook/accuracy.md), 0.30 m on it
DEMO_MAX_RMSE_M = 0.40
DEMO_MAX_BUDGET = 0.20
# The real-time bar is the worst window under QEMU, whose instruction counts are
# deterministic. The native program's wall clock also counts the host scheduler's
# preemptions: its worst window is 50-100x its p99 on a quiet machine and crossed the
# bar when other work shared the two cores, so there the p99 is judged (it still
# catches any slowdown of the estimator itself).
DEMO_BUDGET_FIGURE = {"native": "window_p99", "qemu": "window_max"}
DEMO_AGREEMENT_M = 0.002


@dataclass
class Check:
    """One asserted bar: what was measured against it, and whether it held."""

    name: str
    passed: bool
    message: str          # the measured figure and its bar


def checks(result: dict, max_rmse: float | None, max_budget: float | None, figure: str = "window_max",
           deadlines: bool = False, late_allowed: float = 0.0) -> list[Check]:
    """The bars asked for: accuracy (m), budget (a fraction of the 10 ms budget, on the
    timing `figure`: the worst window unless said otherwise), real-time deadlines (no
    window missed, at most `late_allowed` of those sent late)."""
    out = []
    if max_rmse is not None:
        if "rmse_3d" not in result:
            out.append(Check("rmse_3d", False, f"no rmse_3d to compare with {max_rmse} m ({result.get('score_error')})"))
        else:
            held = result["rmse_3d"] <= max_rmse
            out.append(Check("rmse_3d", held, f"rmse_3d {result['rmse_3d']:.3f} m {'<=' if held else '>'} {max_rmse} m"))
    if max_budget is not None:
        timing = result["timing"]
        fraction = timing[figure] / timing["budget"]
        held = fraction <= max_budget
        name = "worst window" if figure == "window_max" else figure.replace("_", " ")
        out.append(Check(f"budget {figure}", held,
                         f"{name} {fraction:.1%} of the budget {'<=' if held else '>'} {max_budget:.1%}"))
    if deadlines:
        rt = result.get("realtime")
        if rt is None:
            out.append(Check("deadlines", False, "--assert-deadlines needs --mode realtime"))
        else:
            out.append(_deadlines(rt, late_allowed))
    return out


def _deadlines(rt: dict, late_allowed: float) -> Check:
    """No window missed, and no more late than allowed: a share of the windows sent,
    for a host whose scheduler now and then holds the rig or the emulator for a few ms."""
    late, missed, sent = rt["late_windows"], rt["missed_windows"], rt["windows_sent"]
    too_late = late > late_allowed * sent
    failed = ([f"{late} late windows" + (f" (more than {late_allowed:.1%} of {sent})" if late_allowed else "")]
              if too_late else []) + ([f"{missed} missed windows"] if missed else [])
    held = f"{late} late windows of {sent} (at most {late_allowed:.1%} allowed), none missed"
    return Check("deadlines", not failed, ", ".join(failed) or (held if late else "no late or missed window"))


def assertions(result: dict, max_rmse: float | None, max_budget: float | None,
               figure: str = "window_max") -> list[str]:
    """What failed of an accuracy bar (m) and a budget bar (see `checks`)."""
    return [c.message for c in checks(result, max_rmse, max_budget, figure) if not c.passed]


def replay_check(metrics: dict) -> Check:
    """Whether a replay ran to its end: the first testcase of every board."""
    ended = metrics.get("ended", "error" if metrics.get("error") else "completed")
    passed = ended == "completed" and not metrics.get("error")
    detail = f": {metrics['error']}" if metrics.get("error") else f", {metrics.get('n_estimates', 0)} estimates"
    return Check("replay", passed, f"ended {ended}{detail}")


def replay_cases(board: str, board_checks: list[Check], metrics: dict) -> tuple[str, list[Check], float]:
    """A board's testcases: its replay, then each asserted bar on it."""
    return board, [replay_check(metrics), *board_checks], float(metrics.get("wall_seconds", 0.0))


def write_junit(path: Path, suite: str, groups: list[tuple[str, list[Check], float]]) -> None:
    """A JUnit XML report CI systems read: per group (a board, a bench target), one
    testcase per check, a failure carrying the measured figure and its bar. `groups`:
    (name, its checks, seconds it took, given to its first testcase)."""
    import xml.etree.ElementTree as ElementTree

    root = ElementTree.Element("testsuites")
    element = ElementTree.SubElement(root, "testsuite", name=suite)
    tests = failures = 0
    for name, group_checks, seconds in groups:
        for k, check in enumerate(group_checks):
            tests += 1
            case = ElementTree.SubElement(element, "testcase", classname=f"{suite}.{name}", name=check.name,
                                          time=f"{seconds if k == 0 else 0.0:.3f}")
            if not check.passed:
                failures += 1
                ElementTree.SubElement(case, "failure", message=check.message).text = check.message
            else:
                ElementTree.SubElement(case, "system-out").text = check.message
    element.set("tests", str(tests))
    element.set("failures", str(failures))
    path.parent.mkdir(parents=True, exist_ok=True)
    ElementTree.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def demo(recording: Path, out: Path, replay_into) -> tuple[dict[str, dict], float, list[str]]:
    """The main job: `recording` into each of DEMO_TARGETS (`replay_into(recording,
    target, directory)` returns its metrics), accuracy and budget asserted, the two
    targets compared. Returns the metrics by target, the gap between their RMSEs (m)
    and what failed."""
    results, failed = {}, []
    for target in DEMO_TARGETS:
        results[target] = replay_into(recording, target, out / target)
        failed += [f"{target}: {r}" for r in assertions(results[target], DEMO_MAX_RMSE_M, DEMO_MAX_BUDGET,
                                                          DEMO_BUDGET_FIGURE[target])]
    gap = abs(results["native"]["rmse_3d"] - results["qemu"]["rmse_3d"])
    if gap > DEMO_AGREEMENT_M:
        failed.append(f"native and QEMU disagree by {gap * 1e3:.1f} mm")
    return results, gap, failed
