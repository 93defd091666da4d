"""Writes a diagnosis: DIR/report.json (the findings contract), DIR/model.json (the
fitted effects as a simulator effect list) and DIR/report.md with plots of the
residuals against time, viewing angle and position, before and after."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rig.diagnosis import (
    compare,  # noqa: E402
    imu_spectrum,  # noqa: E402
)
from rig.data.files import write_text_whole  # noqa: E402
from rig.diagnosis.channels import AXES, GROSS_Z, left_out_text  # noqa: E402
from rig.diagnosis.findings import Diagnosis, Finding  # noqa: E402
from rig.diagnosis.imu_spectrum import vibration_spread  # noqa: E402
from rig.diagnosis.floor_error import ON_GROUND_M  # noqa: E402
from rig.diagnosis.identifiability import figures  # noqa: E402
from rig.diagnosis.mismatch import CELL_M  # noqa: E402
from rig.diagnosis.wording import (  # noqa: E402
    describe,
    how_far_beyond,
    lean_line,
    per_anchor,
    place,
    ranges_spread,
    where_not_explained,
)
from rig.sim import effects as fx  # noqa: E402

REPORT_JSON, REPORT_MD, MODEL_JSON = "report.json", "report.md", "model.json"
CONTROL_DIR = "control"          # `rig diagnose --control`: the control recording's own report
SENSORS = {"accel": ("accelerometer", "m/s²"), "gyro": ("gyroscope", "rad/s")}     # the IMU's, in words

UNITS = {"tdoa": "m", "accel": "m/s²", "gyro": "rad/s"}
WHERE_SHOWN = 3                  # "Where they differ": the largest of each kind in report.md


def write(diagnosis: Diagnosis, out: Path, recording: str, against_control: dict | None = None) -> dict:
    """report.json, model.json, report.md and its plots into `out`; with
    `against_control` (compare.diagnose_against), what changed against a control
    recording of the same flight too."""
    out.mkdir(parents=True, exist_ok=True)
    report = diagnosis.to_json()
    report["recording"] = recording
    if against_control is not None:
        report["against_control"] = against_control
    write_text_whole(out / REPORT_JSON, json.dumps(report, indent=2, allow_nan=False, default=_finite))
    write_text_whole(out / MODEL_JSON, json.dumps({"effects": report["model"],
                                                   "vibration_rms_mps2": report["vibration_rms_mps2"]}, indent=2))
    images = _plots(diagnosis, report["model"], report["mismatch"], out)
    write_text_whole(out / REPORT_MD, _markdown(diagnosis, report, images))
    return report


def _finite(value):
    raise TypeError(f"not JSON: {value!r}")


def _markdown(diagnosis: Diagnosis, report: dict, images: list[tuple[str, str]]) -> str:
    lines = [f"# Diagnosis of {report['recording']}", "",
             f"{report['duration_s']:.1f} s of flight. The simulator flew the recording's own ground truth past its "
             "surveyed anchors; every recorded sample was compared with the simulated one.", "",
             "## How far simulation and recording are apart", "",
             "| channel | samples | noise (robust σ) | mismatch before | after modelling the findings |",
             "|---|---|---|---|---|"]
    for name, c in report["channels"].items():
        lines.append(f"| {name} | {c['samples']} | {c['noise_scale']:.4g} {UNITS[name]} | "
                     f"{c['fit_before']:.4g} | {c['fit_after']:.4g} ({_change(c)}) |")
    lines += ["", "Mismatch is a robust RMS of recorded − simulated in the channel's unit (IMU channels as "
              "block means); the *after* column re-simulates the recording with every named effect within its "
              "physical bounds.", ""]
    left_out = left_out_text({name: c["gross_errors_left_out"] for name, c in report["channels"].items()})
    if left_out:
        lines += [f"Left out as corrupt (over {GROSS_Z:g} noise deviations from the channel's median: a garbled "
                  f"range, or a glitch of the ground truth): {left_out}.", ""]
    unusable = left_out_text({name: c["unusable_left_out"] for name, c in report["channels"].items()})
    if unusable:
        unknown = ", ".join(map(str, report["unknown_anchors"]))
        lines += [f"Left out as unusable (not finite{', or from anchors the anchor set lacks: ' + unknown if unknown else ''}"
                  f"): {unusable}.", ""]
    lines += _where_lines(report["mismatch"])
    lines += ["## What physics the simulation left out", ""]
    if not diagnosis.explained:
        lines.append("Nothing: no catalog effect removes enough of the mismatch to pay for its parameters.")
    for k, f in enumerate(diagnosis.explained, 1):
        alike = (" Nearly as good an explanation: " + ", ".join(a["candidate"] for a in f.look_alikes) + "."
                 if f.look_alikes else "")
        unnamed_axes = {f"[{AXES.index(axis)}]" for axis in f.not_named_axes}     # an IMU finding has one parameter
        unclear = [label for label in f.not_identified if label[label.find("["):] not in unnamed_axes]
        vague = (" Not identified by this trajectory (even with independent samples the standard error would "
                 "be most of the prior's; the value is mostly the prior's): " + ", ".join(unclear) + "."
                 if unclear else "")
        if f.not_named_axes:
            vague += (" Not named on " + ", ".join(f.not_named_axes) + " (those axes do not pay for themselves): "
                      "neutral there.")
        lines.append(f"{k}. **{f.effect}**: {describe(f)}. Evidence {f.evidence:.1f}; the affected "
                     f"{f.channel} samples' mismatch goes from {f.fit_before:.4g} to {f.fit_after:.4g}"
                     f"{_unit(f)}.{alike}{vague}")
    lines += ["", "Evidence is the robust loss an effect removes given the others but its richer look-alikes "
              "(about half a chi-square); larger is stronger. Parameters are estimated given the simpler "
              "explanations only, so they compare between recordings of the same flight; report.json gives "
              "each one's standard error (`std_err`). On TDOA the evidence counts the samples as independent, "
              "while most of the error varies slowly, so it overstates how sure a finding is; the standard "
              "errors count the slow error. Look-alikes: an "
              "anchor displacement along the line of sight reads as a delay, and a second-order antenna "
              "pattern over a small range of viewing angles as a displacement; an accelerometer scale on z "
              "reads as a bias in hover, and far from the zero of the recording's clock a drift as a time offset "
              "(then both are reported, each with its value, and the one not simulated is marked "
              "`alternative_to` the other in report.json). Once one anchor's delay is supported, every "
              "anchor's delay is reported (some with little evidence of their own): TDOA measures them relative "
              "to each other.", ""]
    lines += _not_explained_lines(diagnosis)
    lines += _against_control_lines(report.get("against_control"))
    lines += _identifiability_lines(report["identifiability"])
    lines += _noise_lines(report["model"])
    for title, name in images:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def _not_explained_lines(diagnosis: Diagnosis) -> list[str]:
    """Where the residual lies that no effect of the catalog explains within its bounds:
    a short section, one row per fit, the largest evidence first."""
    if not diagnosis.not_explained:
        return []
    jointly = sum(f.beyond_only_jointly for f in diagnosis.not_explained)
    lines = ["## Not explained", "",
             f"{len(diagnosis.not_explained)} fits remove real mismatch but are larger than their effect can "
             "physically be" + (f" ({jointly} of them only when fitted jointly with the other named effects, beside "
                                "one that is)" if jointly else "")
             + ": none is a finding, and the re-simulation leaves them out (report.json's "
             "`not_explained`). They say where the residual lies: "
             f"{where_not_explained(diagnosis.not_explained)}. On real flights it is mostly the part of the UWB's "
             "pose-dependent bias that the link bias every link shares does not carry: each anchor's own, and "
             "each place's. A change to the flight of one of these kinds (an anchor moved, an effect injected) "
             "shows only as a change of its fit: compare with a recording of the flight before it (`--control`).",
             "", "| fitted as | where | fit | beyond its bound: its size (a displacement's length, a pattern's "
             "peak-to-peak range bias, else the largest component), or only jointly | its anchor's ranges vary by | "
             "evidence |",
             "|---|---|---|---|---|---|"]
    for f in diagnosis.not_explained:
        spread = ranges_spread(f)
        lines.append(f"| {f.effect} | {place(f)} | {_params_text(f.params)} | {how_far_beyond(f)} | "
                     f"{'—' if spread is None else f'{spread:.3f} m'} | {f.evidence:.1f} |")
    lean = lean_line(diagnosis)
    return lines + ([] if lean is None else ["", lean[0].upper() + lean[1:] + "."]) + [""]


def _against_control_lines(against: dict | None) -> list[str]:
    """What changed against the control recording, effect by effect."""
    if against is None:
        return []
    lines = ["## Against the control recording", ""]
    if not against.get("same_flight", True):
        lines += [f"⚠ **The control does not look like the same flight**: {against['how_it_differs']}. The "
                  "changes below include what differs between two flights (a flight flown again has pose-"
                  "dependent errors of its own), not only a change made to one.", ""]
    lines += [
              f"Each effect as it changed from the control, {against['recording']} (the same flight as it was): "
              "the recording's parameters less the control's, where both name it; where only the recording does, "
              "less the control's estimate of it below its bar if it has one (the parametric TDOA effects), "
              "else as named; where only the control does, the recording's estimate below its bar less the "
              "control's (a clock effect without one: to neutral, the recording's own cancelled it) "
              "(`against_control` in report.json), and its largest component in the recording's standard "
              "errors (too large a yardstick for effects injected into the control, whose noise the two "
              "share). Those named on one only come first, then the largest changes. An NLOS changes by its "
              "mean shift (fraction × mean excess) over the region found, the recording's estimate there less "
              "the control's, named there or not; the floor's effects are listed as each has them. *Told apart "
              "from*: the size from "
              "which this recording "
              "tells a change of that direction from the effect's look-alikes; a change below it is not the "
              "effect's own signal and may be a look-alike's moving (marked ⚠). Where the lever arm changed, "
              "a delay's change carries its share of it (the lever arm's change times how the delay moves "
              "with it when the two are fitted together, `lever_arm_cross_talk`): a lever arm that took part "
              "of another anchor's pattern moves every delay by that much.", "",
              "| effect | anchors | named on | change | standard errors | told apart from | on this recording "
              "| on the control |",
              "|---|---|---|---|---|---|---|---|"]
    for c in compare.by_size(against["changes"]):
        z = "—" if c["change_std_errs"] is None else f"{c['change_std_errs']:.1f}"
        lines.append(f"| {c['effect']} | {_anchors(c)} | {c['named_in']} | {change_text(c)} | {z} | "
                     f"{_told_apart_text(c)} | {_side_text(c, 'recording')} | {_side_text(c, 'control')} |")
    if not against["changes"]:
        lines.append("| — | — | neither | — | — | — | — | — |")
    return lines + [""]


def change_text(change: dict) -> str:
    """A change's amounts, and a delay's share of the lever arm's change, if any."""
    share = change.get("lever_arm_share_m")
    return _params_text(change["change"]) + ("" if share is None else f" (the lever arm's share {figures(share)})")


