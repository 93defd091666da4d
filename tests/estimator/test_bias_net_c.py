"""C derivative checks, and the C bias features / network against hand-computed values."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rig.estimator import native
from rig.estimator.bias_net import ANCHORS, INPUTS, LINK_A, LINK_B, BiasNet, identity_probe_net, shape
from rig.estimator.native import ESTIMATOR_DIR

LEVEL = [0.0, 0.0, 0.0, 1.0]
UPSIDE_DOWN = Rotation.from_euler("x", 180, degrees=True).as_quat()


def test_c_jacobians_and_weights_match_finite_differences() -> None:
    proc = subprocess.run(["make", "-s", "-C", str(ESTIMATOR_DIR), "check"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "ok: 0 failure(s)" in proc.stdout


def test_features_of_an_anchor_straight_above() -> None:
    f = native.features([0, 0, 1], LEVEL, [0, 0, 3], LEVEL, [2, 0, 1], LEVEL)
    np.testing.assert_allclose(f[:6], [0, 0, 2, 2, 0, 0], atol=1e-6)
    assert f[10] == pytest.approx(-np.pi / 2, abs=2e-5)   # tag seen straight below anchor A
    assert f[12] == pytest.approx(np.pi / 2, abs=2e-5)    # anchor A seen straight above the tag
    assert f[9] == pytest.approx(0.0, abs=2e-5) and f[13] == pytest.approx(0.0, abs=2e-5)  # B ahead, level


def test_features_of_an_anchor_behind_the_tag() -> None:
    f = native.features([0, 0, 1], LEVEL, [-2, 0, 1], LEVEL, [0, 2, 1], LEVEL)
    assert abs(f[8]) == pytest.approx(np.pi, abs=2e-5)   # anchor A behind: azimuth ±180°
    assert f[12] == pytest.approx(0.0, abs=2e-5)
    assert f[9] == pytest.approx(np.pi / 2, abs=2e-5)    # anchor B to the left
    assert f[6] == pytest.approx(0.0, abs=2e-5)           # tag in front of anchor A (its +x)


def test_features_of_an_upside_down_anchor() -> None:
    # A ceiling anchor mounted upside down sees a tag below it as "above" in its own frame.
    f = native.features([0, 0, 1], LEVEL, [0, 0, 3], UPSIDE_DOWN, [2, 0, 1], LEVEL)
    assert f[10] == pytest.approx(np.pi / 2, abs=2e-5)


def test_features_follow_the_tag_tilt_but_not_its_heading() -> None:
    # Heading is unobservable for the estimator, so it must not change a feature ...
    yawed = Rotation.from_euler("z", 90, degrees=True).as_quat()
    level = native.features([0, 0, 1], LEVEL, [2, 0, 1], LEVEL, [0, 2, 1], LEVEL)
    assert native.features([0, 0, 1], yawed, [2, 0, 1], LEVEL, [0, 2, 1], LEVEL) == pytest.approx(level, abs=1e-6)
    # ... while tilt does: pitched nose-down by 30 degrees, an anchor ahead at the tag's
    # height appears 30 degrees above the body's x-y plane (and straight ahead).
    pitched = Rotation.from_euler("y", 30, degrees=True).as_quat()
    f = native.features([0, 0, 1], pitched, [2, 0, 1], LEVEL, [0, 2, 1], LEVEL)
    assert f[12] == pytest.approx(np.radians(30), abs=2e-5)
    assert f[8] == pytest.approx(0.0, abs=2e-5)
    # A tilt about a yawed axis is the same tilt: yaw then pitch equals pitch alone in the features.
    yaw_then_pitch = (Rotation.from_euler("z", 40, degrees=True) * Rotation.from_euler("y", 30, degrees=True))
    g = native.features([0, 0, 1], yaw_then_pitch.as_quat(), [2, 0, 1], LEVEL, [0, 2, 1], LEVEL)
    tilt_only = Rotation.from_rotvec(np.cross([0, 0, 1], yaw_then_pitch.as_matrix()[:, 2]) /
                                     np.linalg.norm(np.cross([0, 0, 1], yaw_then_pitch.as_matrix()[:, 2]))
                                     * np.radians(30))
    h = native.features([0, 0, 1], tilt_only.as_quat(), [2, 0, 1], LEVEL, [0, 2, 1], LEVEL)
    assert g == pytest.approx(h, abs=1e-5)


def test_probe_network_output_is_computable_by_hand() -> None:
    net = identity_probe_net(feature=2, gain=0.5, offset=0.01)
    packed = net.pack()
    for z in (-1.0, 0.0, 0.3, 2.0):
        features = np.zeros(INPUTS)
        features[2] = z
        assert native.predict_bias(packed, features) == pytest.approx(0.5 * max(z, 0.0) + 0.01, abs=1e-6)


def test_the_link_form_is_the_difference_of_the_two_links_biases() -> None:
    """Link bias = 0.5 relu(the link's anchor-minus-tag z): a measurement between an anchor
    2 m above the tag (B) and one level with it (A) reads 0.5 × 2 − 0 = 1 m; swapped, −1 m."""
    packed = identity_probe_net(feature=2, gain=0.5, form="link").pack()
    features = np.zeros(INPUTS)
    features[LINK_B[2]] = 2.0
    assert native.predict_bias(packed, features) == pytest.approx(1.0, abs=1e-6)
    features[LINK_A[2]], features[LINK_B[2]] = 2.0, 0.0
    assert native.predict_bias(packed, features) == pytest.approx(-1.0, abs=1e-6)
    features[LINK_B[2]] = 2.0        # the same link bias on both sides cancels
    assert native.predict_bias(packed, features) == pytest.approx(0.0, abs=1e-6)


def test_each_anchors_offset_enters_the_link_bias_and_an_unknown_id_has_none() -> None:
    """TDOA bias = g(B) + d[B] − g(A) − d[A]: with g zero, a measurement from anchor 3 to
    anchor 5 reads d[5] − d[3]; an id beyond the table (or an unseen anchor) adds nothing."""
    offsets = np.zeros(ANCHORS)
    offsets[3], offsets[5] = -0.1, 0.25
    net = identity_probe_net(feature=2, gain=0.0, form="link")
    net.anchor_offset = offsets
    packed = BiasNet.from_json(net.to_json()).pack()     # through the saved form, as shipped
    features = np.zeros(INPUTS)
    assert native.predict_bias(packed, features, 3, 5) == pytest.approx(0.35, abs=1e-6)
    assert native.predict_bias(packed, features, 5, 3) == pytest.approx(-0.35, abs=1e-6)
    assert native.predict_bias(packed, features, 3, 200) == pytest.approx(0.1, abs=1e-6)
    assert BiasNet.from_json(net.to_json()).predict(features, [3, 3], [5, 200]) == pytest.approx([0.35, 0.1])
    with pytest.raises(ValueError, match="anchor ids"):
        BiasNet.from_json(net.to_json()).predict(features)


@pytest.mark.parametrize("form", ["pair", "link"])
def test_a_measurement_with_an_anchor_the_model_never_saw_is_not_corrected(form: str) -> None:
    """In C and in Python, through the saved form: a pair of anchors it was trained on is
    corrected, a pair with another anchor (or an id beyond the table) is left alone."""
    net = identity_probe_net(feature=2, gain=1.0, form=form)     # link form: link feature 2 of A and of B
    net.anchors = [0, 1, 2, 3, 5]
    saved = BiasNet.from_json(net.to_json())
    assert saved.anchors == [0, 1, 2, 3, 5] and saved.anchor_mask == 0b101111
    packed = saved.pack()
    features = np.zeros(INPUTS)
    features[LINK_B[2] if form == "link" else 2] = 0.5
    pairs = [(0, 5), (3, 1), (0, 4), (7, 2), (6, 6), (1, 200)]
    expected = [0.5, 0.5, 0.0, 0.0, 0.0, 0.0]
    assert [native.predict_bias(packed, features, a, b) for a, b in pairs] == pytest.approx(expected, abs=1e-6)
    ids_a, ids_b = zip(*pairs)
    assert saved.predict(np.tile(features, (len(pairs), 1)), ids_a, ids_b) == pytest.approx(expected)
    with pytest.raises(ValueError, match="anchor ids"):
        saved.predict(features)
    with pytest.raises(ValueError, match="ids 0..15"):
        BiasNet.from_json({**net.to_json(), "anchors": [3, 16]})
    assert BiasNet.from_json({k: v for k, v in net.to_json().items() if k != "anchors"}).pack()["anchors"] == \
        0xFFFFFFFF                                   # a model saved before: every anchor


@pytest.mark.parametrize("form", ["pair", "link"])
def test_c_and_python_inference_agree_to_float32_precision(form: str) -> None:
    rng = np.random.default_rng(0)
    n_in, hidden = shape(form)
    shapes = [(hidden, n_in), (hidden, hidden), (hidden, hidden), (1, hidden)]
    anchors = np.random.default_rng(1)        # apart, so the network's draws stay as they were
    offsets = anchors.normal(0, 0.1, ANCHORS) if form == "link" else None
    net = BiasNet([rng.normal(0, 0.4, s) for s in shapes], [rng.normal(0, 0.1, s[0]) for s in shapes],
                  rng.normal(0, 1, n_in), rng.uniform(0.5, 2, n_in), 0.2, -0.01 if form == "pair" else 0.0, form,
                  offsets)
    reference = net.quantized()
    packed = net.pack()
    x = rng.normal(0, 2, (200, INPUTS))
    ids = anchors.integers(0, ANCHORS, (200, 2))
    c_out = np.array([native.predict_bias(packed, row, a, b) for row, (a, b) in zip(x, ids)])
    py_out = reference.predict(x.astype(np.float32).astype(float), ids[:, 0], ids[:, 1])
    np.testing.assert_allclose(c_out, py_out, rtol=1e-4, atol=1e-5)
    # and the int8 quantisation itself stays close to the float network (RMS within 2 %)
    exact = net.predict(x, ids[:, 0], ids[:, 1])
    assert np.sqrt(np.mean((exact - py_out) ** 2)) < 0.02 * np.std(exact)
