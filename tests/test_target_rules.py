"""The per-Gaussian rule language of the real-capture ground truth, against hand-made
cases and independent references (``colorsys`` for HSV)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from divas_engine.evaluation.target_rules import GaussianFeatures, evaluate_rule


def _features(points, opacity=None, rgb=None) -> GaussianFeatures:
    p = np.asarray(points, float)
    n = len(p)
    return GaussianFeatures(
        p,
        np.full(n, 0.5) if opacity is None else np.asarray(opacity, float),
        np.full((n, 3), 0.5) if rgb is None else np.asarray(rgb, float),
    )


def test_geometric_leaves():
    f = _features([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0.5, 0.5, 3.0], [0, 0, 1.05]])
    np.testing.assert_array_equal(
        evaluate_rule({"sphere": {"center": [0, 0, 0], "radius": 1.0}}, f),
        [True, True, False, False, False],
    )
    # oriented box rotated 45° about z: half sizes along the rotated axes
    s = np.sqrt(0.5)
    box = {
        "box": {
            "center": [0, 0, 0],
            "axes": [[s, s, 0], [-s, s, 0], [0, 0, 1]],
            "half": [1.5, 0.2, 2],
        }
    }
    np.testing.assert_array_equal(evaluate_rule(box, f), [True, False, False, False, True])
    # half-space n·x >= d with a non-unit normal (normalised)
    np.testing.assert_array_equal(
        evaluate_rule({"halfspace": {"normal": [0, 0, 2.0], "offset": 1.0}}, f),
        [False, False, False, True, True],
    )
    cyl = {"cylinder": {"p0": [0, 0, -1], "p1": [0, 0, 2], "radius": 0.6}}
    np.testing.assert_array_equal(evaluate_rule(cyl, f), [True, False, False, False, True])
    ell = {
        "ellipsoid": {
            "center": [0, 0, 0],
            "axes": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
            "radii": [1, 2, 1],
        }
    }
    np.testing.assert_array_equal(evaluate_rule(ell, f), [True, True, True, False, False])


def test_colour_and_opacity_leaves_match_colorsys():
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (500, 3))
    f = _features(np.zeros((500, 3)), rng.uniform(0, 1, 500), rgb)
    ref = np.array([colorsys.rgb_to_hsv(*c) for c in rgb])
    ref[:, 0] *= 360.0
    np.testing.assert_allclose(f.hsv[:, 1:], ref[:, 1:], atol=1e-12)
    dh = np.abs(f.hsv[:, 0] - ref[:, 0])
    assert np.all(np.minimum(dh, 360 - dh) < 1e-9)
    rule = {"hsv": {"min": [20, 0.3, 0.2], "max": [60, 1, 0.9]}}
    want = (ref[:, 0] >= 20) & (ref[:, 0] <= 60) & (ref[:, 1] >= 0.3) & (ref[:, 2] >= 0.2)
    want &= ref[:, 2] <= 0.9
    np.testing.assert_array_equal(evaluate_rule(rule, f), want)
    # a hue range through 0° (reds)
    wrap = evaluate_rule({"hsv": {"min": [340, 0, 0], "max": [20, 1, 1]}}, f)
    np.testing.assert_array_equal(wrap, (ref[:, 0] >= 340) | (ref[:, 0] <= 20))
    op = evaluate_rule({"opacity": {"min": 0.25}}, f)
    np.testing.assert_array_equal(op, f.opacities >= 0.25)


def test_nodes_and_errors():
    f = _features([[0, 0, 0], [2, 0, 0]], opacity=[0.9, 0.1])
    a = {"sphere": {"center": [0, 0, 0], "radius": 1}}
    b = {"opacity": {"max": 0.5}}
    np.testing.assert_array_equal(evaluate_rule({"or": [a, b]}, f), [True, True])
    np.testing.assert_array_equal(evaluate_rule({"and": [a, b]}, f), [False, False])
    np.testing.assert_array_equal(evaluate_rule({"not": a}, f), [False, True])
    np.testing.assert_array_equal(evaluate_rule({"all": True}, f), [True, True])
    for bad in (
        {"sphere": {"centre": [0, 0, 0], "radius": 1}},  # typo
        {"spheer": {}},
        {"and": []},
        {"sphere": {"center": [0, 0], "radius": 1}},
        {"a": 1, "b": 2},
    ):
        with pytest.raises(ValueError):
            evaluate_rule(bad, f)
