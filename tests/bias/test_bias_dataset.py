"""The bias network's dataset: features at the estimator's own pose (what the network
sees in flight) or at the ground truth's, labels from the ground truth either way."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.bias.dataset import estimated_poses, flight_samples, truth_latency
from rig.data.importer import load_any
from rig.estimator import metrics

pytestmark = pytest.mark.slow        # left out of `make test-fast`

FLIGHT = "0426-traj1"


@pytest.fixture(scope="module")
def flight(data_dir: Path):
    rec = load_any(data_dir / "flights" / FLIGHT)
    return rec, truth_latency(rec)


def implied_tag(rec, samples) -> np.ndarray:
    """Features 0-2 are anchor A minus the tag's position."""
    anchors = rec.anchor_map()
    return np.array([anchors[int(k)].position for k in samples.id_a]) - samples.features[:, 0:3]


def test_features_are_at_the_estimators_pose_and_labels_at_the_truth(flight) -> None:
    rec, latency = flight
    at_estimate = flight_samples(rec, FLIGHT, latency)
    at_truth = flight_samples(rec, FLIGHT, latency, features_from="truth")
    np.testing.assert_array_equal(at_estimate.label, at_truth.label)
    np.testing.assert_array_equal(at_estimate.t, at_truth.t)

    estimated, _ = estimated_poses(rec, at_estimate.t)
    true = metrics.interpolate_positions(rec.truth, at_truth.t + latency)
    np.testing.assert_allclose(implied_tag(rec, at_estimate), estimated, atol=1e-4)
    np.testing.assert_allclose(implied_tag(rec, at_truth), true, atol=1e-4)
    # the estimator's error: what the network must learn to live with in flight
    apart = np.median(np.linalg.norm(estimated - true, axis=1))
    assert 0.02 < apart < 0.5


def test_an_unknown_feature_source_is_refused(flight) -> None:
    rec, latency = flight
    with pytest.raises(ValueError, match="features_from"):
        flight_samples(rec, FLIGHT, latency, features_from="oracle")


def test_the_features_pose_is_the_recipes_estimator_without_the_anchor_weighting(data_dir: Path) -> None:
    """The recipe's features come from the estimator its networks were judged with
    (RECIPE_ESTIMATOR: no blocked-anchor weighting), not from whatever the estimator ships
    with: on a TDOA3 flight with a shelf in the room the two differ."""
    from rig.bias.config import RECIPE_ESTIMATOR
    from rig.estimator.evaluate import estimator_config, replay

    rec = load_any(data_dir / "flights" / "0426-traj6")
    t = rec.tdoa.t[(rec.tdoa.t > rec.truth.t[0] + 10) & (rec.tdoa.t < rec.truth.t[-1] - 10)]
    position, _ = estimated_poses(rec, t)

    def replayed(**params) -> np.ndarray:
        run = replay(rec, *estimator_config(use_nn=False, **params))
        return metrics.interpolate(t, run.t, run.position)

    np.testing.assert_array_equal(position, replayed(**RECIPE_ESTIMATOR))
    assert np.abs(position - replayed()).max() > 0.01
