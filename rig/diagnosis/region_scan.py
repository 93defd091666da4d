"""Where in the room an anchor's residuals differ from elsewhere: a scan over the
axis-aligned boxes of a quantile grid of the tag's x and y. Both NLOS finders use it,
each with its own score per box: a mean shift (rig.diagnosis.diagnose) and a heavier upper tail
(rig.diagnosis.nlos_mixture). Quantile bins hold equal numbers of samples, so a box is a share of
the flight wherever the tag spent its time."""

from __future__ import annotations

import numpy as np

from rig.sim import effects as fx

GRID_BINS = 8              # boxes are spanned by this many quantile bins of x and of y


def _quantile_edges(v: np.ndarray) -> np.ndarray:
    edges = np.quantile(v, np.linspace(0, 1, GRID_BINS + 1))
    edges[0], edges[-1] = -np.inf, np.inf
    return edges


def _box_sums(cells: tuple[np.ndarray, np.ndarray], boxes: tuple[np.ndarray, ...],
              values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sums of `values` over the samples in each box (x bins i..j−1, y bins k..m−1) by
    2-D cumulative sums; and the sum over all samples."""
    grid = np.zeros((GRID_BINS + 1, GRID_BINS + 1, *values.shape[1:]))
    np.add.at(grid, cells, values)
    grid = grid.cumsum(0).cumsum(1)
    i, j, k, m = boxes
    return grid[j, m] - grid[i, m] - grid[j, k] + grid[i, k], grid[-1, -1]


class BoxScan:
    """The boxes of the grid over `positions` that hold between `min_share` and
    `max_share` of them; `sums` adds any per-sample values up per box."""

    def __init__(self, positions: np.ndarray, min_share: float, max_share: float):
        self.positions = positions
        self.edges = _quantile_edges(positions[:, 0]), _quantile_edges(positions[:, 1])
        self._cells = tuple(np.searchsorted(e, positions[:, axis], side="right")
                            for axis, e in enumerate(self.edges))
        spans = np.array([(i, j) for i in range(GRID_BINS) for j in range(i + 1, GRID_BINS + 1)])
        every = (*np.repeat(spans, len(spans), axis=0).T, *np.tile(spans, (len(spans), 1)).T)
        n_in, self.n_all = _box_sums(self._cells, every, np.ones(len(positions)))
        ok = (n_in >= min_share * self.n_all) & (n_in <= max_share * self.n_all)
        self._boxes = tuple(side[ok] for side in every)
        self.n_in = n_in[ok]

    def sums(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per box, the sum of `values` (one row per sample, any trailing shape) over
        the samples inside; and their sum over all samples."""
        return _box_sums(self._cells, self._boxes, values)

    def best(self, score: np.ndarray) -> fx.Region | None:
        """The box of the highest finite score, as far as the samples reach (an open
        side ends at the flight's edge); None when no box scores."""
        if not len(score) or not np.isfinite(score).any():
            return None
        b = int(np.argmax(np.where(np.isfinite(score), score, -np.inf)))
        (ex, ey), (i, j, k, m) = self.edges, (side[b] for side in self._boxes)
        box = fx.Region(np.array([ex[i], ey[k], -np.inf]), np.array([ex[j], ey[m], np.inf]))
        chosen = self.positions[box.contains(self.positions)]
        return fx.Region(np.where(np.isfinite(box.low), box.low, chosen.min(axis=0)),
                         np.where(np.isfinite(box.high), box.high, chosen.max(axis=0)))
