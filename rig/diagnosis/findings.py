"""The diagnosis as reported: each effect a recording supports (`Finding`), each it
does not name but estimates (`Unnamed`), and the whole (`Diagnosis`), with the noise
the fitted model leaves: report.json's contract, which `rig diagnose`, the comparison
against a control (rig.diagnosis.compare) and the report (rig.diagnosis.report) share.
Fits nothing: rig.diagnosis.diagnose makes them."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from rig.diagnosis import identifiability as ident
from rig.diagnosis import imu_spectrum
from rig.diagnosis.channels import Problem
from rig.diagnosis.lean import Lean
from rig.diagnosis.robust import mad_scale, robust_rms
from rig.sim import effects as fx


@dataclass
class Finding:
    """One effect the recording supports, as reported (report.json's contract)."""

    effect: str
    channel: str
    anchors: list[int]
    params: dict
    evidence: float
    fit_before: float
    fit_after: float
    where: dict
    look_alikes: list = field(default_factory=list)
    beyond_bound: bool = False      # larger than the effect can physically be: stands for something else, not simulated
    std_err: dict | None = None     # standard errors of the fitted parameter (None: not a fitted term)
    not_identified: list = field(default_factory=list)   # its components this trajectory does not identify
    alternative_to: dict | None = None   # {"effect", "axes"}: in place of those axes of that finding, as good
    not_named_axes: list = field(default_factory=list)   # a gyroscope scale's axes that did not pay: neutral there
    not_simulated: bool = False     # within bound, but left out of the model for its sign (terms.model_terms)
    std_err_independent: dict | None = None   # std_err with the samples counted as independent

    @property
    def beyond_only_jointly(self) -> bool:
        """Left out as beyond its bound although its own estimate is within it: fitted
        jointly with the other named effects, beside one beyond its bound that shares
        its shape (a delay beside its anchor's pattern), it went beyond its bound there
        (rig.diagnosis.terms.model_terms)."""
        return self.beyond_bound and not fx.make_effect(self.effect, self.params).beyond_bound()

    def to_json(self) -> dict:
        out = {"effect": self.effect, "channel": self.channel, "params": self.params, "evidence": self.evidence,
               "fit_before": self.fit_before, "fit_after": self.fit_after, "where": self.where}
        if self.std_err is not None:
            out["std_err"], out["not_identified"] = self.std_err, self.not_identified
        if self.std_err_independent is not None:
            out["std_err_independent"] = self.std_err_independent
        if self.anchors:
            out["anchors"] = self.anchors
        if self.look_alikes:
            out["look_alikes"] = self.look_alikes
        if self.beyond_bound:
            out["beyond_physical_bound"] = True
            if self.beyond_only_jointly:
                out["beyond_only_jointly"] = True
        if self.alternative_to:
            out["alternative_to"] = self.alternative_to
        if self.not_named_axes:
            out["not_named_axes"] = self.not_named_axes
        if self.not_simulated:
            out["not_simulated"] = True
        return out


@dataclass
class Diagnosis:
    problem: Problem
    findings: list[Finding]
    model: list[fx.Effect]
    residual_before: dict[str, np.ndarray]
    residual_after: dict[str, np.ndarray]
    identifiability: list[ident.Identifiability] = field(default_factory=list)
    cross_talk: dict[int, list[float]] = field(default_factory=dict)     # lever_arm_cross_talk
    unnamed: list[Unnamed] = field(default_factory=list)                # unnamed_estimates
    in_place: list[Unnamed] = field(default_factory=list)               # in_place_estimates
    # the TDOA's standardised residual less the named effects other than NLOS, as
    # fitted: where an NLOS of this recording or another of the flight is estimated
    tdoa_left: np.ndarray | None = None
    mismatch: dict = field(default_factory=dict)       # where recording and simulation differ (mismatch.locate)
    lean: Lean | None = None                           # the airframe's lean by each IMU sensor (lean.measure_lean)

    @property
    def explained(self) -> list[Finding]:
        """The findings within their effect's physical bounds: what the report names."""
        return [f for f in self.findings if not f.beyond_bound]

    @property
    def not_explained(self) -> list[Finding]:
        """Fits larger than their effect can physically be: they stand for something the
        catalog does not model (on real flights, the pose-dependent bias of the
        antennas and the airframe) and say where the residual lies, not what it is."""
        return [f for f in self.findings if f.beyond_bound]

    def channel_fits(self) -> dict:
        return {name: {"samples": int(len(r)), "gross_errors_left_out": self.problem.left_out[name],
                       "unusable_left_out": self.problem.unusable[name],
                       "noise_scale": float(self.problem.scales[name][0]),
                       "fit_before": robust_rms(r, self.problem.scales[name]),
                       "fit_after": robust_rms(self.residual_after[name], self.problem.scales[name])}
                for name, r in self.residual_before.items()}

    def to_json(self) -> dict:
        rec = self.problem.rec
        return {"recording": rec.metadata.get("source", ""), "duration_s": float(rec.truth.t[-1] - rec.truth.t[0]),
                "findings": [f.to_json() for f in self.explained],
                "not_explained": [f.to_json() for f in self.not_explained], "channels": self.channel_fits(),
                "unknown_anchors": self.problem.unknown_anchors,
                "mismatch": self.mismatch,
                "model": [e.to_json() for e in self.model] + self.noise_model,
                "vibration_rms_mps2": self.vibration_rms(),
                "identifiability": [i.to_json() for i in self.identifiability],
                "lever_arm_cross_talk": [{"anchor": k, "delay_m_per_m": rounded_floats(v)}
                                         for k, v in self.cross_talk.items()],
                "unnamed_estimates": [u.to_json() for u in self.unnamed],
                "in_place_estimates": [u.to_json() for u in self.in_place],
                "lean_against_truth": None if self.lean is None else self.lean.to_json()}

    def vibration_rms(self) -> list[float] | None:
        """The accelerometer's mean vibration RMS per axis over the compared rows: what
        a rectification's gain multiplies on this flight (None without accelerometer)."""
        if not len(self.problem.imu_rows["accel"]):
            return None
        return self.problem.vibration().reshape(-1, 3).mean(axis=0).tolist()

    @cached_property
    def noise_model(self) -> list[dict]:
        """The noise the fitted model leaves, per sample, so `model` simulates data like
        the recording: the TDOA residual after the effects; for the IMU, the raw
        samples' spread around their own running mean (imu_spectrum.SLOW_S) per axis:
        the vibration and sensor noise. Not the spread around the ground truth, whose
        attitude noise, differentiated, is 10–50 times the gyroscope's own noise. When
        the readings were low-pass filtered before logging (their spectrum rolls off),
        the model has the filter (`imu_lowpass`) and the noise before it that comes out
        of it with that spread; when their spectrum peaks (the airframe's slow shaking),
        part of that noise goes through the peak (`imu_resonance`)."""
        out = []
        if "tdoa" in self.residual_after:
            out.append({"effect": "tdoa_noise", "params": {"std_m": mad_scale(self.residual_after["tdoa"])}})
        rec = self.problem.rec
        if not (len(rec.accel) and len(rec.gyro)):
            return out
        sensors = {"accel": rec.accel, "gyro": rec.gyro}
        fits = {name: imu_spectrum.fit_noise(series) for name, series in sensors.items()}
        corners = {name: corner for name, (corner, _) in fits.items()}
        peaks = {name: peak for name, (_, peak) in fits.items()}
        sizes = {name: imu_spectrum.imu_noise_sizes(series, corners[name], peaks[name]) for name, series in sensors.items()}
        out.append({"effect": "imu_noise", "params": {f"{name}_std": white.tolist()
                                                      for name, (white, _) in sizes.items()}})
        if any(peaks.values()):
            params = {}
            for name, (_, resonant) in sizes.items():
                peak = peaks[name]
                params |= {f"{name}_std": resonant.tolist(), f"{name}_hz": peak.hz if peak else 0.0,
                           f"{name}_q": peak.q if peak else 1.0}
            out.append({"effect": "imu_resonance", "params": params})
        if any(corners.values()):
            out.append({"effect": "imu_lowpass", "params": {"accel_hz": corners["accel"], "gyro_hz": corners["gyro"]}})
        return out


@dataclass
class Unnamed:
    """An effect measured as the recording does not report it: a TDOA effect it does
    not name, as a named one would be (report.json's `unnamed_estimates`), or a
    look-alike in a named effect's place (`in_place_of` that effect and its axes;
    `in_place_estimates`)."""

    effect: str
    anchors: list[int]
    params: dict
    std_err: dict
    std_err_independent: dict | None = None   # std_err with the samples counted as independent
    in_place_of: dict | None = None

    def to_json(self) -> dict:
        out = {"effect": self.effect, "params": self.params, "std_err": self.std_err}
        if self.std_err_independent is not None:
            out["std_err_independent"] = self.std_err_independent
        return out | ({"anchors": self.anchors} if self.anchors else {}) | (
            {"in_place_of": self.in_place_of} if self.in_place_of else {})


def rounded_floats(value, digits: int = 6):
    """`value` with every float inside (lists and dicts included) rounded: parameters as
    reported (the fit is not more precise than that)."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, list):
        return [rounded_floats(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: rounded_floats(v, digits) for k, v in value.items()}
    return value