def _side_text(change: dict, side: str) -> str:
    """One recording's parameters (`side`: "recording" or "control"), or its estimate
    of an effect it does not name, or of one in the look-alike's place the other
    recording reports it in."""
    unnamed, in_place = change.get(f"{side}_unnamed"), change.get(f"{side}_in_place")
    if in_place is not None:
        return f"{_params_text(in_place)} (estimated in its look-alike's place, as the other reports it)"
    if unnamed is None:
        return _params_text(change[side])
    return f"{_params_text(unnamed)} (estimated, below the bar)"


def _told_apart_text(change: dict) -> str:
    if "size" not in change:
        return "—"
    limit = change["told_apart_from"]
    below = compare.Shown(change["size"], limit).below
    return ("at no size" if limit is None else figures(limit)) + (" ⚠" if below else "")


def _params_text(params: dict | None) -> str:
    """'meters 0.12; offset_m [0.2, 0.2, 0]': the amounts, three significant figures."""
    if params is None:
        return "—"
    return "; ".join(f"{k} {_amount(v)}" for k, v in params.items() if k != "anchor")


def _amount(value) -> str:
    if isinstance(value, float):
        return figures(value)
    if isinstance(value, list):
        return "[" + ", ".join(_amount(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_amount(v)}" for k, v in value.items()) + "}"
    return str(value)


