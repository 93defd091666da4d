"""One replay job: a recording into one target through its bridge, with its outputs in
a directory — the run record (written as it goes, finished on every exit path),
metrics.json (also after a board failure, with the error) and the HTML report.

`rig replay`, `rig demo` and `rig farm` are this job with different options.
"""

from __future__ import annotations

import logging
import math
import os
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from rig.data.files import write_json
from rig.hil.links import LinkError

if TYPE_CHECKING:
    from rig.data.recording import Recording
    from rig.estimator.evaluate import StartPose

log = logging.getLogger(__name__)

METRICS_FILE = "metrics.json"
# How a job ended (metrics.json's `ended`): every board answered; a signal stopped it;
# the board or its link failed; the rig itself failed.
ENDED = ("completed", "interrupted", "board_lost", "error")
BOARD_NAME = re.compile(r"[A-Za-z0-9_.-]+")      # no zenoh wildcard or separator (* ** $ / #) in a name
TARGET = re.compile(r"native|native-udp|qemu|qemu-usart|(serial|crazyflie|zenoh):.+")


@dataclass
class EstimatorChoice:
    """Which estimator the board runs: the robust update or the plain one, with the bias
    network (the shipped one unless `model_path`) or without, weighting blocked anchors
    or not."""

    use_nn: bool = True
    robust: bool = True
    model_path: Path | None = None
    full_trust: bool = False       # the whole correction, not the share the flight supports
    anchor_weighting: bool = True  # down-weight an anchor whose tracked range bias is large

    def params(self) -> dict:
        """The estimator parameters it sets beyond the choice of update and network."""
        return {} if self.anchor_weighting else {"anchor_bias_c": 0.0}


class JobFailed(LinkError):
    """The board or its link failed mid-job; what was recorded is kept (the message says where)."""

    def __init__(self, message: str, result: dict):
        super().__init__(message)
        self.result = result


# Windows kept in flight ahead of the one awaited (same answers: the board takes them in
# order). The native program's pty buffers a few; a board's receive ring is 1 kB, and
# on QEMU a window's instruction count would take in the next window's arriving bytes.
NATIVE_LOOKAHEAD = 2


def default_lookahead(target: str) -> int:
    return NATIVE_LOOKAHEAD if target == "native" else 0


def writable_directory(out: Path) -> None:
    """Create `out` and check that files can be written in it, before any board starts
    (InputError naming it otherwise)."""
    from rig.data.errors import InputError

    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe.", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"cannot write to the output directory {out}: {exc.strerror or exc}") from exc


def check_options(target: str, board: str = "local", start: float | None = None, duration: float | None = None,
                  lookahead: int | None = None, speed: float | None = None, full_answer_every: int = 1,
                  late_allowed: float = 0.0) -> None:
    """Refuse option values a replay cannot use, before anything starts or is written
    (ValueError, saying the rule)."""
    if not TARGET.fullmatch(target):
        raise ValueError(f"unknown target {target!r} (native, native-udp, qemu, qemu-usart, serial:URL, crazyflie:URI or "
                         "zenoh:NAME)")
    for name in ([board] + ([target[len("zenoh:"):]] if target.startswith("zenoh:") else [])):
        if not BOARD_NAME.fullmatch(name):
            raise ValueError(f"board name {name!r}: letters, digits, '_', '.' and '-' only (no wildcard or '/')")
    if start is not None and not math.isfinite(start):
        raise ValueError(f"--start must be a finite time, not {start}")
    if duration is not None and not duration > 0:
        raise ValueError(f"--duration must be a positive number of seconds, not {duration}")
    if lookahead is not None and lookahead < 0:
        raise ValueError(f"--lookahead must be 0 (strict lock-step) or more windows, not {lookahead}")
    if speed is not None and not speed > 0:
        raise ValueError(f"--speed must be a positive number, not {speed}")
    if full_answer_every < 1:
        raise ValueError(f"--full-answer-every must be 1 (every answer full) or more windows, not {full_answer_every}")
    if not 0.0 <= late_allowed <= 1.0:
        raise ValueError(f"--late-allowed must be a share of the windows sent, from 0 to 1, not {late_allowed}")


def board_link(target: str, session, board: str):
    """The rig reaches boards only through a bridge: a remote one (zenoh:NAME) over the
    session, or an in-process one tapping a local board's link onto the session."""
    from rig.hil.targets import open_target
    from rig.hil.zenoh import TapLink, ZenohLink

    if target.startswith("zenoh:"):
        return ZenohLink(session, target[len("zenoh:"):]).open()
    return TapLink(open_target(target), session, board)


