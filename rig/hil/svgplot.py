"""Charts as inline SVG for the run report: lines, dots, bars with error bars and
histograms on linear or log axes, with ticks, labels and a legend.

Written for the report rather than drawn with matplotlib, which took longer to import
and render than the whole replay of a flight took to run; the page stays
self-contained, and the charts scale without blurring.
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass, field

import numpy as np

COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd")
MAX_POINTS = 4000          # a longer series is thinned to this many points (every k-th)
MARGIN = (62, 18, 34, 46)  # left, right, top, bottom (px)


@dataclass
class Series:
    x: np.ndarray
    y: np.ndarray
    label: str = ""
    color: str = COLORS[0]
    kind: str = "line"                 # line, dots or bars
    width: float = 1.2
    yerr: np.ndarray | None = None     # bars: symmetric error bars


@dataclass
class Chart:
    title: str
    xlabel: str
    ylabel: str
    series: list[Series] = field(default_factory=list)
    vlines: list[tuple[float, str, str]] = field(default_factory=list)   # (x, color, label)
    hlines: list[tuple[float, str]] = field(default_factory=list)        # (y, color)
    log_y: bool = False
    equal_aspect: bool = False
    width: int = 860
    height: int = 300
    xticks: list[float] | None = None


def histogram(values: np.ndarray, bins: int = 60, **kwargs) -> Series:
    """Bars of a histogram (bar centres and counts)."""
    counts, edges = np.histogram(values, bins=bins)
    return Series((edges[:-1] + edges[1:]) / 2, counts.astype(float), kind="bars", **kwargs)


def nice_ticks(low: float, high: float, count: int = 6) -> list[float]:
    """About `count` round values (1, 2 or 5 times a power of ten) spanning low..high."""
    if not math.isfinite(low) or not math.isfinite(high):
        return []
    if high <= low:
        return [low]
    raw = (high - low) / max(count - 1, 1)
    power = 10 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 5, 10) if m * power >= raw)
    first = math.ceil(low / step - 1e-9) * step
    return [round(first + k * step, 12) for k in range(int((high - first) / step + 1e-9) + 1)]


def _label(value: float) -> str:
    return f"{value:.6g}"


def _finite(series: list[Series], attr: str) -> np.ndarray:
    parts = [np.asarray(getattr(s, attr), float).ravel() for s in series]
    values = np.concatenate(parts) if parts else np.zeros(0)
    return values[np.isfinite(values)]


class _Axes:
    """Data to pixel coordinates of the plot area."""

    def __init__(self, chart: Chart) -> None:
        left, right, top, bottom = MARGIN
        self.x0, self.x1, self.y0, self.y1 = left, chart.width - right, top, chart.height - bottom
        xs = np.concatenate([_finite(chart.series, "x"), [v[0] for v in chart.vlines]])
        ys = _finite(chart.series, "y")
        for s in chart.series:
            if s.kind == "bars":
                ys = np.concatenate([ys, [0.0]])
                if s.yerr is not None:
                    ys = np.concatenate([ys, np.asarray(s.y) + s.yerr, np.asarray(s.y) - s.yerr])
        ys = np.concatenate([ys, [h[0] for h in chart.hlines]])
        self.log_y = chart.log_y
        if self.log_y:
            ys = np.log10(ys[ys > 0]) if np.any(ys > 0) else np.zeros(1)
        self.xlim = self._span(xs, pad=0.0 if not any(s.kind == "bars" for s in chart.series) else 0.03)
        self.ylim = self._span(ys, pad=0.05)
        if chart.equal_aspect:
            self._equalise()

    @staticmethod
    def _span(values: np.ndarray, pad: float) -> tuple[float, float]:
        if not len(values):
            return 0.0, 1.0
        low, high = float(values.min()), float(values.max())
        if high - low < 1e-12:
            low, high = low - 0.5, high + 0.5
        margin = (high - low) * pad
        return low - margin, high + margin

    def _equalise(self) -> None:
        """One metre is as long on both axes: widen the narrower span about its centre."""
        per_px = max((self.xlim[1] - self.xlim[0]) / (self.x1 - self.x0),
                     (self.ylim[1] - self.ylim[0]) / (self.y1 - self.y0))
        cx, cy = sum(self.xlim) / 2, sum(self.ylim) / 2
        hx, hy = per_px * (self.x1 - self.x0) / 2, per_px * (self.y1 - self.y0) / 2
        self.xlim, self.ylim = (cx - hx, cx + hx), (cy - hy, cy + hy)

    def px(self, x) -> np.ndarray:
        x = np.asarray(x, float)
        return self.x0 + (x - self.xlim[0]) / (self.xlim[1] - self.xlim[0]) * (self.x1 - self.x0)

    def py(self, y) -> np.ndarray:
        y = np.asarray(y, float)
        if self.log_y:
            y = np.log10(np.where(y > 0, y, np.nan))
        return self.y1 - (y - self.ylim[0]) / (self.ylim[1] - self.ylim[0]) * (self.y1 - self.y0)


def render(chart: Chart) -> str:
    """The chart as one <svg> element."""
    ax = _Axes(chart)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{chart.width}" height="{chart.height}" '
           f'viewBox="0 0 {chart.width} {chart.height}" font-family="sans-serif" font-size="11">',
           f'<rect x="{ax.x0}" y="{ax.y0}" width="{ax.x1 - ax.x0}" height="{ax.y1 - ax.y0}" fill="none" '
           f'stroke="#444"/>',
           f'<text x="{(ax.x0 + ax.x1) / 2}" y="16" text-anchor="middle" font-size="13">{html.escape(chart.title)}</text>',
           f'<text x="{(ax.x0 + ax.x1) / 2}" y="{chart.height - 6}" text-anchor="middle">'
           f'{html.escape(chart.xlabel)}</text>',
           f'<text transform="translate(14 {(ax.y0 + ax.y1) / 2}) rotate(-90)" text-anchor="middle">'
           f'{html.escape(chart.ylabel)}</text>']
    out += _ticks(chart, ax)
    out.append(f'<clipPath id="plot"><rect x="{ax.x0}" y="{ax.y0}" width="{ax.x1 - ax.x0}" '
               f'height="{ax.y1 - ax.y0}"/></clipPath><g clip-path="url(#plot)">')
    for y, color in chart.hlines:
        out.append(f'<line x1="{ax.x0}" x2="{ax.x1}" y1="{ax.py(y):.1f}" y2="{ax.py(y):.1f}" stroke="{color}"/>')
    for s in chart.series:
        out += _draw(s, ax)
    for x, color, _ in chart.vlines:
        out.append(f'<line x1="{ax.px(x):.1f}" x2="{ax.px(x):.1f}" y1="{ax.y0}" y2="{ax.y1}" stroke="{color}" '
                   f'stroke-dasharray="5 3"/>')
    out.append("</g>")
    out += _legend(chart, ax)
    out.append("</svg>")
    return "".join(out)


def _ticks(chart: Chart, ax: _Axes) -> list[str]:
    out = []
    for x in chart.xticks if chart.xticks is not None else nice_ticks(*ax.xlim):
        if ax.xlim[0] <= x <= ax.xlim[1]:
            p = ax.px(x)
            out.append(f'<line x1="{p:.1f}" x2="{p:.1f}" y1="{ax.y1}" y2="{ax.y1 + 4}" stroke="#444"/>'
                       f'<text x="{p:.1f}" y="{ax.y1 + 16}" text-anchor="middle">{_label(x)}</text>')
    if ax.log_y:
        ys = [10.0 ** k for k in range(math.floor(ax.ylim[0]), math.ceil(ax.ylim[1]) + 1)]
    else:
        ys = nice_ticks(*ax.ylim)
    for y in ys:
        p = float(ax.py(y))
        if ax.y0 - 0.5 <= p <= ax.y1 + 0.5:
            out.append(f'<line x1="{ax.x0 - 4}" x2="{ax.x0}" y1="{p:.1f}" y2="{p:.1f}" stroke="#444"/>'
                       f'<line x1="{ax.x0}" x2="{ax.x1}" y1="{p:.1f}" y2="{p:.1f}" stroke="#ddd"/>'
                       f'<text x="{ax.x0 - 7}" y="{p + 4:.1f}" text-anchor="end">{_label(y)}</text>')
    return out


def _thin(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, math.ceil(len(x) / MAX_POINTS))
    return x[::step], y[::step]


def _draw(s: Series, ax: _Axes) -> list[str]:
    x, y = np.asarray(s.x, float), np.asarray(s.y, float)
    if s.kind == "bars":
        return _bars(s, x, y, ax)
    x, y = _thin(x, y)
    px, py = ax.px(x), ax.py(y)
    keep = np.isfinite(px) & np.isfinite(py)
    if s.kind == "dots":
        return [f'<circle cx="{a:.1f}" cy="{b:.1f}" r="1.3" fill="{s.color}"/>' for a, b in zip(px[keep], py[keep])]
    points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px[keep], py[keep]))
    return [f'<polyline points="{points}" fill="none" stroke="{s.color}" stroke-width="{s.width}"/>']


def _bars(s: Series, x: np.ndarray, y: np.ndarray, ax: _Axes) -> list[str]:
    spacing = np.min(np.diff(np.sort(x))) if len(x) > 1 else 1.0
    half = max(1.0, 0.4 * spacing * (ax.x1 - ax.x0) / (ax.xlim[1] - ax.xlim[0]))
    base = ax.y1 if ax.log_y else float(ax.py(0.0))
    out = []
    for k, (a, b) in enumerate(zip(x, y)):
        if not np.isfinite(b) or (ax.log_y and b <= 0):
            continue
        top, cx = float(ax.py(b)), float(ax.px(a))
        out.append(f'<rect x="{cx - half:.1f}" y="{min(top, base):.1f}" width="{2 * half:.1f}" '
                   f'height="{abs(base - top):.1f}" fill="{s.color}"/>')
        if s.yerr is not None:
            lo, hi = float(ax.py(b - s.yerr[k])), float(ax.py(b + s.yerr[k]))
            out.append(f'<line x1="{cx:.1f}" x2="{cx:.1f}" y1="{lo:.1f}" y2="{hi:.1f}" stroke="#000"/>')
    return out


def _legend(chart: Chart, ax: _Axes) -> list[str]:
    entries = [(s.label, s.color) for s in chart.series if s.label]
    entries += [(label, color) for _, color, label in chart.vlines if label]
    if not entries:
        return []
    out = [f'<rect x="{ax.x1 - 156}" y="{ax.y0 + 3}" width="152" height="{15 * len(entries) + 4}" fill="#fff" '
           f'fill-opacity="0.85" stroke="#ccc"/>']
    for k, (label, color) in enumerate(entries):
        y = ax.y0 + 14 + 15 * k
        out.append(f'<line x1="{ax.x1 - 150}" x2="{ax.x1 - 132}" y1="{y - 4}" y2="{y - 4}" stroke="{color}" '
                   f'stroke-width="2.5"/><text x="{ax.x1 - 127}" y="{y}">{html.escape(label)}</text>')
    return out
