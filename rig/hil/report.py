"""The HTML page of one run: `rig report DIR` (and the end of every replay).

Reads DIR/run.mcap and DIR/metrics.json and writes DIR/report.html, self-contained
(plots embedded as PNG): the trajectory against ground truth, the error over time,
per-anchor innovation statistics (each TDOA as sent against the one predicted from the
board's estimate at that time) and the histogram of window costs against the budget.
"""

from __future__ import annotations

import base64
import html
import io
import json
import logging
from pathlib import Path

import numpy as np

from rig.data.recording import TOPIC_ANCHORS
from rig.estimator.metrics import interpolate
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


def _png(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buffer.getvalue()).decode()


def _plots(messages: dict, stats: list[dict]) -> dict[str, str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est, truth, timing = (messages.get(k, []) for k in (TOPIC_ESTIMATE, TOPIC_TRUTH, TOPIC_TIMING))
    images = {}
    if est:
        t_est, p_est = np.array([r["t"] for r in est]), _xyz(est, "position")
        fig, (ax_xy, ax_t) = plt.subplots(1, 2, figsize=(12, 4.5))
        if truth:
            t_truth, p_truth = np.array([r["t"] for r in truth]), _xyz(truth, "position")
            ax_xy.plot(p_truth[:, 0], p_truth[:, 1], "k-", lw=1, label="ground truth")
            for i, axis in enumerate("xyz"):
                ax_t.plot(t_truth - t_est[0], p_truth[:, i], "k-", lw=0.8)
        ax_xy.plot(p_est[:, 0], p_est[:, 1], "C0-", lw=1, label="estimate")
        ax_xy.set(xlabel="x [m]", ylabel="y [m]", title="trajectory (top view)", aspect="equal")
        ax_xy.legend()
        for i, axis in enumerate("xyz"):
            ax_t.plot(t_est - t_est[0], p_est[:, i], f"C{i}-", lw=1, label=f"{axis} estimate")
        ax_t.set(xlabel="time [s]", ylabel="position [m]", title="position (black: ground truth)")
        ax_t.legend(fontsize=8)
        images["trajectory"] = _png(fig)
        plt.close(fig)
        if truth:
            err = np.linalg.norm(p_est - interpolate(t_est, t_truth, p_truth), axis=1)
            fig, ax = plt.subplots(figsize=(12, 3))
            ax.plot(t_est - t_est[0], err, lw=0.8)
            ax.set(xlabel="time [s]", ylabel="3D error [m]", title="position error over time")
            images["error"] = _png(fig)
            plt.close(fig)
    if stats:
        fig, ax = plt.subplots(figsize=(8, 3))
        ids = [s["anchor"] for s in stats]
        ax.bar(ids, [s["median"] for s in stats], yerr=[s["mad"] for s in stats], capsize=3)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel="anchor", ylabel="innovation [m]", title="per-anchor TDOA innovation: median ± MAD",
               xticks=ids)
        images["innovation"] = _png(fig)
        plt.close(fig)
    if timing:
        window = np.array([r["window"] for r in timing], float)
        budget, unit = timing[0]["budget"], timing[0]["unit"]
        fig, ax = plt.subplots(figsize=(8, 3))
        ax.hist(window / budget * 100, bins=60)
        ax.axvline(100, color="r", label="budget (10 ms)")
        ax.axvline(20, color="orange", ls="--", label="20 % target")
        ax.set(xlabel=f"window cost [% of the budget; {unit}]", ylabel="windows", title="window cost", yscale="log")
        ax.legend()
        images["timing"] = _png(fig)
        plt.close(fig)
    latency = [(r["t"], r["latency_ms"]) for r in timing if r.get("latency_ms") is not None]
    if latency:
        t, ms = np.array(latency).T
        fig, ax = plt.subplots(figsize=(8, 3))
        ax.plot(t - t[0], ms, ".", ms=2)
        ax.set(xlabel="time [s]", ylabel="latency [ms]", title="real time: input-to-estimate latency", yscale="log")
        images["latency"] = _png(fig)
        plt.close(fig)
    return images


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
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    stats = innovation_stats(messages)
    images = _plots(messages, stats)
    timing = metrics.get("timing", {})
    summary = [
        {"figure": "recording", "value": metrics.get("recording")},
        {"figure": "target", "value": metrics.get("target")},
        {"figure": "estimates", "value": metrics.get("n_estimates")},
        {"figure": "RMSE 3D [m]", "value": metrics.get("rmse_3d")},
        {"figure": "RMSE x, y, z [m]", "value": metrics.get("rmse_xyz")},
        {"figure": f"worst window [{timing.get('unit')}]", "value": timing.get("window_max")},
        {"figure": "worst window / budget", "value": timing.get("window_max_fraction_of_budget")},
        {"figure": "overruns", "value": timing.get("overruns")},
        {"figure": "replay speed [x real time]", "value": metrics.get("speed")},
        {"figure": "mode", "value": metrics.get("mode")},
        *([{"figure": f"real time: {k}", "value": v} for k, v in metrics["realtime"].items()]
          if metrics.get("realtime") else []),
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
            parts.append(f"<h2>{title}</h2><img src='data:image/png;base64,{images[key]}'>")
        if key == "innovation" and stats:
            parts.append(_table(stats, ["anchor", "n", "mean", "median", "std", "mad"]))
    out = directory / REPORT_FILE
    out.write_text("\n".join(parts))
    return out
