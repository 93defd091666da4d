"""The bars a replay is held to, judged on its metrics alone (no board needed)."""

from __future__ import annotations

from rig.hil.checks import checks


def test_the_deadline_check_fails_a_missed_window_and_late_windows_beyond_the_allowance() -> None:
    def deadline(late: int, missed: int, allowed: float) -> tuple[bool, str]:
        realtime = {"late_windows": late, "missed_windows": missed, "windows_sent": 2000}
        (check,) = checks({"realtime": realtime}, None, None, deadlines=True, late_allowed=allowed)
        return check.passed, check.message

    assert deadline(0, 0, 0.0) == (True, "no late or missed window")
    assert deadline(1, 0, 0.0) == (False, "1 late windows")
    assert deadline(20, 0, 0.01) == (True, "20 late windows of 2000 (at most 1.0% allowed), none missed")
    assert deadline(21, 0, 0.01) == (False, "21 late windows (more than 1.0% of 2000)")
    assert deadline(0, 1, 1.0) == (False, "1 missed windows")
    assert not checks({}, None, None, deadlines=True)[0].passed        # lock-step has no deadlines


def test_a_real_time_summary_says_which_windows_were_late_and_where_the_slowest_fell() -> None:
    from rig.hil.replay import RealTime

    rt = RealTime(speed=1.0)
    for k in range(1, 201):
        t_us = k * 10_000
        rt.sent_at[t_us] = float(k)
        if k != 150:                                          # one window never answered
            rt.latency[t_us] = {1: 0.0116, 120: 0.0105}.get(k, 0.0004)
    summary = rt.summary()
    assert summary["windows_sent"] == 200 and summary["late_windows"] == 2
    assert summary["first_late_t_us"] == [10_000, 1_200_000] and summary["slowest_t_us"] == 10_000
    assert summary["missed_windows"] == 1 and summary["first_missed_t_us"] == [1_500_000]
    assert summary["latency_ms"]["max"] == 11.6
    (check,) = checks({"realtime": summary}, None, None, deadlines=True, late_allowed=0.01)
    assert not check.passed and check.message == "1 missed windows"
