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