def _identifiability_lines(items: list[dict]) -> list[str]:
    """How large each candidate must be for this flight to show it and to tell it
    from its look-alikes, and, in words, the kinds it cannot tell apart at any size
    they can physically have."""
    if not items:
        return []
    lines = ["## What this flight can tell apart", "",
             "How large each candidate effect must be for this recording to show it at all (against the noise "
             "alone) and to tell it from its look-alikes: the explanations as simple as it or simpler that fit "
             "the same signal (a displacement's is its anchor's delay, a pattern's its delay and displacement; "
             "a time offset and a clock drift, or an IMU bias and scale, are each other's). Sizes are of the "
             "parameter's change from neutral (a scale's from 1): first in the direction the trajectory shows "
             "best, then the size from which it tells every direction apart (`identifiability` in report.json). "
             "They are bounds for one effect alone: outliers and the other effects in the model only raise "
             "them. Of two equally simple look-alikes it cannot tell apart, the diagnosis names the one that "
             "explains more and reports the other in its place (`alternative_to`).", "",
             "| effect | anchor | shows from | told from its look-alikes from | in every direction from | "
             "look-alikes |", "|---|---|---|---|---|---|"]
    for i in items:
        beyond = "" if i["told_apart"] else f" (beyond its {_size(i['bound'], i['unit'])})"
        seen, apart, every = (_size(i[key], i["unit"]) for key in
                              ("smallest_seen", "smallest_told_apart", "told_apart_in_every_direction"))
        lines.append(f"| {i['effect']} (`{i['param']}`) | {_anchors(i)} | {seen} | {apart}{beyond} | {every} | "
                     f"{', '.join(i['look_alikes']) or '—'} |")
    never: dict[str, list[dict]] = {}
    for i in items:
        if not i["told_apart"]:
            never.setdefault(i["effect"], []).append(i)
    if never:
        kinds = "; ".join(_never_told_apart(group) for group in never.values())
        lines += ["", f"This trajectory cannot tell apart from their look-alikes, at any size they can physically "
                      f"have: {kinds}. Such an effect, were it there, is reported as its look-alikes, unless the "
                      "flight shows one of its own of that kind (a comparison with a control recording of the same "
                      "flight then sees what changed)."]
    return lines + [""]


