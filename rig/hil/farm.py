"""Many boards at once: one router session here, one `bridge` process per board, every
replay through zenoh in parallel; each job writes OUT/boardK/ (run.mcap, metrics.json,
report.html) and OUT/farm.json sums them up."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

from rig.data.files import write_json
from rig.hil.job import EstimatorChoice, replay_job

if TYPE_CHECKING:
    from rig.estimator.evaluate import StartPose

FARM_FILE = "farm.json"


def farm_jobs(recordings: list[Path], targets: list[str]) -> list[tuple[Path, str]]:
    """Each recording on each target when either list has one entry, else pairwise."""
    if len(recordings) == 1 or len(targets) == 1:
        return [(r, t) for r in recordings for t in targets]
    if len(recordings) != len(targets):
        raise ValueError("give one recording, one target, or as many recordings as targets")
    return list(zip(recordings, targets))


def run_farm(jobs: list[tuple[Path, str]], out: Path, listen: str, estimator: EstimatorChoice = EstimatorChoice(),
             duration: float | None = None, on_replayed: Callable[[dict], None] | None = None,
             start_pose: StartPose | None = None) -> list[dict]:
    """Replay every job at once, each into its own bridge process; one board's failure
    does not take the others down (its result is {"error": ...}). `on_replayed` sees each
    job's metrics as it ends. Each recording is loaded once, whatever number of boards
    replay it. `start_pose`: every board's, in place of the ground truth's (rig.hil.job).
    Writes the reports (in parallel processes) and OUT/farm.json; returns the results."""
    from rig.data.importer import load_any
    from rig.hil.zenoh import open_session

    loaded = {}
    for recording in dict.fromkeys(r for r, _ in jobs):
        try:
            loaded[recording] = load_any(recording)
        except Exception as exc:  # the jobs on it fail alone, saying why
            loaded[recording] = exc

    session = open_session("router", [listen], [])
    bridges = [subprocess.Popen([sys.executable, "-m", "bridge", "--target", target, "--name", f"board{k}",
                                 "--connect", listen], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
               for k, (_, target) in enumerate(jobs)]

    def job(k: int) -> dict:
        recording, target = jobs[k]
        try:
            if isinstance(loaded[recording], Exception):
                raise loaded[recording]
            result = replay_job(recording, f"zenoh:board{k}", out / f"board{k}", estimator, duration=duration,
                                report=False, session=session, board=f"board{k}", loaded=loaded[recording],
                                start_pose=start_pose)
            if on_replayed is not None:
                on_replayed(result)
            if result["run_record_error"]:
                result = {"error": result["run_record_error"]}
        except Exception as exc:  # one board's failure must not take the others down
            result = {"error": str(exc)}
        return {**result, "board": f"board{k}", "recording": str(recording), "target": target,
                "via": f"zenoh:board{k}"}

    try:
        with ThreadPoolExecutor(max_workers=len(jobs)) as pool:
            results = list(pool.map(job, range(len(jobs))))
    finally:
        for proc in bridges:
            proc.terminate()
        for proc in bridges:
            proc.wait(timeout=10)
        session.close()
    write_reports([out / f"board{k}" for k in range(len(results)) if (out / f"board{k}" / "run.mcap").exists()])
    write_json(out / FARM_FILE, {"jobs": results})
    return results


def write_reports(directories: list[Path], workers: int = 2) -> None:
    """Each directory's report.html, in parallel processes (matplotlib draws one figure
    at a time per process)."""
    from concurrent.futures import ProcessPoolExecutor

    from rig.hil.report import write_report

    if len(directories) < 2:
        for directory in directories:
            write_report(directory)
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        list(pool.map(write_report, directories))
