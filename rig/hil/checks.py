"""What a replay must meet: accuracy and budget bars, real-time deadlines, and the
main job's checks (`rig demo`: the default recording into native and QEMU)."""

from __future__ import annotations

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


def assertions(result: dict, max_rmse: float | None, max_budget: float | None,
               figure: str = "window_max") -> list[str]:
    """What failed of an accuracy bar (m) and a budget bar (fraction of the 10 ms budget,
    on the timing `figure`: the worst window unless said otherwise)."""
    failed = []
    if max_rmse is not None and "rmse_3d" not in result:
        failed.append(f"no rmse_3d to compare with {max_rmse} m ({result.get('score_error')})")
    elif max_rmse is not None and not result["rmse_3d"] <= max_rmse:
        failed.append(f"rmse_3d {result['rmse_3d']:.3f} m > {max_rmse} m")
    timing = result["timing"]
    fraction = timing[figure] / timing["budget"]
    if max_budget is not None and not fraction <= max_budget:
        name = "worst window" if figure == "window_max" else figure.replace("_", " ")
        failed.append(f"{name} {fraction:.1%} of the budget > {max_budget:.1%}")
    return failed


def deadline_failures(result: dict) -> list[str]:
    """Late and missed windows of a real-time replay (any is a failure)."""
    rt = result.get("realtime")
    if rt is None:
        return ["--assert-deadlines needs --mode realtime"]
    return [f"{rt[key]} {key.replace('_', ' ')}" for key in ("late_windows", "missed_windows") if rt[key]]


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
