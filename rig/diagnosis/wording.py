"""How a finding reads in words, in report.md and in `rig diagnose`'s output: the
sentence for each effect of the catalog with its parameters, their standard errors,
and how far a fit lies beyond its effect's physical bound."""

from __future__ import annotations

import numpy as np

from rig.diagnosis.findings import Diagnosis, Finding
from rig.sim import effects as fx

PLAIN = {
    "time_offset": "the UWB timestamps are late by {seconds:.3f} s against the IMU and ground-truth clock",
    "clock_drift": "the UWB clock runs fast by {ppm:.0f} ppm against the IMU clock",
    # as if: on real flights an anchor's own bias that changes with the tag's direction
    # from it reads as a displacement too (docs/notebook/diagnosis-experiments.md, session 81)
    "anchor_position": "anchor {anchor}'s ranges read as if it stood {offset_m} m from where the survey puts it",
    "anchor_delay": "every range from anchor {anchor} reads {meters:+.3f} m long (antenna delay; relative to the "
                    "anchors' common delay, which TDOA cannot see)",
    # its coefficients are not its size: how much its ranges differ between directions is (Effect.size)
    "antenna_pattern": "anchor {anchor}'s ranges are biased with the viewing angle (antenna pattern {coeffs_m} m, "
                       "differing by at most {span_m:.3f} m between any two directions)",
    "nlos": "ranges to anchor {anchor} carry an excess delay (NLOS: {fraction:.0%} of them, {mean_excess_m:.3f} m "
            "on average) while the tag is inside {region}",
    "multipath_floor": "below {height_m} m the TDOA noise grows by {std_m:.3f} m{upper} (floor multipath)",
    "on_ground_delay": "with the tag on the floor (below {height_m} m{fade}) the ranges read longer than in flight, "
                       "per anchor: {meters} m (the floor in the direct paths; relative to each other)",
    "imu_accel_bias": "the accelerometer reads {bias_mps2} m/s² too high",
    "imu_gyro_bias": "the gyroscope reads {bias_rps} rad/s too high",
    "imu_accel_scale": "the accelerometer's scale factors are {scale}",
    "imu_vibration_rectification": "the accelerometer reads {gain} × the RMS of its vibration too high (vibration "
                                   "rectification: a bias that follows the rotors' shaking and is gone with the "
                                   "motors off)",
    "imu_gyro_scale": "the gyroscope's scale factors are {scale}",
    "lever_arm": "the UWB antenna sits at {offset_m} m from the body origin (body frame)",
    "link_bias": "every tag–anchor link's range carries the link bias calibrated on the shared flights (the "
                 "antennas' patterns, the airframe, the received power) at {gain:.2f} × its calibrated size",
}


def per_anchor(values: dict[str, float], unit: str = "") -> str:
    """'0: +1.84, 1: -1.22' (metres by anchor id), each with `unit` after it."""
    return ", ".join(f"{k}: {v:+.2f}{unit}" for k, v in values.items())


def _angles(span: list[float]) -> str:
    return f"{span[0]:.0f}…{span[1]:.0f}°"


def _two_figures(value: float) -> str:
    """A standard error to two significant figures, without an exponent (540, not 5.4e+02)."""
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.2g}"


def _std_err_text(finding: Finding) -> str:
    """Its standard errors, as report.json gives them (on TDOA counting the slow error)."""
    if not finding.std_err:
        return ""
    parts = [("of its mean shift " if name == "mean_shift_m" else "")
             + (f"[{', '.join(map(_two_figures, value))}]" if isinstance(value, list) else _two_figures(value))
             for name, value in finding.std_err.items()]
    return f" (standard error {'; '.join(parts)})"