def _never_told_apart(group: list[dict]) -> str:
    """'antenna_pattern on anchors 0, 2 (told apart from 1.8 m on, physically at most 1 m)'."""
    first, on = group[0], ", ".join(_anchors(i) for i in group if i.get("anchors"))
    smallest = min((i["smallest_told_apart"] for i in group if i["smallest_told_apart"] is not None), default=None)
    where = f" on anchor{'s' if len(group) > 1 else ''} {on}" if on else ""
    told = f"told apart from {_size(smallest, first['unit'])} on" if smallest is not None else "never told apart"
    return f"{first['effect']}{where} ({told}, physically at most {_size(first['bound'], first['unit'])})"


def _anchors(item: dict) -> str:
    return ", ".join(str(k) for k in item.get("anchors", [])) or "—"


def _size(value: float | None, unit: str) -> str:
    if value is None:
        return "never"
    return f"{figures(value)} {unit}".rstrip()


def _where_lines(mismatch: dict) -> list[str]:
    """Where the untouched simulation and the recording differ (rig.diagnosis.mismatch): each
    anchor, and of the pairs, regions and viewing angles the clearest few."""
    def clearest(items, entry):
        """By |mean| × √samples of each item's `entry`: a large mean over a handful of
        samples is noise."""
        return sorted(items, key=lambda item: -abs(entry(item)["mean_m"]) * np.sqrt(entry(item)["samples"])
                      )[:WHERE_SHOWN]

    lines = ["## Where they differ", "",
             "Recorded − simulated before any effect is modelled (all of it under `mismatch` in report.json; "
             "pairs and viewing angles the clearest first, by |mean| × √samples):", ""]
    if "tdoa_per_anchor_m" in mismatch:
        anchors = dict(sorted(mismatch["tdoa_per_anchor_m"].items(), key=lambda kv: -abs(kv[1])))
        pairs = clearest(mismatch["tdoa_per_pair_m"].items(), lambda kv: kv[1])
        regions = mismatch["tdoa_per_region"][:WHERE_SHOWN]
        angles = clearest([(k, b) for k, bins in mismatch["tdoa_per_viewing_angle"].items() for b in bins],
                          lambda kb: kb[1])
        lines += [f"- **Anchors**, how long each one's ranges read, largest first: {per_anchor(anchors, ' m')}.",
                  "- **Anchor pairs**, the later anchor's range against the earlier's: "
                  + "; ".join(f"{pair} {c['mean_m']:+.2f} m ({c['samples']} samples)" for pair, c in pairs) + ".",
                  f"- **Regions of space** ({CELL_M:g} m cubes), the largest robust RMS first: " + "; ".join(map(_region_text, regions)) + ".",
                  "- **Viewing angles**, the tag seen from an anchor: "
                  + "; ".join(f"anchor {k} at azimuth {b['azimuth_deg'][0]:g}…{b['azimuth_deg'][1]:g}°, elevation "
                              f"{b['elevation_deg'][0]:g}…{b['elevation_deg'][1]:g}°: {b['mean_m']:+.2f} m "
                              f"({b['samples']} samples)" for k, b in angles) + "."]
    imu = [f"{name} {', '.join(f'{axis} {v:+.3g}' for axis, v in mismatch[f'{name}_per_axis'].items())} {UNITS[name]}"
           for name in ("accel", "gyro") if f"{name}_per_axis" in mismatch]
    if imu:
        lines.append(f"- **IMU axes**: {'; '.join(imu)}.")
    lines += [f"- **Time**: {'; '.join(_worst_block_text(name, mismatch) for name in UNITS if f'{name}_per_time_block' in mismatch)}.",
              ""]
    return lines + _on_ground_lines(mismatch.get("tdoa_on_ground_m", {}))


