"""The HTML page of one run: `rig report DIR` (and the end of every replay).

Reads DIR/run.mcap and DIR/metrics.json and writes DIR/report.html, self-contained
(charts inline as SVG): the trajectory against ground truth, the error over time,
per-anchor innovation statistics (each TDOA as sent against the one predicted from the
board's estimate at that time) and the histogram of window costs against the budget.
"""

from __future__ import annotations

import html
import logging
from pathlib import Path

import numpy as np

from rig.data.errors import read_json
from rig.data.files import write_text_whole
from rig.data.recording import TOPIC_ANCHORS
from rig.estimator.metrics import interpolate
from rig.hil.svgplot import COLORS, Chart, Series, histogram, render
from rig.hil.runrecord import RUN_FILE, TOPIC_ESTIMATE, TOPIC_TDOA, TOPIC_TIMING, TOPIC_TRUTH, read_run

log = logging.getLogger(__name__)

REPORT_FILE = "report.html"


def _xyz(rows: list[dict], key: str) -> np.ndarray:
    return np.array([[r[key]["x"], r[key]["y"], r[key]["z"]] for r in rows], float).reshape(-1, 3)


def innovation_stats(messages: dict) -> list[dict]:
    """Per anchor: TDOA measured minus predicted from the estimate, signed so that a
    positive mean means the anchor's ranges read long (as an anchor delay would)."""
    est, tdoa = messages.get(TOPIC_ESTIMATE, []), messages.get(TOPIC_TDOA, [])
    anchors = messages.get(TOPIC_ANCHORS, [{}])[-1].get("anchors", [])
    if not est or not tdoa or not anchors:
        return []
    where = {a["id"]: np.array([a["position"][c] for c in "xyz"]) for a in anchors}
    t_est = np.array([r["t"] for r in est])
    rows = [r for r in tdoa if r["distance_diff"] is not None and r["id_a"] in where and r["id_b"] in where
            and t_est[0] <= r["t"] <= t_est[-1]]
    if not rows:
        return []
    p = interpolate(np.array([r["t"] for r in rows]), t_est, _xyz(est, "position"))
    a = np.array([where[r["id_a"]] for r in rows])
    b = np.array([where[r["id_b"]] for r in rows])
    predicted = np.linalg.norm(p - b, axis=1) - np.linalg.norm(p - a, axis=1)
    innovation = np.array([r["distance_diff"] for r in rows]) - predicted
    ids_a, ids_b = np.array([r["id_a"] for r in rows]), np.array([r["id_b"] for r in rows])
    stats = []
    for k in sorted(where):
        signed = np.concatenate([innovation[ids_b == k], -innovation[ids_a == k]])
        if len(signed):
            stats.append({"anchor": int(k), "n": int(len(signed)), "mean": float(np.mean(signed)),
                          "median": float(np.median(signed)), "std": float(np.std(signed)),
                          "mad": float(np.median(np.abs(signed - np.median(signed))))})
    return stats


def _plots(messages: dict, stats: list[dict]) -> dict[str, str]:
    """The report's charts, as inline SVG (rig.hil.svgplot)."""
    est, truth, timing = (messages.get(k, []) for k in (TOPIC_ESTIMATE, TOPIC_TRUTH, TOPIC_TIMING))
    charts: dict[str, list[Chart]] = {}
    if est:
        t_est, p_est = np.array([r["t"] for r in est]), _xyz(est, "position")
        top = Chart("trajectory (top view)", "x [m]", "y [m]", equal_aspect=True, width=430, height=400)
        over_time = Chart("position (black: ground truth)", "time [s]", "position [m]", width=640, height=400)
        if truth:
            t_truth, p_truth = np.array([r["t"] for r in truth]), _xyz(truth, "position")
            top.series.append(Series(p_truth[:, 0], p_truth[:, 1], "ground truth", "#000", width=1.0))
            over_time.series += [Series(t_truth - t_est[0], p_truth[:, i], "", "#000", width=0.8) for i in range(3)]
        top.series.append(Series(p_est[:, 0], p_est[:, 1], "estimate", COLORS[0]))
        over_time.series += [Series(t_est - t_est[0], p_est[:, i], f"{axis} estimate", COLORS[i])
                             for i, axis in enumerate("xyz")]
        charts["trajectory"] = [top, over_time]
        if truth:
            err = np.linalg.norm(p_est - interpolate(t_est, t_truth, p_truth), axis=1)
            charts["error"] = [Chart("position error over time", "time [s]", "3D error [m]", width=1080, height=260,
                                     series=[Series(t_est - t_est[0], err, width=0.8)])]
    if stats:
        ids = np.array([s["anchor"] for s in stats], float)
        charts["innovation"] = [Chart(
            "per-anchor TDOA innovation: median ± MAD", "anchor", "innovation [m]", hlines=[(0.0, "#000")],
            xticks=ids.tolist(), series=[Series(ids, np.array([s["median"] for s in stats]), kind="bars",
                                                yerr=np.array([s["mad"] for s in stats]))])]
    if timing:
        window = np.array([r["window"] for r in timing], float)
        budget, unit = timing[0]["budget"], timing[0]["unit"]
        charts["timing"] = [Chart(
            "window cost", f"window cost [% of the budget; {unit}]", "windows", log_y=True,
            series=[histogram(window / budget * 100)],
            vlines=[(100.0, "#d62728", "budget (10 ms)"), (20.0, "#ff7f0e", "20 % target")])]
    latency = [(r["t"], r["latency_ms"]) for r in timing if r.get("latency_ms") is not None]
    if latency:
        t, ms = np.array(latency).T
        charts["latency"] = [Chart("real time: input-to-estimate latency", "time [s]", "latency [ms]", log_y=True,
                                   series=[Series(t - t[0], ms, kind="dots")])]
    return {key: "".join(render(c) for c in group) for key, group in charts.items()}