def beyond_bound_by(effect: str, params: dict, std_err: dict | None) -> tuple[float, float, float] | None:
    """(size, bound, standard errors beyond) of a fit, if it lies beyond its effect's
    physical bound; None where it does not or has no standard error of its bounded
    parameter. The size is as the bound measures it (`Effect.size`: a displacement's
    length, a pattern's peak-to-peak range bias, else the largest component), with its
    standard error through `Effect.size_weights`. Beyond by less than two may be the
    flight's slow error."""
    param = next(iter(std_err or {}), None)
    kind = fx.EFFECTS.get(effect)
    bound = kind.bounds.get(param) if kind is not None else None
    if bound is None or param not in params:
        return None
    deviation = np.ravel(np.asarray(params[param], float)) - kind.neutral   # a scale's size is from 1
    size = kind.size(param, deviation)
    if size <= bound:
        return None
    error = float(np.linalg.norm(kind.size_weights(param, deviation) * np.ravel(std_err[param])))
    return size, float(bound), float((size - bound) / max(error, 1e-12))


def _beyond_text(beyond: tuple[float, float, float]) -> str:
    return f"{beyond[0]:.3g} against {beyond[1]:.3g}, {beyond[2]:.1f} standard errors beyond"


def _beyond_by(finding: Finding) -> str:
    beyond = beyond_bound_by(finding.effect, finding.params, finding.std_err)
    return "" if beyond is None else f" ({_beyond_text(beyond)})"


def place(finding: Finding) -> str:
    """Where a fit lies: its anchors, or its channel."""
    return f"anchor {', '.join(map(str, finding.anchors))}" if finding.anchors else f"the {finding.channel} channel"


def not_explained_line(finding: Finding) -> str:
    """A fit left out as beyond its bound in one line: what it was fitted as, where, and
    how far beyond ('anchor_position on anchor 2: 2.18 against 1, 2.6 standard errors
    beyond'), or that it was beyond only in the joint fit; for a per-anchor fit, by how
    much it changes its anchor's ranges (ranges_spread)."""
    spread = ranges_spread(finding)
    return f"{finding.effect} on {place(finding)}: {how_far_beyond(finding)}" + \
        ("" if spread is None else f"; its anchor's ranges vary by {spread:.3f} m over the flight")


def how_far_beyond(finding: Finding) -> str:
    """'2.2 against 1, 3.0 standard errors beyond', or without a standard error of the
    bounded parameter (an NLOS's mean excess) 'mean_excess_m 1.75 (bound 1)'."""
    if finding.beyond_only_jointly:
        return "within its bound as estimated; beyond it only in the joint fit, beside a fit beyond its bound"
    beyond = beyond_bound_by(finding.effect, finding.params, finding.std_err)
    if beyond is not None:
        return _beyond_text(beyond)
    params = {k: v for k, v in finding.params.items() if k in fx.EFFECTS[finding.effect].bounds}
    return "; ".join(f"{k} {np.round(v, 3).tolist()} (bound {fx.EFFECTS[finding.effect].bounds[k]:g})"
                     for k, v in params.items()) or "beyond its bound"


def lean_line(diagnosis: Diagnosis) -> str | None:
    """What an accelerometer scale beyond its bound stands for, when the flight was
    measured for a lean (rig.diagnosis.lean); None otherwise."""
    if diagnosis.lean is None or not any(f.effect == "imu_accel_scale" for f in diagnosis.not_explained):
        return None
    mrad = {name: ", ".join(f"{1e3 * v:+.1f}" for v in values)
            for name, values in (("gyroscope", diagnosis.lean.gyroscope), ("accelerometer", diagnosis.lean.accelerometer))}
    return (f"against the ground truth's attitude the airframe leans into its motion by [{mrad['gyroscope']}] mrad "
            f"per m/s (x, y) by the gyroscope and [{mrad['accelerometer']}] by the accelerometer (`attitude_lean`): "
            "where the two agree, the accelerometer's scale stands for that lean, read as more rotor drag")


def where_not_explained(findings: list[Finding]) -> str:
    """The places of the fits beyond their bounds, each with the effects fitted there
    ('anchor 0 (anchor_position, antenna_pattern); the tdoa channel (lever_arm)')."""
    by_place: dict[str, list[str]] = {}
    for f in findings:
        by_place.setdefault(place(f), []).append(f.effect)
    return "; ".join(f"{where} ({', '.join(dict.fromkeys(effects))})" for where, effects in sorted(by_place.items()))


