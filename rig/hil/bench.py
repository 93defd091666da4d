"""Per-call and per-window cost on the board targets, compared with a committed baseline.

`rig bench` replays a fixed segment of a recording in strict lock-step into the native
program (nanoseconds) and the QEMU firmware (instructions, deterministic under
-icount), collects the figures of `replay.timing_summary` and compares each with
benchmarks/baseline.json (paths.BENCH_BASELINE): a figure that grew by more than its unit's threshold is a
regression. Instruction counts repeat exactly, so their threshold is tight;
nanoseconds depend on the machine and its load, so theirs is loose.
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

from rig.data.errors import read_json
from rig.data.recording import Recording
from rig.estimator.evaluate import estimator_config
from rig.hil import replay, targets
from rig.hil.links import Link, LinkError

log = logging.getLogger(__name__)

TARGETS = ("native", "qemu")          # what the bench measures
THRESHOLDS = {"instructions": 0.05, "cycles": 0.05, "ns": 0.50}
# Wall-clock extremes are one preemption away from anything: printed, never compared.
UNCOMPARED = {"ns": {"window_p99", "window_max", "tdoa_update_max"}}


@dataclass
class Figures:
    target: str
    unit: str
    values: dict[str, float]


def figures(summary: dict) -> dict[str, float]:
    """The compared figures of one run's timing summary."""
    calls = summary["per_call"]
    return {"window_p50": summary["window_p50"], "window_p99": summary["window_p99"],
            "window_max": summary["window_max"], "predict_p50": calls["predict"]["p50"],
            "tdoa_update_mean": calls["tdoa_update"]["mean"], "tdoa_update_max": calls["tdoa_update"]["max"]}


def open_link(target: str, binary: Path | None) -> Link:
    if target == "native":
        return targets.open_native(binary)
    if target == "qemu":
        return targets.open_qemu(binary)
    raise LinkError(f"rig bench measures {' and '.join(TARGETS)}, not {target!r}")


def measure(target: str, rec: Recording, start: float | None, duration: float,
            binary: Path | None = None) -> Figures:
    params, model = estimator_config(robust=True, use_nn=True)
    link = open_link(target, binary)
    try:
        session = replay.run(link, rec, params, model, start=start, duration=duration)
    finally:
        link.close()
    summary = replay.timing_summary(session)
    return Figures(target, summary["unit"], figures(summary))


def compare(current: list[Figures], baseline: dict, thresholds: dict[str, float] = THRESHOLDS) -> list[dict]:
    """One row per figure: baseline, current, ratio and whether it regressed."""
    rows = []
    for f in current:
        base = baseline.get("targets", {}).get(f.target)
        if base is None or base["unit"] != f.unit:
            log.warning("no %s baseline in %s units: %s is not compared", f.unit, f.target, f.target)
            continue
        limit = thresholds.get(f.unit, 0.05)
        for name, value in f.values.items():
            ref = base["values"].get(name)
            ratio = value / ref if ref else float("nan")
            compared = bool(ref) and name not in UNCOMPARED.get(f.unit, ())
            rows.append({"target": f.target, "figure": name, "unit": f.unit, "baseline": ref, "current": value,
                         "ratio": ratio, "threshold": limit, "compared": compared,
                         "regressed": compared and ratio > 1.0 + limit})
    return rows


def baseline_document(current: list[Figures], recording: Path, start: float | None, duration: float) -> dict:
    """The figures, and what they were measured on: the recording by its bytes (a path
    relative to the working directory when it lies under it, so the committed
    baseline names no machine's checkout) and the segment."""
    return {"recording": _shown(recording), "recording_sha256": recording_digest(recording),
            "start": start, "duration": duration,
            "targets": {f.target: {"unit": f.unit, "values": f.values} for f in current}}


def recording_digest(recording: Path) -> str | None:
    """The recording's bytes, as a baseline identifies them (None: not a file)."""
    return hashlib.sha256(recording.read_bytes()).hexdigest() if recording.is_file() else None


def check_same_recording(baseline: dict, recording: Path) -> None:
    """Figures compare only on the recording the baseline was measured on: another one
    (or the same file regenerated) is refused, naming both."""
    measured_on = baseline.get("recording_sha256")
    if measured_on is not None and measured_on != recording_digest(recording):
        raise ValueError(f"the baseline was measured on {baseline.get('recording')}, and {recording} is not that "
                         f"recording (its bytes differ): replay the baseline's recording, or measure a new baseline "
                         f"with --update-baseline")


def _shown(path: Path) -> str:
    relative = os.path.relpath(path.resolve(), Path.cwd())
    return str(path) if relative.startswith("..") else relative


def load_baseline(path: Path) -> dict:
    try:
        return read_json(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"no baseline at {path}: run `rig bench --update-baseline` first") from None


def run_settings(baseline: dict) -> tuple[float | None, float]:
    """The segment the baseline was measured on (comparisons must replay the same one)."""
    return baseline.get("start"), float(baseline.get("duration", 20.0))

