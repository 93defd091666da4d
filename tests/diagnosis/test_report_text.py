"""How report.md and `rig diagnose` word a finding: a displacement as how the anchor's
ranges read, not as a moved anchor; its standard errors follow its
parameters, as report.json gives them (a noise-level finding has none), and a fit
beyond its physical bound says by how many of them, in one line where it is listed
among the fits not explained; one left out although its own estimate is within its
bound says that it was beyond only in the joint fit."""

from __future__ import annotations

from rig.diagnosis.findings import Finding
from rig.diagnosis.wording import describe, not_explained_line, where_not_explained


def _finding(effect: str, params: dict, std_err: dict | None, anchors: list[int] = (), channel: str = "tdoa"
             ) -> Finding:
    return Finding(effect, channel, list(anchors), params, 40.0, 1.0, 0.9, {}, std_err=std_err)


def test_a_fitted_finding_gives_its_standard_errors() -> None:
    lever = _finding("lever_arm", {"offset_m": [0.45, -0.2, 0.1]}, {"offset_m": [0.131, 0.1249, 0.27]})
    assert describe(lever).endswith("(standard error [0.13, 0.12, 0.27])")
    delay = _finding("anchor_delay", {"anchor": 3, "meters": 0.24}, {"meters": 0.0671})
    assert "(standard error 0.067)" in describe(delay)
    drift = _finding("clock_drift", {"ppm": -287.0}, {"ppm": 543.2})
    assert "(standard error 543)" in describe(drift)


def test_a_displacement_says_how_the_ranges_read_not_that_the_anchor_moved() -> None:
    moved = _finding("anchor_position", {"anchor": 4, "offset_m": [-0.81, -0.46, 0.52]}, {"offset_m": [0.25, 0.34, 0.49]})
    assert describe(moved).startswith("anchor 4's ranges read as if it stood [-0.81, -0.46, 0.52] m from where the "
                                      "survey puts it")


def test_an_nlos_gives_its_mean_shifts_and_a_noise_level_finding_none() -> None:
    nlos = _finding("nlos", {"anchor": 0, "fraction": 0.5, "mean_excess_m": 0.3,
                             "region": {"min": [0, 0, 0], "max": [1, 1, 1]}}, {"mean_shift_m": 0.021})
    assert "(standard error of its mean shift 0.021)" in describe(nlos)
    floor = _finding("multipath_floor", {"height_m": 0.6, "std_m": 0.2}, None)
    assert "standard error" not in describe(floor)


def test_a_fit_beyond_its_bound_says_by_how_many_standard_errors() -> None:
    """The lever arm's bound is 0.15 m of length: [0.45, -0.2, 0.1] m is 0.502 m long, with
    a standard error of 0.121 m along it, so 2.9 beyond (its largest component alone,
    0.45 ± 0.12 m, would read 2.5)."""
    lever = _finding("lever_arm", {"offset_m": [0.45, -0.2, 0.1]}, {"offset_m": [0.12, 0.1, 0.2]})
    lever.beyond_bound = True
    assert "(0.502 against 0.15, 2.9 standard errors beyond)" in describe(lever)
    lever.beyond_bound = False
    assert "standard errors beyond" not in describe(lever)


def test_a_pattern_beyond_its_bound_is_measured_by_its_peak_to_peak_bias() -> None:
    """[0.9, -0.99, -0.68] has r = 1.2 on the horizon harmonics, more than |c0|: its
    ranges differ by 2r = 2.4 m between two horizontal directions, beyond 1 m though
    every coefficient is within it; the standard error is of that span, through its
    gradient 2 (c1, c2)/r: √((2·0.99·0.3/1.2)² + (2·0.68·0.4/1.2)²) = 0.66."""
    pattern = _finding("antenna_pattern", {"anchor": 2, "coeffs_m": [0.9, -0.99, -0.68]},
                       {"coeffs_m": [0.3, 0.3, 0.4]}, anchors=[2])
    assert ("(antenna pattern [0.9, -0.99, -0.68] m, differing by at most 2.402 m between any two directions)"
            in describe(pattern))
    pattern.beyond_bound = True
    assert "(2.4 against 1, 2.1 standard errors beyond)" in describe(pattern)


def test_a_scale_beyond_its_bound_is_measured_from_one() -> None:
    """A scale's bound (0.15) is of its distance from 1: 1.25 ± 0.05 is 0.25 from it, 2
    standard errors beyond, not 1.25 against 0.15."""
    scale = _finding("imu_accel_scale", {"scale": [1.25, 1.0, 0.98]}, {"scale": [0.05, 0.01, 0.01]}, channel="accel")
    scale.beyond_bound = True
    assert "(0.25 against 0.15, 2.0 standard errors beyond)" in describe(scale)