def replay_job(recording: Path, target: str, out: Path, estimator: EstimatorChoice = EstimatorChoice(), *,
               start: float | None = None, duration: float | None = None, lookahead: int | None = None,
               speed: float | None = None, full_answer_every: int = 1, report: bool = True, session=None,
               board: str = "local",
               survey: Path | None = None, progress=None, strict: bool = False,
               loaded: Recording | None = None, on_scored: Callable[[dict], None] | None = None,
               start_pose: StartPose | None = None) -> dict:
    """Replay `recording` into `target` (through zenoh `session`, or a private one) and
    write OUT/run.mcap, OUT/metrics.json and, with `report`, OUT/report.html. Returns
    what metrics.json holds; raises JobFailed (after writing both files) when the board
    or its link failed. Interrupted (a signal) it finishes both files, marked
    `ended: interrupted`, and raises the interruption on. `loaded`: the recording
    already read (a farm replays one recording into many boards). `on_scored` sees the
    result before any file of it is written (a full disk must not hide the score).
    `full_answer_every`: compact answers, the counters and timing every N windows.
    `start_pose`: where the drone stood, for a recording without ground truth (the run
    is then timed and not scored)."""
    from rig.data.errors import InputError
    from rig.data.importer import load_any
    from rig.estimator.evaluate import estimator_config, initial_pose, start_time
    from rig.hil import replay
    from rig.hil.runrecord import RUN_FILE, RunRecorder
    from rig.hil.zenoh import open_session

    check_options(target, board, start, duration, lookahead, speed, full_answer_every)
    lookahead = default_lookahead(target) if lookahead is None else lookahead
    rec = load_any(recording, survey, strict=strict) if loaded is None else loaded
    first, last = start_time(rec, given=start_pose) if start is None else start, float(rec.time_span()[1])
    if first >= last:
        raise InputError(f"--start {first:g} s is past the end of {recording} ({last:g} s on its clock)")
    initial_pose(rec, first, start_pose)      # a pose to start from, before a board starts or a file is written
    params, model = estimator_config(estimator.robust, estimator.use_nn, estimator.model_path,
                                     full_trust=estimator.full_trust, **estimator.params())
    writable_directory(out)
    recorder = RunRecorder(out / RUN_FILE)
    info = {"recording": str(recording), "target": target, "bias_net": model is not None,
            "start_pose": None if start_pose is None else start_pose.as_dict(),
            "robust": estimator.robust, "lookahead": lookahead, "mode": "lockstep" if speed is None else "realtime",
            "full_answer_every": full_answer_every, "full_trust": estimator.full_trust,
            "anchor_weighting": estimator.anchor_weighting}
    began, run, error, own, link, ended, stop = time.monotonic(), None, None, session is None, None, ENDED[0], None
    try:
        session = session or open_session()
        link = board_link(target, session, board)
        run = replay.run(link, rec, params, model, start=start, duration=duration, lookahead=lookahead,
                         speed=speed, full_every=full_answer_every, progress=progress, recorder=recorder,
                         start_pose=start_pose)
    except LinkError as exc:
        error, run, ended = str(exc), getattr(exc, "session", None), "board_lost"
        recorder.status(run.t0 if run else 0.0, "rig", -1, error)
    except KeyboardInterrupt as exc:          # SIGINT, SIGTERM, SIGHUP: finish everything, then stop
        stop, run, ended = exc, getattr(exc, "session", None), "interrupted"
        error = f"interrupted by {exc.args[0] if exc.args else 'SIGINT'}"
        recorder.status(run.t0 if run else 0.0, "rig", -1, error)
    except Exception as exc:
        error, ended, stop = f"{type(exc).__name__}: {exc}", "error", exc
        recorder.status(0.0, "rig", -1, error)
    finally:
        recorder.close()         # first: the record is whole whatever the link's teardown does
        try:
            if link is not None:
                info["bytes_sent"], info["bytes_received"] = link.bytes_sent, link.bytes_received
                link.close()
        finally:
            if own and session is not None:
                session.close()
    wall = time.monotonic() - began
    result = score_run(run, rec, model)
    info.setdefault("bytes_sent", 0)       # the link never opened
    info.setdefault("bytes_received", 0)
    result.update(info)
    loop = run.loop_seconds if run is not None and run.loop_seconds else wall
    result.update({"wall_seconds": wall, "loop_seconds": loop,
                   "speed": result["n_estimates"] * replay.BUDGET_SECONDS / loop,
                   "run_record": str(out / RUN_FILE), "run_record_error": recorder.failed, "error": error,
                   "ended": ended})
    if on_scored is not None:
        on_scored(result)
    write_json(out / METRICS_FILE, result)
    if stop is not None:
        raise stop
    if error is not None:
        raise JobFailed(f"{error} (kept: {out / RUN_FILE}, {out / METRICS_FILE} with "
                        f"{result['n_estimates']} estimates)", result)
    if report:
        from rig.hil.report import write_report

        write_report(out, recorder.kept)
    return result


def score_run(run, rec, model=None) -> dict:
    """Accuracy and timing of what the board answered, and what it reported of the link;
    a run cut short before the scored segment still reports its estimates, timing,
    real-time bookkeeping and counters, without accuracy."""
    from rig.data.recording import TOPIC_TRUTH
    from rig.estimator.metrics import MetricsError
    from rig.hil import replay

    if run is None:
        return {"n_estimates": 0}
    board_link = {"board_link": replay.board_link_summary(run.statuses)}
    if not run.estimates:
        return {"n_estimates": 0} | board_link
    try:
        if len(rec.truth) == 0:
            raise MetricsError(f"the recording has no ground truth on {TOPIC_TRUTH}: timed, not scored")
        accuracy = replay.score(run, rec, model)
    except MetricsError as exc:
        accuracy = {"score_error": str(exc)}
    return accuracy | replay.answers_summary(run, model) | board_link