def _region_text(cell: dict) -> str:
    low, high = cell["region"]["min"], cell["region"]["max"]
    box = ", ".join(f"{axis} {a:g}…{b:g}" for axis, a, b in zip(AXES, low, high))
    worst = (f", anchor {cell['anchor']} reading {cell['anchor_mean_m']:+.2f} m there" if "anchor" in cell else "")
    return f"{box} m: {cell['robust_rms']:.3g} m over {cell['samples']} samples{worst}"


def _worst_block_text(name: str, mismatch: dict) -> str:
    blocks = mismatch[f"{name}_per_time_block"]
    worst = max(blocks, key=lambda b: b["robust_rms"])
    typical = float(np.median([b["robust_rms"] for b in blocks]))
    return (f"{name} worst over {worst['time'][0]:g}–{worst['time'][1]:g} s ({worst['robust_rms']:.3g} "
            f"{UNITS[name]} against a median block's {typical:.3g})")


def _on_ground_lines(on_ground: dict[str, float]) -> list[str]:
    """Where the tag sat on the floor: how each anchor's ranges read there."""
    if not on_ground:
        return []
    readings = per_anchor(on_ground, " m")
    return [f"With the tag on the floor (below {ON_GROUND_M:g} m), each anchor's ranges read, against the same "
            f"anchor's in flight and relative to the other anchors': {readings} (`mismatch.tdoa_on_ground_m` "
            "in report.json, against the untouched simulation, which has no floor in the way of the direct paths; "
            "`on_ground_delay` below models what the named effects leave of it).", ""]


