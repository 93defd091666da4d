"""What a recording adds to a control recording of the same flight (`rig diagnose
REC --control CONTROL`): real flights carry effects of their own, so a change made
to the flight (an anchor moved, a firmware's timestamping changed, an effect
injected) shows as the difference of the two diagnoses, effect by effect.

The two are comparable because each finding is estimated given the simpler
explanations only (rig.diagnosis.diagnose, method step 4): what an effect added to a recording
changes in them is mostly that effect. For an effect named on both, the change is
the recording's parameters less the control's (a scale's ratio less one added to
one); a delay confined to a window on one and not on the other is compared outside
the window. An NLOS changes by its mean shift (fraction × mean excess) over the
recording's region (the control's, where only the control names one), each
recording's estimated there as the search that found it estimates, whether the
control names one there or not: a flight has excess paths of its own, below the bar
or in a box of its own. The floor's
multipath and error are not differences of parameters; they are listed as each
recording has them. An effect named on the recording only changes from the
control's estimate of it where the control has one (the parametric TDOA effects
it does not name, `unnamed_estimates`: a flight's own effect below the bar is still
there), else from neutral; one named on the control only changes to the
recording's estimate of it where the recording has one. Else a clock effect named
on the control only was cancelled by the recording's (its own plus an opposite one
adds up to about none): its change is from the control's value to neutral.

Each change of an effect with design columns also says from which size the recording
tells a change of its direction from the effect's look-alikes (rig.diagnosis.identifiability):
a change below it is not the effect's own signal, and may be a look-alike's moving
(a flight's own pattern-like bias read as a displacement)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.data.recording import Recording
from rig.diagnosis import nlos_mixture
from rig.diagnosis.channels import AXES
from rig.diagnosis.combine import outside_window
from rig.diagnosis.confined import NLOS_PRIOR_M
from rig.diagnosis.diagnose import diagnose
from rig.diagnosis.findings import Diagnosis, rounded_floats
from rig.diagnosis.floor_error import ON_GROUND_M
from rig.diagnosis.identifiability import Identifiability
from rig.diagnosis.robust import MIN_SAMPLES, irls
from rig.estimator.metrics import interpolate_positions
from rig.sim.effects import Region, anchor_sign

NOT_ADDITIVE = {"multipath_floor", "on_ground_delay"}       # listed as they are, not as a difference
NLOS = "nlos"                                                  # changes by its mean shift over the samples
CANCELLABLE = {"time_offset", "clock_drift"}                      # a clock's: the recording's may cancel the control's


SAME_FLIGHT_M = 0.05    # a control's ground truth this close to the recording's (median): the same flight
SAME_SURVEY_M = 0.01    # its anchors surveyed this close: the same room
SAME_SPAN = 0.9         # and its ground truth covering this share of the recording's


def flight_difference(rec: Recording, control: Recording) -> str | None:
    """Why `control` does not look like a recording of the same flight as `rec` (None
    when it does): other anchors or survey, or a ground truth elsewhere or elsewhen.
    Its changes then include what differs between two flights (one flown again has
    pose-dependent errors of its own, and a survey redone moves every anchor's
    reference), not only a change made to one."""
    reasons = []
    own, its = rec.anchor_map(), control.anchor_map()
    if set(own) != set(its):
        reasons.append(f"anchors {sorted(its)} against the recording's {sorted(own)}")
    elif own:
        moved = max(float(np.linalg.norm(np.subtract(own[k].position, its[k].position))) for k in own)
        if moved > SAME_SURVEY_M:
            reasons.append(f"anchors surveyed up to {moved:.2f} m from the recording's")
    t, truth = rec.truth.t, control.truth
    inside = (t >= truth.t[0]) & (t <= truth.t[-1]) if len(truth) else np.zeros(len(t), bool)
    if inside.mean() < SAME_SPAN:
        reasons.append(f"a ground truth over {inside.mean():.1%} of the recording's time")
    if inside.any():
        at = interpolate_positions(truth, t[inside])
        apart = float(np.median(np.linalg.norm(at - rec.truth.position[inside], axis=1)))
        if apart > SAME_FLIGHT_M:
            reasons.append(f"a ground truth {apart:.2f} m from the recording's (median)")
    return "; ".join(reasons) or None


@dataclass
class Change:
    """One effect of the catalog, as it differs between a recording and its control."""

    effect: str
    anchors: list[int]
    named_in: str                    # "both", "recording" or "control"
    change: dict | None              # the recording's parameters less the control's; None where not a difference
    recording: dict | None           # the finding on the recording (report.json's), if named there
    control: dict | None             # on the control, if named there
    shown: Shown | None = None       # the change's size against what the recording tells apart; None: not assessed
    lever_arm_share: float | None = None   # a delay's: the part of its change the lever arm's change carries
    control_unnamed: dict | None = None    # named on the recording only: the control's estimate, unnamed there
    recording_unnamed: dict | None = None  # named on the control only: the recording's estimate, unnamed there
    # reported in a look-alike's place on one only: the other's estimate in that place
    control_in_place: dict | None = None
    recording_in_place: dict | None = None
    # the control is the same flight: the two recordings share its slow error
    shares_slow_error: bool = False

    @property
    def std_errs(self) -> float | None:
        """The change in the recording's standard errors, its largest component's (None
        where either is missing): of its finding, or, named on the control only, of its
        estimate below the bar (`recording_unnamed`), which the change goes to. Against a
        control of the same flight, which shares its slow error, in the standard errors
        of independent samples (`std_err_independent`) where the recording has them.
        Conservative for a recording that shares its noise with the control (effects
        injected into it), whose difference is less noisy."""
        recording = self.recording or self.recording_unnamed or {}
        errors = (self.shares_slow_error and recording.get("std_err_independent")) or recording.get("std_err") or {}
        ratios = [np.abs(np.asarray(self.change[field], float) - neutral(self.effect))
                  / np.maximum(np.asarray(error, float), 1e-12)
                  for field, error in errors.items() if self.change and field in self.change]
        return float(max(np.max(r) for r in ratios)) if ratios else None

    def to_json(self) -> dict:
        z = self.std_errs
        out = {"effect": self.effect, "named_in": self.named_in, "change": rounded_floats(self.change),
               "change_std_errs": None if z is None else round(z, 2),
               "recording": _params(self.recording), "control": _params(self.control)}
        if self.shown is not None:
            out["size"], out["told_apart_from"] = round(self.shown.size, 6), self.shown.told_apart_from
        if self.anchors:
            out["anchors"] = self.anchors
        if self.lever_arm_share is not None:
            out["lever_arm_share_m"] = round(self.lever_arm_share, 6)
        if self.control_unnamed is not None:
            out["control_unnamed"] = _params(self.control_unnamed)
        if self.recording_unnamed is not None:
            out["recording_unnamed"] = _params(self.recording_unnamed)
        for side, estimate in (("control", self.control_in_place), ("recording", self.recording_in_place)):
            if estimate is not None:
                out[f"{side}_in_place"] = _params(estimate)
        return out


@dataclass
class TdoaSamples:
    """The recording's compared TDOA samples: where the tag was, which two anchors each
    one paired and what the named effects other than NLOS leave of it. An NLOS's change
    is estimated over them."""

    positions: np.ndarray          # (n, 3) m
    anchor_ids: np.ndarray         # (n, 2): id_a, id_b
    left: np.ndarray               # (n,) in noise deviations (Diagnosis.tdoa_left)
    scale: float                   # the noise deviation, m

    @classmethod
    def of(cls, diagnosis: Diagnosis) -> "TdoaSamples":
        problem = diagnosis.problem
        d, rows = problem.rec.tdoa, problem.tdoa_rows
        left = diagnosis.tdoa_left if diagnosis.tdoa_left is not None else np.full(len(rows), np.nan)
        return cls(problem.tag_positions(), np.column_stack([d.id_a[rows], d.id_b[rows]]), left,
                   float(problem.scales["tdoa"][0]) if len(rows) else 1.0)

    @classmethod
    def from_json(cls, listed: dict) -> "TdoaSamples":
        return cls(np.asarray(listed["positions"], float).reshape(-1, 3),
                   np.asarray(listed["anchor_ids"], int).reshape(-1, 2), np.asarray(listed["left"], float),
                   float(listed["scale"]))

    def to_json(self) -> dict:
        return {"positions": np.round(self.positions, 3).tolist(), "anchor_ids": self.anchor_ids.tolist(),
                "left": np.round(self.left, 4).tolist(), "scale": self.scale}

    def inside(self, anchor: int, region: dict | None) -> np.ndarray:
        """Which samples pair `anchor` with the tag inside `region` (JSON; None: anywhere)."""
        return (self.anchor_ids == anchor).any(axis=1) & Region.from_json(region).contains(self.positions)

    def signed(self, anchor: int) -> np.ndarray:
        """What is left of each sample as `anchor`'s range reads it (0 where it is not in
        the pair): a longer range raises the TDOA whose id_b it is."""
        return anchor_sign(self.anchor_ids[:, 0], self.anchor_ids[:, 1], anchor) * self.left


@dataclass
class Shown:
    """An amount of an effect (its change from neutral), its size, and the size from
    which the recording tells an amount of its direction from the effect's
    look-alikes (None: at no size)."""

    size: float
    told_apart_from: float | None

    @property
    def below(self) -> bool:
        return self.told_apart_from is None or self.size < self.told_apart_from


def shown(items: Sequence[Identifiability], effect: str, anchors: list[int], params: dict) -> Shown | None:
    """`params` (an effect's, or a change's) against the recording's identifiability
    `items`; None for an effect without design columns (NLOS, the floor's) or a
    parameter it does not hold."""
    for item in items:
        if item.effect == effect and item.anchors == anchors and item.param in params:
            amount = np.asarray(params[item.param], float) - neutral(effect)
            return Shown(item.size(amount), item.told_apart_along(amount))
    return None


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


def mean_shift(nlos: dict) -> float:
    """What an NLOS adds to a range inside its region, on average."""
    return nlos["fraction"] * nlos["mean_excess_m"]


def nlos_estimate(samples: TdoaSamples, nlos: dict, by_shape: bool) -> float | None:
    """The mean shift (m) that an NLOS on `nlos`'s anchor and region has on these
    samples, with the tag in the air, estimated as the search that found it estimates:
    by shape (the excess's mixture inside the region against the anchor's ranges
    outside it), or by mean shift. None: too few samples, or none left to estimate on."""
    s = samples.signed(nlos["anchor"])
    rows = (s != 0) & np.isfinite(s) & (samples.positions[:, 2] >= ON_GROUND_M)
    region = Region.from_json(nlos.get("region"))
    if by_shape:
        shape = nlos_mixture.shape_in_region(samples.positions[rows], s[rows], samples.scale, region)
        return None if shape is None else shape[0] * shape[1]
    inside = rows & region.contains(samples.positions)
    if inside.sum() < MIN_SAMPLES:
        return None
    return float(irls(s[inside], np.full((inside.sum(), 1), 1.0 / samples.scale), np.array([NLOS_PRIOR_M]))[0])


def nlos_change(found: dict | None, own: dict | None, samples: TdoaSamples | None,
                control_samples: TdoaSamples | None) -> dict | None:
    """An NLOS's change of mean shift over the region the recording found (the
    control's, where only the control names one): both recordings' estimates there,
    made as the search that found it makes them, the recording's less the control's. A
    flight's own excess there counts on both sides, named on the control or not, and
    in whatever region the control found its own. None where either recording's
    samples are not at hand."""
    named = found or own
    if samples is None or control_samples is None:
        return None
    by_shape = "found_by" in named.get("where", {})
    estimates = [nlos_estimate(on, named["params"], by_shape) for on in (samples, control_samples)]
    if None in estimates:
        return None
    return {"mean_shift_m": estimates[0] - estimates[1]}


def change(effect: str, anchors: list[int], found: dict | None, control: dict | None,
           samples: TdoaSamples | None = None, control_unnamed: dict | None = None,
           recording_unnamed: dict | None = None, control_samples: TdoaSamples | None = None,
           control_in_place: Sequence[dict] = (), recording_in_place: Sequence[dict] = ()) -> Change:
    """The effect's change from `control` (its finding there, or None) to `found`;
    an NLOS's over both recordings' TDOA samples. Named on one recording only, from
    or to the other's estimate of it (`control_unnamed`, `recording_unnamed`: its
    report.json's `unnamed_estimates`), where it has one: the flight's effect below
    the bar. Reported in a look-alike's place (`alternative_to`) on one recording
    only, from or to the other's estimate of it in that place (`control_in_place`,
    `recording_in_place`: report.json's `in_place_estimates`) on the axes it takes."""
    named_in = "both" if found and control else "recording" if found else "control"
    control_estimate = on_named_axes(control_unnamed, found) if named_in == "recording" else None
    recording_estimate = on_named_axes(recording_unnamed, control) if named_in == "control" else None
    control_place, recording_place = in_place(found, control, control_in_place), in_place(control, found,
                                                                                         recording_in_place)
    if effect in NOT_ADDITIVE:
        difference = None
    elif effect == NLOS:
        difference = nlos_change(found, control, samples, control_samples)
    elif control_place is not None:
        difference = added(effect, found["params"], control_place["params"])
    elif recording_place is not None:
        difference = added(effect, recording_place["params"], control["params"])
    elif named_in == "both":
        difference = added(effect, found["params"], control["params"])
    elif named_in == "recording":
        difference = (dict(found["params"]) if control_estimate is None
                      else added(effect, found["params"], control_estimate["params"]))
    elif recording_estimate is not None:
        difference = added(effect, recording_estimate["params"], control["params"])
    else:
        difference = cancelled(effect, control["params"]) if effect in CANCELLABLE else None
    return Change(effect, anchors, named_in, difference, found, control, control_unnamed=control_estimate,
                  recording_unnamed=recording_estimate, control_in_place=control_place,
                  recording_in_place=recording_place)


def on_named_axes(estimate: dict | None, finding: dict | None) -> dict | None:
    """The other recording's `estimate` of an effect it does not name, neutral on the
    axes `finding` is not named on (`not_named_axes`, neutral there too): on those
    neither recording names it, and they do not change."""
    axes = (finding or {}).get("not_named_axes")
    if estimate is None or not axes:
        return estimate
    return neutral_on(estimate, finding["effect"], {AXES.index(axis) for axis in axes})


def neutral_on(estimate: dict, effect: str, axes: set[int]) -> dict:
    """`estimate` with its vector parameters neutral on `axes` (indices)."""
    params = {field: [neutral(effect) if j in axes else v for j, v in enumerate(value)]
              if isinstance(value, list) else value for field, value in estimate["params"].items()}
    return estimate | {"params": params}


def in_place(finding: dict | None, other: dict | None, other_in_place: Sequence[dict]) -> dict | None:
    """Where `finding` is reported in a look-alike's place and `other` (the other
    recording's finding of that effect, if any) is not: the other recording's estimate
    of it in the same place (its `in_place_estimates`), neutral off the axes the
    finding takes. None otherwise."""
    instead = (finding or {}).get("alternative_to")
    if instead is None or (other or {}).get("alternative_to"):
        return None
    estimate = next((e for e in other_in_place if key(e) == key(finding)
                     and e["in_place_of"]["effect"] == instead["effect"]), None)
    if estimate is None or "axes" not in instead:
        return estimate
    return neutral_on(estimate, finding["effect"], {j for j, axis in enumerate(AXES) if axis not in instead["axes"]})


def changes(findings: list[dict], control: list[dict], identifiability: Sequence[Identifiability] = (),
            cross_talk: dict[int, list[float]] | None = None, samples: TdoaSamples | None = None,
            control_unnamed: Sequence[dict] = (), recording_unnamed: Sequence[dict] = (),
            control_samples: TdoaSamples | None = None, control_in_place: Sequence[dict] = (),
            recording_in_place: Sequence[dict] = (), same_flight: bool = False) -> list[Change]:
    """Every effect reported on either recording, as it changed; the recording's
    findings first, by their evidence, then those on the control only. One reported
    in a look-alike's place (`alternative_to`) counts too: it carries that
    explanation's value, which a change of the flight moves as well. With the
    recording's `identifiability`, each difference is assessed against it; with its
    lever arm's `cross_talk` (rig.diagnosis.diagnose.lever_arm_cross_talk), each delay's change
    gets the share of it that the lever arm's change carries; with both recordings'
    TDOA `samples` and `control_samples`, an NLOS gets its change; with either's
    `unnamed_estimates`, an effect named on the other only changes from or to its
    estimate there; with their `in_place_estimates`, one reported in a look-alike's
    place on one only, from or to the other's estimate in that place. Of the `same_flight`,
    a change is measured in the standard errors of independent samples (Change.std_errs)."""
    named = {key(f): f for f in findings}
    own = {key(f): f for f in control}
    own_below, named_below = ({key(u): u for u in listed} for listed in (control_unnamed, recording_unnamed))
    order = sorted(named, key=lambda k: -named[k]["evidence"]) + [k for k in own if k not in named]
    out = [change(k[0], list(k[1]), named.get(k), own.get(k), samples, own_below.get(k), named_below.get(k),
                  control_samples, control_in_place, recording_in_place) for k in order]
    lever = lever_arm_change(named, own)
    for c in out:
        c.shares_slow_error = same_flight
        if c.change is None:
            continue
        c.shown = shown(identifiability, c.effect, c.anchors, c.change)
        if c.effect == "anchor_delay" and lever is not None and cross_talk and c.anchors[0] in cross_talk:
            c.lever_arm_share = float(np.dot(cross_talk[c.anchors[0]], lever))
    return out


LEVER_ARM = ("lever_arm", ())


def lever_arm_change(named: dict, own: dict) -> np.ndarray | None:
    """The lever arm's change from the control, None where neither recording names it.
    Unlike `change`, where an effect the recording does not name is no difference
    (it may be there below the bar), an unnamed lever arm counts as none: the share
    is about the delays as fitted, and those were fitted without it."""
    if LEVER_ARM not in named and LEVER_ARM not in own:
        return None
    offsets = [np.asarray(f[LEVER_ARM]["params"]["offset_m"], float) if LEVER_ARM in f else np.zeros(3)
               for f in (named, own)]
    return offsets[0] - offsets[1]


def by_size(listed: list[dict]) -> list[dict]:
    """Changes (as in report.json) most telling first: those named on one recording
    only, then by their size in standard errors; those without one last."""
    return sorted(listed, key=lambda c: (c["named_in"] == "both", c["change_std_errs"] is None,
                                         -(c["change_std_errs"] or 0.0)))


def every_fit(report: dict) -> list[dict]:
    """A report's findings and the fits it leaves not explained: a change of the flight
    can move either, and an effect beyond its bound on one recording may be within it
    on the other."""
    return report["findings"] + report.get("not_explained", [])


@dataclass
class AgainstControl:
    """A recording and a control recording of the same flight, both diagnosed, and what
    changed between them: report.json's `against_control`."""

    diagnosis: Diagnosis
    control: Diagnosis
    against_control: dict


def diagnose_against(rec: Recording, control_rec: Recording, control_name: str, progress=None,
                     control_progress=None) -> AgainstControl:
    """Diagnose `rec` and its control, and compare them effect by effect: whether the
    control looks like the same flight (`same_flight`, `how_it_differs`) and each
    effect's change from it (`changes`)."""
    differs = flight_difference(rec, control_rec)
    control = diagnose(control_rec, progress=control_progress)
    diagnosis = diagnose(rec, progress=progress)
    report, control_report = diagnosis.to_json(), control.to_json()
    against = {"recording": control_name, "same_flight": differs is None}
    if differs is not None:
        against["how_it_differs"] = differs
    against["changes"] = [
        c.to_json() for c in changes(every_fit(report), every_fit(control_report), diagnosis.identifiability,
                                     diagnosis.cross_talk, TdoaSamples.of(diagnosis),
                                     control_report.get("unnamed_estimates", ()), report["unnamed_estimates"],
                                     TdoaSamples.of(control), control_report.get("in_place_estimates", ()),
                                     report["in_place_estimates"], same_flight=differs is None)]
    return AgainstControl(diagnosis, control, against)
