"""The report's SVG charts: well-formed, data where it belongs, round ticks, log and
equal-aspect axes, long series thinned."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from rig.hil.svgplot import MAX_POINTS, Chart, Series, histogram, nice_ticks, render

SVG = "{http://www.w3.org/2000/svg}"


def parse(chart: Chart) -> ET.Element:
    return ET.fromstring(render(chart))


@pytest.mark.parametrize("low, high", [(0.0, 1.0), (-1.53, 1.61), (3.0, 812.0), (0.001, 0.0042)])
def test_ticks_are_round_and_span_the_range(low: float, high: float) -> None:
    ticks = nice_ticks(low, high)
    assert 3 <= len(ticks) <= 11 and low - 1e-12 <= ticks[0] and ticks[-1] <= high + 1e-12
    step = np.diff(ticks)
    assert np.allclose(step, step[0])
    mantissa = step[0] / 10 ** np.floor(np.log10(step[0]))
    assert any(np.isclose(mantissa, m) for m in (1, 2, 5))


def test_a_line_goes_through_its_points_in_pixels() -> None:
    chart = Chart("t", "x", "y", series=[Series(np.array([0.0, 1.0, 2.0]), np.array([0.0, 2.0, 1.0]), "line")])
    root = parse(chart)
    points = [tuple(map(float, p.split(","))) for p in root.find(f".//{SVG}polyline").get("points").split()]
    xs, ys = np.array(points).T
    assert np.allclose(np.diff(xs), xs[1] - xs[0])            # equally spaced in x
    assert ys[1] < ys[2] < ys[0]                               # y up is pixels down
    assert "line" in [t.text for t in root.iter(f"{SVG}text")]  # the legend names it


def test_equal_aspect_gives_a_metre_the_same_length_on_both_axes() -> None:
    circle = np.linspace(0, 2 * np.pi, 100)
    root = parse(Chart("top", "x", "y", equal_aspect=True, width=600, height=300,
                       series=[Series(np.cos(circle), np.sin(circle))]))
    xs, ys = np.array([tuple(map(float, p.split(","))) for p in
                       root.find(f".//{SVG}polyline").get("points").split()]).T
    assert np.ptp(xs) == pytest.approx(np.ptp(ys), rel=0.02)


def test_log_axis_ticks_powers_of_ten_and_skips_what_it_cannot_draw() -> None:
    values = np.array([0.5, 3.0, 40.0, 0.0])
    root = parse(Chart("latency", "t", "ms", log_y=True, series=[Series(np.arange(4.0), values, kind="dots")]))
    labels = {t.text for t in root.iter(f"{SVG}text")}
    assert {"1", "10"} <= labels
    assert len(root.findall(f".//{SVG}circle")) == 3            # the zero has no place on a log axis


def test_long_series_are_thinned_and_bars_carry_error_bars() -> None:
    n = 3 * MAX_POINTS + 7
    root = parse(Chart("e", "t", "m", series=[Series(np.arange(n, dtype=float), np.ones(n))]))
    assert len(root.find(f".//{SVG}polyline").get("points").split()) <= MAX_POINTS
    bars = parse(Chart("b", "k", "m", series=[Series(np.arange(3.0), np.array([1.0, -1.0, 0.5]), kind="bars",
                                                      yerr=np.array([0.1, 0.2, 0.3]))]))
    assert len(bars.findall(f".//{SVG}rect")) == 1 + 1 + 3      # frame, clip area, three bars
    heights = [float(r.get("height")) for r in bars.findall(f".//{SVG}g/{SVG}rect")]
    assert heights[0] == pytest.approx(heights[1]) and heights[2] == pytest.approx(heights[0] / 2)
    hist = histogram(np.array([1.0, 1.0, 2.0, 3.0]), bins=3)
    assert hist.kind == "bars" and hist.y.sum() == 4
