"""A flight's constant tag offset in its TDOA errors: found, and removed by
`untranslated` without touching what an offset cannot explain."""

from __future__ import annotations

import numpy as np

from rig.bias.dataset import Samples
from rig.bias.tag_offset import offset_basis, tag_offsets, untranslated
from rig.estimator import native

ANCHORS = np.array([[-4, -4, 0.2], [-4, 4, 2.8], [4, 4, 0.2], [4, -4, 2.8], [0, -4, 2.8], [0, 4, 0.2]], float)


def _flight(name: str, offset: np.ndarray, rng: np.random.Generator, n: int = 3000) -> tuple[Samples, np.ndarray]:
    """A circle flight whose TDOA errors are a constant tag `offset`, a per-link pattern
    an offset cannot mimic (the tag's azimuth in anchor A's frame, second order), and
    noise; also returns the pattern."""
    angle = rng.uniform(-np.pi, np.pi, n)
    tag = np.column_stack([1.5 * np.cos(angle), 1.5 * np.sin(angle), 1.5 + 0.3 * np.sin(3 * angle)])
    ia = rng.integers(0, len(ANCHORS), n)
    ib = (ia + 1 + rng.integers(0, len(ANCHORS) - 1, n)) % len(ANCHORS)
    rots = np.repeat(np.eye(3)[None], n, axis=0)
    features = native.features_batch(tag, rots, ANCHORS[ia], rots, ANCHORS[ib], rots)
    pattern = 0.2 * np.cos(2 * features[:, 6])
    label = offset_basis(features) @ offset + pattern + rng.normal(0, 0.05, n)
    return Samples(features, label, np.full(n, name), ia, ib, np.arange(n) * 0.02), pattern


def test_the_basis_is_the_tdoa_change_of_a_tag_moved() -> None:
    tag, moved = np.array([[0.3, -0.2, 1.4]]), np.array([[0.3, -0.2, 1.4]]) + [0.01, -0.02, 0.03]
    rots = np.eye(3)[None]
    a, b = ANCHORS[[0]], ANCHORS[[3]]
    tdoa = lambda p: np.linalg.norm(b - p) - np.linalg.norm(a - p)  # noqa: E731
    features = native.features_batch(tag, rots, a, rots, b, rots)
    # a tag measured as if it were at `moved` reads the TDOA error H δ
    assert abs(float(offset_basis(features)[0] @ (moved - tag)[0]) - (tdoa(moved) - tdoa(tag))) < 1e-4


def test_each_flights_offset_is_found_and_removed_and_the_rest_kept() -> None:
    rng = np.random.default_rng(3)
    offsets = {"f0": np.array([0.04, -0.04, 0.09]), "f1": np.array([0.0, 0.0, -0.2])}
    parts = [_flight(name, offset, rng) for name, offset in offsets.items()]
    samples = Samples.concatenate([p[0] for p in parts])
    pattern = np.concatenate([p[1] for p in parts])
    found = tag_offsets(samples)
    for name, offset in offsets.items():
        assert np.allclose(found[name], offset, atol=0.02), (name, found[name])
    left = untranslated(samples)
    assert all(np.allclose(v, 0, atol=1e-9) for v in tag_offsets(left).values())
    # what an offset cannot explain stays: the pattern is still most of the label
    assert np.corrcoef(left.label, pattern)[0, 1] > 0.8
    assert np.std(left.label - pattern) < 0.07
