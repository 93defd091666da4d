"""What every command shares: exit statuses, the one-line error, progress bars, JSON
output, printing a score, and the options several commands take."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.data import paths

# Exit statuses: an assertion failed (1), bad input or usage (2), a board or link failed
# (3), the rig itself failed (4: the traceback goes to a log file); 128 + the signal
# when interrupted (130 SIGINT, 143 SIGTERM, 129 SIGHUP).
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_BOARD, EXIT_INTERNAL = 0, 1, 2, 3, 4
CRASH_LOG = "rig-error.log"


class CliError(Exception):
    """An error to report to the user in one line, without a traceback."""

    status = EXIT_BAD_INPUT


class BoardError(CliError):
    """A board or its link failed (what was recorded is kept; the message says where)."""

    status = EXIT_BOARD


def positive(kind: type):
    """An argparse type: a number of `kind` above zero, else a one-line usage error."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be above zero, not {text}")
        return value
    parse.__name__ = kind.__name__
    return parse


def anchor_ids(text: str) -> list[int]:
    """An argparse type: anchor ids as K,K (non-negative integers)."""
    try:
        ids = [int(k) for k in text.split(",")]
    except ValueError:
        ids = []
    if not ids or min(ids) < 0:
        raise argparse.ArgumentTypeError(f"not anchor ids K,K: {text!r}")
    return ids


def progress(total: int | None = None, desc: str = ""):
    """A tqdm wrapper factory that stays quiet when stderr is not a terminal."""
    from tqdm import tqdm

    def wrap(iterable):
        return tqdm(iterable, total=total, desc=desc, unit="msg", disable=not sys.stderr.isatty(),
                    mininterval=0.5, leave=False)
    return wrap


def write_json(path: Path | None, data: dict) -> None:
    """`data` into `path` as every command writes JSON; nothing when no path was asked for."""
    if path is None:
        return
    from rig.data.files import write_json as write

    write(path, data)


def print_imu_gaps(result: dict) -> None:
    """Windows the estimator predicted without an IMU sample, if any (a real flight has none)."""
    if result.get("imu_gaps"):
        print(f"IMU: {result['imu_gaps']} windows of 10 ms without a sample (held the last reading)"
              + (": the recording has no IMU samples, the estimate is TDOA alone"
                 if result.get("imu_samples") == 0 else ""), file=sys.stderr)


def print_accuracy(result: dict) -> None:
    if "score_error" in result:
        print(f"not scored: {result['score_error']}")
        return
    x, y, z = result["rmse_xyz"]
    print(f"RMSE 3D {result['rmse_3d']:.3f} m (x {x:.3f}, y {y:.3f}, z {z:.3f}); "
          f"p95 {result['p95_3d']:.3f} m, max {result['max_3d']:.3f} m over {result['n_scored']} estimates")
    if result.get("n_not_finite"):
        print(f"{result['n_not_finite']} of the {result['n_scored']} scored estimates are not finite numbers "
              "(counted as an infinite error)")
    if "correction_trust" in result:
        print("bias correction applied whole (--full-trust)" if result.get("full_trust") else
              f"bias correction applied at {result['correction_trust']:.0%} at the end of the flight: the share "
              "its measurements support (--full-trust applies all of it)")
    share = result.get("outside_trained_region")
    if share is not None:
        print(f"bias correction: {share:.1%} of the measurements corrected with the tag outside where the model "
              f"was trained{' (an extrapolation there: compare with --no-nn)' if share > 0 else ''}")


def add_estimator_options(p: argparse.ArgumentParser) -> None:
    """The recording and the estimator configuration, shared by evaluate and replay."""
    p.add_argument("recording", type=Path, nargs="?", default=paths.default_recording(),
                   help="MCAP recording or shared flight log (default: the shipped default recording)")
    survey_option(p)
    strict_option(p)
    no_nn_option(p)
    no_anchor_weighting_option(p)
    p.add_argument("--no-robust", action="store_true", help="plain EKF update instead of M-estimation")
    p.add_argument("--model", type=Path, help="bias network JSON (default: the shipped model)")
    p.add_argument("--full-trust", action="store_true",
                   help="apply the whole bias correction, not only the share the flight's measurements support")


def no_nn_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-nn", action="store_true",
                   help="no learned bias correction (the shipped network is the estimator's only one)")


def no_anchor_weighting_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-anchor-weighting", action="store_true",
                   help="do not down-weight the measurements of an anchor whose tracked range bias is large "
                        "(a blocked anchor; anchor_bias_c 0)")


def anchor_weighting_params(args: argparse.Namespace) -> dict:
    """The estimator parameters `--no-anchor-weighting` sets (none without it)."""
    return {"anchor_bias_c": 0.0} if getattr(args, "no_anchor_weighting", False) else {}


def strict_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strict", action="store_true",
                   help="a damaged or unfinished recording is an error (exit 2); by default the messages before "
                        "the damage are used, with a warning")


def survey_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--survey", type=Path, help="anchor survey of a flight log (default: anchor_MMDD.txt of the "
                                               "log's day, beside its flights directory or in the shared data)")


def add_segment_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--min-height", type=float, default=0.3, help="score only above this height (m)")
    p.add_argument("--skip-after-takeoff", type=float, default=5.0, help="seconds after take-off not scored")


REPLAY_FROM_GIVEN_START = ("a recording without ground truth is then replayed from its first IMU sample, timed "
                           "and not scored")


def add_start_pose_options(p: argparse.ArgumentParser, then: str = REPLAY_FROM_GIVEN_START) -> None:
    """--start-position and --start-yaw (read back by `start_pose`); `then`: what follows."""
    p.add_argument("--start-position", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help=f"where the drone stood, in the anchors' frame (metres), instead of the ground truth's "
                        f"pose: {then}")
    p.add_argument("--start-yaw", type=float, default=0.0, metavar="DEG",
                   help="with --start-position: the drone's heading (default 0); it starts level")


def start_pose(args: argparse.Namespace):
    """The start pose given on the command line, or None (the ground truth's)."""
    from rig.estimator.evaluate import StartPose

    if args.start_position is None:
        if args.start_yaw != 0.0:
            raise CliError("--start-yaw needs --start-position")
        return None
    return StartPose(tuple(args.start_position), args.start_yaw)