def _noise_lines(model: list[dict]) -> list[str]:
    """What the model's noise is, in words: the TDOA noise per measurement, the
    IMU's peak (the airframe's slow shaking) when its spectrum peaks, and its white
    noise, with the low-pass it went through when the spectrum rolls off."""
    noise = fx.params_by_name(model)
    lines = ["## The noise the model leaves", ""]
    if "tdoa_noise" in noise:
        lines.append(f"- TDOA: {noise['tdoa_noise']['std_m']:.3f} m per measurement (robust σ after the effects).")
    if "imu_resonance" in noise:
        peak = noise["imu_resonance"]
        shaking = [f"at {peak[f'{s}_hz']:.1f} Hz on the {name} ({_per_axis(peak[f'{s}_std'])} {unit})"
                   for s, (name, unit) in SENSORS.items() if peak[f"{s}_hz"] > 0]
        lines.append(f"- IMU: the readings' spectrum peaks {' and '.join(shaking)}: the airframe's slow "
                     "shaking (the attitude loop's wobble, the frame's sway), which the ground truth does not "
                     "resolve and a 100 Hz estimator takes in whole. The model carries it (`imu_resonance`: "
                     "white noise through a peak) besides the white noise.")
    if "imu_noise" in noise:
        imu = noise["imu_noise"]
        white = (f"white noise of {_per_axis(imu['accel_std'])} m/s² and {_per_axis(imu['gyro_std'])} rad/s "
                 "per sample")
        lowpass = noise.get("imu_lowpass")
        if lowpass:
            lines.append(f"- IMU: the readings were low-pass filtered before they were logged (the flight "
                         f"controller's filter): their spectrum rolls off above {lowpass['accel_hz']:.0f} Hz on "
                         f"the accelerometer and {lowpass['gyro_hz']:.0f} Hz on the gyroscope, where white noise "
                         f"would put most of its power above 100 Hz. The model carries the filter "
                         f"(`imu_lowpass`) and the {white} before it, which comes out of it with the recorded "
                         "spread (see the spectrum below).")
        else:
            lines.append(f"- IMU: {white} (the readings' spectrum does not roll off).")
    return lines + [""] if len(lines) > 2 else []


def _unit(f: Finding) -> str:
    """Noise-level effects (floor multipath, NLOS found by its shape) measure their
    fit as a likelihood, not a robust RMS: say so."""
    return f" ({f.where['fit_unit']})" if "fit_unit" in f.where else ""


def _change(c: dict) -> str:
    if not c["fit_before"]:
        return "—"
    return f"{(c['fit_after'] - c['fit_before']) / c['fit_before']:+.1%}"


def _plots(diagnosis: Diagnosis, model: list[dict], mismatch: dict, out: Path) -> list[tuple[str, str]]:
    images = []
    if mismatch.get("tdoa_per_region"):
        images.append(("Where they differ: TDOA mismatch by region of space, before modelling",
                       _regions_plot(mismatch["tdoa_per_region"], out)))
    p = diagnosis.problem
    names = list(diagnosis.residual_before)
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.6 * len(names)), squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        t = p.times(name)
        for label, r in (("before", diagnosis.residual_before[name]), ("after", diagnosis.residual_after[name])):
            ax.plot(*_running_median(t, np.abs(r)), label=f"|residual| {label}")
        ax.set(ylabel=f"{name} [{UNITS[name]}]")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set(xlabel="time [s]")
    fig.suptitle("recorded − simulated against time (running median of the magnitude)")
    images.append(("Residuals against time", _save(fig, out, "residual_time.png")))
    anchor_findings = [f for f in diagnosis.findings if f.channel == "tdoa" and f.anchors]
    if anchor_findings:
        k = anchor_findings[0].anchors[0]
        images.append((f"Anchor {k}: residual against viewing angle", _angle_plot(diagnosis, k, out)))
        images.append((f"Anchor {k}: residual against position", _position_plot(diagnosis, k, out)))
    rectified = [f for f in diagnosis.findings if f.effect == "imu_vibration_rectification"]
    if rectified:
        images.append(("Accelerometer residual against its vibration",
                       _vibration_plot(diagnosis, rectified[0], out)))
    noise = fx.params_by_name(model)
    if "imu_lowpass" in noise:
        images.append(("IMU noise spectrum, recorded and modelled", _spectrum_plot(diagnosis, noise, out)))
    if diagnosis.findings:
        fig, ax = plt.subplots(figsize=(9, 0.4 * len(diagnosis.findings) + 1.2))
        labels = [f"{f.effect} {f.anchors or ''}" for f in diagnosis.findings]
        y = np.arange(len(labels))
        ax.barh(y - 0.2, [f.fit_before for f in diagnosis.findings], 0.4, label="without the effect")
        ax.barh(y + 0.2, [f.fit_after for f in diagnosis.findings], 0.4, label="with it")
        ax.set(yticks=y, yticklabels=labels, xlabel="mismatch of the affected samples (channel unit)")
        ax.invert_yaxis()
        ax.legend(fontsize=8)
        images.append(("Each finding's fit", _save(fig, out, "findings.png")))
    return images


