"""What a recording adds to a control recording of the same flight (`rig diagnose
REC --control CONTROL`): real flights carry effects of their own, so a change made
to the flight (an anchor moved, a firmware's timestamping changed, an effect
injected) shows as the difference of the two diagnoses, effect by effect.

The two are comparable because each finding is estimated given the simpler
explanations only (rig.diagnose, method step 4): what an effect added to a recording
changes in them is mostly that effect. For an effect named on both, the change is
the recording's parameters less the control's (a scale's ratio less one added to
one); a delay confined to a window on one and not on the other is compared outside
the window. The noise-level effects (NLOS, the floor's multipath and error) are not
differences of parameters; they are listed as each recording has them. A clock
effect named on the control only was cancelled by the recording's (its own plus an
opposite one adds up to about none): its change is from the control's value to
neutral."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.diagnose import rounded_floats
from rig.fitted_model import outside_window

NOT_ADDITIVE = {"nlos", "multipath_floor", "on_ground_delay"}    # listed as they are, not as a difference
CANCELLABLE = {"time_offset", "clock_drift"}                      # a clock's: the recording's may cancel the control's


@dataclass
class Change:
    """One effect of the catalog, as it differs between a recording and its control."""

    effect: str
    anchors: list[int]
    named_in: str                    # "both", "recording" or "control"
    change: dict | None              # the recording's parameters less the control's; None where not a difference
    recording: dict | None           # the finding on the recording (report.json's), if named there
    control: dict | None             # on the control, if named there

    @property
    def std_errs(self) -> float | None:
        """The change in the recording's standard errors, its largest component's (None
        where either is missing). Conservative for a recording that shares its noise
        with the control (effects injected into it), whose difference is less noisy."""
        errors = (self.recording or {}).get("std_err") or {}
        ratios = [np.abs(np.asarray(self.change[field], float) - neutral(self.effect))
                  / np.maximum(np.asarray(error, float), 1e-12)
                  for field, error in errors.items() if self.change and field in self.change]
        return float(max(np.max(r) for r in ratios)) if ratios else None

    def to_json(self) -> dict:
        z = self.std_errs
        out = {"effect": self.effect, "named_in": self.named_in, "change": rounded_floats(self.change),
               "change_std_errs": None if z is None else round(z, 2),
               "recording": _params(self.recording), "control": _params(self.control)}
        if self.anchors:
            out["anchors"] = self.anchors
        return out


def _params(finding: dict | None) -> dict | None:
    return None if finding is None else finding["params"]


def key(finding: dict) -> tuple[str, tuple[int, ...]]:
    """A finding's effect and anchors: what identifies it between two recordings."""
    return finding["effect"], tuple(finding.get("anchors", []))


def neutral(effect: str) -> float:
    """The parameter value that means no effect: a scale's is one."""
    return 1.0 if "scale" in effect else 0.0


def added(effect: str, found: dict, own: dict) -> dict:
    """`found`'s parameters less `own`'s, the control's (plus neutral: a scale's
    change stays a scale); fields that are not amounts (an anchor id, a window, a
    region) stay as found. A window on one only: both compared outside it."""
    got = dict(found)
    if ("during" in got) != ("during" in own):
        got, own = outside_window(got), outside_window(own)
    for field, value in own.items():
        if field in ("anchor", "during") or field not in got:
            continue
        if isinstance(value, (int, float)):
            got[field] = got[field] - value + neutral(effect)
        elif isinstance(value, list):
            got[field] = [a - b + neutral(effect) for a, b in zip(got[field], value)]
    return got


def cancelled(effect: str, own: dict) -> dict:
    """The change of a clock effect named on the control only: from its value to neutral."""
    return {field: (neutral(effect) - value if isinstance(value, (int, float)) else value)
            for field, value in own.items()}


def change(effect: str, anchors: list[int], found: dict | None, control: dict | None) -> Change:
    """The effect's change from `control` (its finding there, or None) to `found`."""
    named_in = "both" if found and control else "recording" if found else "control"
    if effect in NOT_ADDITIVE:
        difference = None
    elif named_in == "both":
        difference = added(effect, found["params"], control["params"])
    elif named_in == "recording":
        difference = dict(found["params"])
    else:
        difference = cancelled(effect, control["params"]) if effect in CANCELLABLE else None
    return Change(effect, anchors, named_in, difference, found, control)


def changes(findings: list[dict], control: list[dict]) -> list[Change]:
    """Every effect reported on either recording, as it changed; the recording's
    findings first, by their evidence, then those on the control only. One reported
    in a look-alike's place (`alternative_to`) counts too: it carries that
    explanation's value, which a change of the flight moves as well."""
    named = {key(f): f for f in findings}
    own = {key(f): f for f in control}
    order = sorted(named, key=lambda k: -named[k]["evidence"]) + [k for k in own if k not in named]
    return [change(effect, list(anchors), named.get((effect, anchors)), own.get((effect, anchors)))
            for effect, anchors in order]


def by_size(listed: list[dict]) -> list[dict]:
    """Changes (as in report.json) most telling first: those named on one recording
    only, then by their size in standard errors; those without one last."""
    return sorted(listed, key=lambda c: (c["named_in"] == "both", c["change_std_errs"] is None,
                                         -(c["change_std_errs"] or 0.0)))
