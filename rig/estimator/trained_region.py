"""Where a bias model was trained: the tag's positions relative to each anchor that its
network learnt from, as cells of a coarse grid.

The network's link features start with the anchor's position relative to the tag (in
the world frame), so a link whose relative position lies far from every one it was
trained on asks the network to extrapolate. The shipped model learnt from flights that
all circle the room's centre at about 1.5 m; held out of training, a quarter of that
circle had its TDOA error narrowed in 8 of 12 runs of the shipped recipe and widened
in 4, and abstaining outside the region did not narrow more of them (10 of 12, but the
mean spread 0.278 → 0.282 m; docs/notebook/bias-validation.md). So the region does not switch the correction off;
`rig evaluate` reports how much of a flight lay outside it, the share of the
measurements whose correction was an extrapolation, so that a user knows when to
compare with `--no-nn` or to train on flights there.

A relative position is inside when its cell or one of the 26 cells around it holds a
training sample: within CELL_M to 2·CELL_M of where the network was trained.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

CELL_M = 0.5
_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


def _cells(relative: np.ndarray, cell_m: float) -> np.ndarray:
    return np.floor(np.asarray(relative, float).reshape(-1, 3) / cell_m).astype(np.int64)


def _keys(cells: np.ndarray) -> np.ndarray:
    """One integer per cell (cells are within ±2^20 of the anchor: ±500 km at 0.5 m)."""
    shifted = cells + (1 << 20)
    return (shifted[:, 0] << 42) | (shifted[:, 1] << 21) | shifted[:, 2]


@dataclass
class TrainedRegion:
    """Per anchor id, the grid cells of the tag's position relative to that anchor
    (anchor − tag, world frame, the network's features 0–2 and 3–5) in training."""

    cells: dict[int, np.ndarray] = field(default_factory=dict)   # id -> (n, 3) int cell indices
    cell_m: float = CELL_M

    def __post_init__(self) -> None:
        if not self.cell_m > 0:
            raise ValueError(f"a trained region's cell must be positive, not {self.cell_m}")
        self.cells = {int(k): np.unique(np.asarray(v, np.int64).reshape(-1, 3), axis=0)
                      for k, v in self.cells.items()}
        self._dilated = {k: np.unique(_keys((v[:, None, :] + _NEIGHBOURS).reshape(-1, 3)))
                         for k, v in self.cells.items()}

    @classmethod
    def from_features(cls, features: np.ndarray, id_a: np.ndarray, id_b: np.ndarray,
                      cell_m: float = CELL_M) -> "TrainedRegion":
        """The region of training samples' 14 measurement features and anchor ids."""
        features = np.atleast_2d(features)
        relative = np.vstack([features[:, 0:3], features[:, 3:6]])
        ids = np.concatenate([id_a, id_b]).astype(int)
        return cls({k: _cells(relative[ids == k], cell_m) for k in np.unique(ids)}, cell_m)

    def inside(self, relative: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Whether each link's relative position (anchor − tag, m) lies in the region of
        its anchor; an anchor the model never saw has no region."""
        keys, ids = _keys(_cells(relative, self.cell_m)), np.asarray(ids, int).reshape(-1)
        out = np.zeros(len(ids), bool)
        for k, seen in self._dilated.items():
            mine = ids == k
            out[mine] = np.isin(keys[mine], seen)
        return out

    def to_json(self) -> dict:
        return {"cell_m": self.cell_m, "cells": {str(k): v.tolist() for k, v in sorted(self.cells.items())}}

    @classmethod
    def from_json(cls, obj: dict) -> "TrainedRegion":
        try:
            return cls({int(k): np.array(v, np.int64) for k, v in obj["cells"].items()}, float(obj["cell_m"]))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"a model's trained_region must be {{'cell_m', 'cells': {{id: [[i, j, k], ...]}}}} "
                             f"({exc})") from exc


def outside_share(region: TrainedRegion, relative_a: np.ndarray, relative_b: np.ndarray,
                  id_a: np.ndarray, id_b: np.ndarray) -> float:
    """The share of measurements (rows: both anchors' positions relative to the tag, as
    the network's features 0–2 and 3–5, and their ids) with either link outside the
    region: the corrections that were extrapolations."""
    if not len(relative_a):
        return 0.0
    inside = region.inside(relative_a, id_a) & region.inside(relative_b, id_b)
    return float(1.0 - inside.mean())