def _signed(diagnosis: Diagnosis, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sign = diagnosis.problem.anchor_sign(k)
    rows = sign != 0
    return rows, sign[rows] * diagnosis.residual_before["tdoa"][rows], sign[rows] * diagnosis.residual_after["tdoa"][rows]


def _angle_plot(diagnosis: Diagnosis, k: int, out: Path) -> str:
    p = diagnosis.problem
    batch = p.predictor.tdoa([])
    _, elevation = fx.viewing_angles(batch, p.predictor.world([]), k)
    rows, before, after = _signed(diagnosis, k)
    el = np.degrees(elevation[p.tdoa_rows][rows])
    fig, ax = plt.subplots(figsize=(8, 3))
    for label, r in (("before", before), ("after", after)):
        ax.plot(*_running_median(el, r), label=label)
    ax.axhline(0, color="k", lw=0.5)
    ax.set(xlabel=f"elevation of the tag seen from anchor {k} [deg]", ylabel="range error [m] (running median)")
    ax.legend(fontsize=8)
    return _save(fig, out, f"anchor{k}_angle.png")


def _vibration_plot(diagnosis: Diagnosis, finding: Finding, out: Path) -> str:
    """Each rectified axis' block residual against the RMS of its vibration: a line
    sloping by the gain before, flat after."""
    level = diagnosis.problem.vibration().reshape(-1, 3)
    before = diagnosis.residual_before["accel"].reshape(-1, 3)
    after = diagnosis.residual_after["accel"].reshape(-1, 3)
    axes_named = finding.where.get("axes") or list(AXES)
    fig, axes = plt.subplots(1, len(axes_named), figsize=(4.5 * len(axes_named), 3.6), squeeze=False,
                             layout="constrained")
    for ax, name in zip(axes[0], axes_named):
        j = AXES.index(name)
        for label, r in (("before", before[:, j]), ("after", after[:, j])):
            ax.scatter(level[:, j], r, s=3, alpha=0.3, label=label)
            ax.plot(*_running_median(level[:, j], r, bins=20), lw=2)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(title=f"{name} (gain {finding.params['gain'][j]:+.2f})", xlabel="vibration RMS [m/s²]",
               ylabel="recorded − simulated [m/s²]")
        ax.legend(fontsize=8, markerscale=3)
    fig.suptitle("accelerometer 0.2 s means against the RMS of the axis' vibration")
    return _save(fig, out, "accel_vibration.png")


def _per_axis(std) -> str:
    """A standard deviation for all axes, or one per axis as "x, y, z"."""
    if isinstance(std, list):
        return "[" + ", ".join(f"{v:.3g}" for v in std) + "] (x, y, z)"
    return f"{std:.3g}"


def _spectrum_plot(diagnosis: Diagnosis, model: dict, out: Path) -> str:
    """Each IMU sensor's recorded noise spectrum (mean over the axes) against the
    model's (its white noise and resonance through its low-pass) and against white
    noise of the recorded spread (what the model was without the filter)."""
    rec = diagnosis.problem.rec
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
    for ax, (sensor, (name, unit)) in zip(axes, SENSORS.items()):
        series = getattr(rec, sensor)
        spec = imu_spectrum.spectrum(series)
        if spec is None:
            continue
        spread = np.sqrt(np.mean(vibration_spread(series) ** 2))      # the power of the axes' mean
        keep = (spec.freq > 0) & (spec.freq <= fx.LOWPASS_MAX_SHARE * spec.rate)   # the filter's zero at Nyquist
        freq = spec.freq[keep]
        white = np.full(len(freq), 2 * spread ** 2 / spec.rate)      # one-sided density of that spread
        recorded = spec.power[:, keep].mean(axis=0)
        ax.loglog(freq, recorded, label="recorded")
        ax.loglog(freq, white, label="white noise of the recorded spread")
        corner, peak = model["imu_lowpass"][f"{sensor}_hz"], model.get("imu_resonance", {}).get(f"{sensor}_hz", 0.0)
        if corner > 0:                       # a sensor the fit found no roll-off on has no model line
            peaked = f"a {peak:.1f} Hz peak and " if peak else ""
            label = f"model: {peaked}white noise through a {corner:.0f} Hz low-pass"
            ax.loglog(freq, imu_spectrum.model_density(freq, spec.rate, model, sensor), label=label)
        ax.set(title=name, xlabel="frequency [Hz]", ylabel=f"power [({unit})²/Hz]",
               ylim=(recorded.min() / 10, max(recorded.max(), white[0]) * 10))
        ax.legend(fontsize=8)
    fig.suptitle("noise spectrum: the readings less their 0.2 s running mean")
    return _save(fig, out, "imu_spectrum.png")


def _position_plot(diagnosis: Diagnosis, k: int, out: Path) -> str:
    rows, before, after = _signed(diagnosis, k)
    xy = diagnosis.problem.tag_positions()[rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    lim = np.percentile(np.abs(before), 90)
    for ax, (label, r) in zip(axes, (("before", before), ("after", after))):
        sc = ax.scatter(xy[:, 0], xy[:, 1], c=r, s=2, cmap="coolwarm", vmin=-lim, vmax=lim)
        ax.set(title=f"anchor {k} range error, {label}", xlabel="x [m]", aspect="equal")
    axes[0].set(ylabel="y [m]")
    fig.colorbar(sc, ax=axes, label="m")
    return _save(fig, out, f"anchor{k}_position.png")


def _regions_plot(cells: list[dict], out: Path) -> str:
    """The cubes of `mismatch.tdoa_per_region` seen from above, one panel per layer of
    height: each coloured by its robust RMS and labelled with the anchor reading
    furthest off there and by how much."""
    layers = sorted({c["region"]["min"][2] for c in cells})
    fig, axes = plt.subplots(1, len(layers), figsize=(4.2 * len(layers) + 1, 4), squeeze=False, layout="constrained")
    norm = matplotlib.colors.Normalize(0.0, max(c["robust_rms"] for c in cells))
    low, high = (np.array([c["region"][end] for c in cells]) for end in ("min", "max"))
    for ax, z in zip(axes[0], layers):
        for c in (c for c in cells if c["region"]["min"][2] == z):
            (x0, y0, _), (x1, y1, _) = c["region"]["min"], c["region"]["max"]
            shade = norm(c["robust_rms"])
            ax.add_patch(matplotlib.patches.Rectangle((x0, y0), x1 - x0, y1 - y0, color=plt.cm.viridis(shade)))
            if "anchor" in c:
                ax.text((x0 + x1) / 2, (y0 + y1) / 2, f"{c['anchor']}: {c['anchor_mean_m']:+.2f}", ha="center",
                        va="center", fontsize=8, color="k" if shade > 0.6 else "w")
        ax.set(title=f"z {z:g}…{z + CELL_M:g} m", xlabel="x [m]", ylabel="y [m]", aspect="equal",
               xlim=(low[:, 0].min(), high[:, 0].max()), ylim=(low[:, 1].min(), high[:, 1].max()))
    fig.colorbar(matplotlib.cm.ScalarMappable(norm, "viridis"), ax=axes[0].tolist(),
                 label="robust RMS of recorded − simulated [m]")
    fig.suptitle("label: the anchor reading furthest off in the cube, and by how much [m]", fontsize=9)
    return _save(fig, out, "mismatch_regions.png")


def _running_median(x: np.ndarray, y: np.ndarray, bins: int = 60) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(x)
    chunks = np.array_split(order, min(bins, max(1, len(order) // 10)))
    return (np.array([x[c].mean() for c in chunks if len(c)]), np.array([np.median(y[c]) for c in chunks if len(c)]))


def _save(fig, out: Path, name: str) -> str:
    fig.savefig(out / name, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return name