def test_the_fits_not_explained_are_listed_short_by_where_they_lie() -> None:
    lever = _finding("lever_arm", {"offset_m": [0.1, -0.3, -0.8]}, {"offset_m": [0.04, 0.04, 0.06]})
    moved = _finding("anchor_position", {"anchor": 2, "offset_m": [-2.2, -1.3, 1.2]}, {"offset_m": [0.4, 0.4, 0.9]},
                     anchors=[2])
    pattern = _finding("antenna_pattern", {"anchor": 2, "coeffs_m": [2.0, 0.1, 0.1]}, {"coeffs_m": [1.0, 0.3, 0.3]},
                       anchors=[2])
    assert not_explained_line(moved) == "anchor_position on anchor 2: 2.82 against 1, 3.5 standard errors beyond"
    assert not_explained_line(lever) == "lever_arm on the tdoa channel: 0.86 against 0.15, 12.3 standard errors beyond"
    nlos = _finding("nlos", {"anchor": 2, "fraction": 1.0, "mean_excess_m": 1.748}, {"mean_shift_m": 0.05},
                    anchors=[2])     # its standard error is of the mean shift, not of the bounded excess
    assert not_explained_line(nlos) == "nlos on anchor 2: mean_excess_m 1.748 (bound 1)"
    assert where_not_explained([lever, moved, pattern, moved]) == \
        "anchor 2 (anchor_position, antenna_pattern); the tdoa channel (lever_arm)"



def test_a_per_anchor_fit_says_how_much_it_changes_its_anchors_ranges() -> None:
    """A displacement of 2.2 m over the directions one flight shows changes the ranges
    by 0.12 m: the line and the finding say both."""
    moved = _finding("anchor_position", {"anchor": 2, "offset_m": [-2.2, -1.3, 1.2]}, {"offset_m": [0.4, 0.4, 0.9]},
                     anchors=[2])
    moved.where = {"anchors": [2], "spread_m": {"2": 0.1204},
                   "largest": {"anchor": 2, "tag_azimuth_deg": [10.0, 40.0], "tag_elevation_deg": [-30.0, -20.0],
                               "anchor_elevation_in_body_deg": [20.0, 30.0], "sign": "long"}}
    assert not_explained_line(moved) == ("anchor_position on anchor 2: 2.82 against 1, 3.5 standard errors beyond; "
                                         "its anchor's ranges vary by 0.120 m over the flight")
    assert "; it changes anchor 2's ranges by 0.120 m over the flight (standard deviation; their mean is a delay), " \
           "reading longest with the tag at azimuth 10…40° and elevation -30…-20° in the anchor's frame" in describe(moved)
    link = _finding("link_bias", {"coeffs_m": [0.1] * 6, "gain": 1.0}, {"gain": 0.1})
    link.where = {**moved.where}
    assert "vary by" not in not_explained_line(link)          # its spread is every anchor's, not one anchor's
    assert "it varies most on anchor 2's links (0.120 m)" in describe(link)


def test_a_fit_left_out_only_for_the_joint_fit_says_so_and_not_how_far_beyond() -> None:
    """A delay of −0.067 m (bound 1.5 m) that the model left out beside its anchor's
    pattern: not explained, but neither its line nor report.json calls its estimate
    physically impossible; a fit beyond its bound keeps the usual wording."""
    delay = _finding("anchor_delay", {"anchor": 5, "meters": -0.067}, {"meters": 0.03}, anchors=[5])
    delay.beyond_bound = True
    assert delay.beyond_only_jointly and delay.to_json()["beyond_only_jointly"] is True
    assert not_explained_line(delay) == ("anchor_delay on anchor 5: within its bound as estimated; beyond it only "
                                         "in the joint fit, beside a fit beyond its bound")
    assert "within what this effect can physically be" in describe(delay) and "beyond what" not in describe(delay)
    moved = _finding("anchor_position", {"anchor": 2, "offset_m": [-2.2, -1.3, 1.2]}, {"offset_m": [0.4, 0.4, 0.9]},
                     anchors=[2])
    moved.beyond_bound = True
    assert not moved.beyond_only_jointly and "beyond_only_jointly" not in moved.to_json()
    assert "beyond what this effect can physically be" in describe(moved)
    delay.beyond_bound = False                                     # a finding: neither
    assert not delay.beyond_only_jointly and "beyond_physical_bound" not in delay.to_json()