def ranges_spread(finding: Finding) -> float | None:
    """How much a per-anchor fit changes its anchor's ranges over the flight (m, standard
    deviation over its links; the mean is a delay): the size to check against physics
    whatever the fit's parameters say (a displacement of metres over the narrow cone of
    directions a flight shows changes them by tenths). None where not measured."""
    largest = finding.where.get("largest")
    if not largest or finding.effect == "link_bias":
        return None
    return finding.where["spread_m"][str(largest["anchor"])]


def _largest_text(finding: Finding) -> str:
    """'; it changes anchor 2's ranges by 0.120 m over the flight …, reading longest with
    the tag at …' (where it changes them most), or '' where not measured."""
    largest = finding.where.get("largest")
    if not largest:
        return ""
    k = largest["anchor"]
    spread = finding.where["spread_m"][str(k)]
    size = (f"it varies most on anchor {k}'s links ({spread:.3f} m)" if finding.effect == "link_bias" else
            f"it changes anchor {k}'s ranges by {spread:.3f} m over the flight (standard deviation; their mean is "
            f"a delay)")
    return (f"; {size}, reading {largest['sign']}est with the tag at azimuth {_angles(largest['tag_azimuth_deg'])} "
            f"and elevation {_angles(largest['tag_elevation_deg'])} in the anchor's frame (the anchor at elevation "
            f"{_angles(largest['anchor_elevation_in_body_deg'])} from the tag)")


def describe(finding: Finding) -> str:
    params = {k: (np.round(v, 3).tolist() if isinstance(v, list) else v) for k, v in finding.params.items()}
    if isinstance(params.get("meters"), dict):
        params["meters"] = per_anchor(params["meters"])
    if params.get("fade_m"):
        params["fade"] = f", fading out over the {params['fade_m']} m above"
    params.setdefault("fade", "")          # a step: whole below its height, none above
    if finding.effect == "antenna_pattern":
        params["span_m"] = fx.size_of(finding.effect, "coeffs_m", finding.params["coeffs_m"])
    upper = params.get("upper_height_m")
    params["upper"] = "" if upper is None else f", on top of {params['upper_std_m']:.3f} m below {upper} m"
    if isinstance(params.get("region"), dict):
        box = params["region"]
        params["region"] = ", ".join(f"{axis} {low:.2f}…{high:.2f}" for axis, low, high
                                     in zip("xyz", box["min"], box["max"])) + " m"
    text = PLAIN.get(finding.effect, finding.effect + " {}").format(**params) + _std_err_text(finding)
    text += _largest_text(finding)
    if "during" in finding.params:
        start, end = finding.params["during"]
        elsewhere = finding.params.get("outside_m")
        text += (f", from {start:.1f} s to {end:.1f} s only" if elsewhere is None
                 else f" from {start:.1f} s to {end:.1f} s and {elsewhere:.3f} m elsewhere")
    if finding.beyond_only_jointly:
        text += (" — within what this effect can physically be, but fitted jointly with the other named effects "
                 "it goes beyond it, beside a fit beyond its bound that shares its shape on this flight: the "
                 "re-simulation leaves it out")
    elif finding.beyond_bound:
        text += (" — beyond what this effect can physically be" + _beyond_by(finding) + ": it stands for "
                 "something the catalog does not model, and the re-simulation leaves it out")
    if finding.not_simulated:
        text += (" — not re-simulated: fitted jointly with the other named effects it would go below zero, "
                 "which it cannot physically be, so they share its shape on this flight")
    if finding.alternative_to:
        named = finding.alternative_to["effect"]
        axes = f" on {', '.join(finding.alternative_to['axes'])}" if "axes" in finding.alternative_to else ""
        text += (f" — nearly as good an explanation as the {named}{axes}, in its place: this flight cannot tell "
                 f"the two apart (the re-simulation has the {named})")
    return text