def _table(rows: list[dict], columns: list[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(c))}</td>" for c in columns) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


def write_report(directory: Path, messages: dict[str, list[dict]] | None = None) -> Path:
    """Write DIR/report.html from DIR/run.mcap (or its `messages` by topic, as the replay
    that wrote it still holds them) and DIR/metrics.json; returns its path."""
    directory = Path(directory)
    if messages is None:
        messages = read_run(directory / RUN_FILE)
    metrics_path = directory / "metrics.json"
    metrics = read_json(metrics_path) if metrics_path.exists() else {}
    stats = innovation_stats(messages)
    images = _plots(messages, stats)
    timing = metrics.get("timing", {})
    summary = [
        {"figure": "recording", "value": metrics.get("recording")},
        {"figure": "target", "value": metrics.get("target")},
        {"figure": "estimates", "value": metrics.get("n_estimates")},
        *([{"figure": "RMSE 3D [m]", "value": metrics.get("rmse_3d")},
           {"figure": "RMSE x, y, z [m]", "value": metrics.get("rmse_xyz")}] if "score_error" not in metrics else
          [{"figure": "not scored", "value": metrics["score_error"]}]),
        *([{"figure": "start pose given (position [m], yaw [deg])",
            "value": f"{metrics['start_pose']['position']}, {metrics['start_pose']['yaw_deg']:g}"}]
          if metrics.get("start_pose") else []),
        *([{"figure": "share of the bias correction applied at the end (correction trust)",
            "value": f"{metrics['correction_trust']:.0%}"}] if metrics.get("correction_trust") is not None else []),
        *([{"figure": "bias corrections outside where the model was trained (extrapolated)",
            "value": f"{metrics['outside_trained_region']:.1%}"}] if metrics.get("outside_trained_region") is not None
          else []),
        {"figure": f"worst window [{timing.get('unit')}]", "value": timing.get("window_max")},
        {"figure": "worst window / budget", "value": timing.get("window_max_fraction_of_budget")},
        {"figure": "overruns", "value": timing.get("overruns")},
        {"figure": "replay speed [x real time]", "value": metrics.get("speed")},
        {"figure": "mode", "value": metrics.get("mode")},
        *([{"figure": f"real time: {k}", "value": v} for k, v in metrics["realtime"].items()]
          if metrics.get("realtime") else []),
        *([{"figure": f"board link: {k.replace('_', ' ')}", "value": v} for k, v in metrics["board_link"].items()]
          if metrics.get("board_link") else []),
        {"figure": "error", "value": metrics.get("error")},
    ]
    parts = ["<!doctype html><meta charset='utf-8'><title>uwb-rig run report</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px}</style>",
             f"<h1>Run report: {html.escape(str(metrics.get('recording', directory)))}</h1>",
             _table(summary, ["figure", "value"])]
    titles = {"trajectory": "Trajectory against ground truth", "error": "Error over time",
              "innovation": "Per-anchor innovation", "timing": "Window cost against the budget",
              "latency": "Input-to-estimate latency (real-time mode)"}
    for key, title in titles.items():
        if key in images:
            parts.append(f"<h2>{title}</h2>{images[key]}")
        if key == "innovation" and stats:
            parts.append(_table(stats, ["anchor", "n", "mean", "median", "std", "mad"]))
    out = directory / REPORT_FILE
    write_text_whole(out, "\n".join(parts))
    return out
