"""Turn a Crazyflie uSD event log plus an anchor survey into a `Recording`.

Unit conversions: g → m/s² (×9.81), deg/s → rad/s, µs → s. Each stream is sorted
by time (stably), because the log's recording order is not strictly monotonic.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from rig.data.errors import SurveyError
from rig.data.recording import PoseSeries, Recording, TdoaSeries, Vec3Series
from rig.data.survey import parse_survey
from rig.data.usdlog import DecodedLog, LogFormatError, read_log

log = logging.getLogger(__name__)

GRAVITY = 9.81  # m/s² per g, as the Crazyflie firmware scales its accelerometer
DEG_TO_RAD = np.pi / 180.0
US_TO_S = 1e-6

REQUIRED_EVENTS = {
    "estAcceleration": ("acc.x", "acc.y", "acc.z"),
    "estGyroscope": ("gyro.x", "gyro.y", "gyro.z"),
    "estTDOA": ("idA", "idB", "distanceDiff"),
    "estPose": ("locSrv.x", "locSrv.y", "locSrv.z", "locSrv.qx", "locSrv.qy", "locSrv.qz", "locSrv.qw"),
}

# Share of TDOA samples from consecutive anchor pairs above which the mode is TDOA2.
TDOA2_CONSECUTIVE_SHARE = 0.8


def _columns(decoded: DecodedLog, event: str) -> tuple[np.ndarray, np.ndarray]:
    series = decoded.series(event)
    missing = [v for v in REQUIRED_EVENTS[event] if v not in series.type.variables]
    if missing:
        raise LogFormatError(f"event {event} lacks variable(s) {missing}")
    order = np.argsort(series.timestamps_us, kind="stable")
    values = np.column_stack([series.column(v) for v in REQUIRED_EVENTS[event]]) if len(series) else \
        np.zeros((0, len(REQUIRED_EVENTS[event])))
    return series.timestamps_us[order].astype(np.float64) * US_TO_S, values[order]


def infer_uwb_mode(id_a: np.ndarray, id_b: np.ndarray, n_anchors: int) -> str:
    """TDOA2 anchors answer each other in a ring, so most pairs are (k, k+1 mod n)."""
    if len(id_a) == 0 or n_anchors < 2:
        return "unknown"
    consecutive = np.mean((id_a + 1) % n_anchors == id_b)
    return "TDOA2" if consecutive >= TDOA2_CONSECUTIVE_SHARE else "TDOA3"


def import_log(log_path: Path, survey_path: Path, *, salvage: bool = False, uwb_mode: str | None = None) -> Recording:
    """Decode `log_path`, attach the anchors of `survey_path`, convert to SI units."""
    decoded = read_log(log_path, salvage=salvage)
    anchors = parse_survey(survey_path)

    t_acc, acc = _columns(decoded, "estAcceleration")
    t_gyr, gyr = _columns(decoded, "estGyroscope")
    t_tdoa, tdoa = _columns(decoded, "estTDOA")
    # a flight without motion capture has no estPose: it is replayed from a given start (rig replay --start-position)
    t_pose, pose = _columns(decoded, "estPose") if "estPose" in decoded.events else (np.zeros(0), np.zeros((0, 7)))

    id_a = tdoa[:, 0].astype(int)
    id_b = tdoa[:, 1].astype(int)
    known = {a.id for a in anchors}
    unknown = sorted((set(id_a.tolist()) | set(id_b.tolist())) - known)
    if unknown:         # the survey does not match the log: a wrong day's, or a line lost
        counts = {k: int(np.sum((id_a == k) | (id_b == k))) for k in unknown}
        raise SurveyError(f"{survey_path}: the log's TDOA samples use anchor(s) "
                          f"{', '.join(f'{k} ({n} samples)' for k, n in counts.items())}, which this survey lacks "
                          f"(it has {sorted(known)}): is it the survey of {Path(log_path).name}'s day?")
    mode = uwb_mode or infer_uwb_mode(id_a, id_b, len(anchors))
    metadata = {
        "source": str(log_path),
        "survey": str(survey_path),
        "uwb_mode": mode,
        "log_version": str(decoded.version),
        "crc": "ok" if decoded.crc_ok else "bad (salvaged)",
        "event_counts": ",".join(f"{k}={v}" for k, v in sorted(decoded.counts().items())),
    }
    if decoded.dropped:
        metadata["salvage"] = "; ".join(decoded.dropped)
    return Recording(
        accel=Vec3Series(t_acc, acc * GRAVITY),
        gyro=Vec3Series(t_gyr, gyr * DEG_TO_RAD),
        tdoa=TdoaSeries(t_tdoa, id_a, id_b, tdoa[:, 2].copy()),
        truth=PoseSeries(t_pose, pose[:, :3].copy(), pose[:, 3:].copy()),
        anchors=anchors,
        metadata=metadata,
    )


def day_survey(log: Path) -> Path:
    """The survey of a flight log's day (`paths.survey_for`), or a SurveyError that says
    where it was looked for."""
    from rig.data.paths import survey_for

    found = survey_for(log)
    if Path(log).is_file() and not found.is_file():
        looked = dict.fromkeys([str(Path(log).resolve().parent.parent / "surveys"), str(found.parent)])
        raise SurveyError(f"{log}: no survey of its day: {found.name} is not in "
                          f"{' nor in '.join(looked)} (name one with --survey FILE)")
    return found


def load_any(path: Path, survey: Path | None = None, strict: bool = False) -> Recording:
    """An MCAP recording, or a flight log imported with `survey` (by default its day's,
    see `paths.survey_for`). An MCAP recording carries its own anchors. `strict`: a
    damaged recording is an error (a damaged log always is, without `--salvage`)."""
    from rig.data import cache

    path = Path(path)
    if path.suffix == ".mcap":
        if survey is not None:
            raise LogFormatError(f"{path}: an MCAP recording carries its own anchors; --survey is for flight logs")
        return cache.read_cached(path, strict)
    # a log is imported once for a given log and survey (the cache's key is both files)
    sources = [path, Path(survey) if survey is not None else day_survey(path)]
    rec = cache.load(*sources)
    if rec is None:
        rec = import_log(*sources)
        cache.store(*sources, rec=rec)
    return rec
