"""Depth weighting (paper Sec. 3.4): eq:nerf-depthweight and eq:depthband / eq:gs-bandpass,
checked on small hand-computed arrays."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.segment.depth_weighting import (
    GsBandpassConfig,
    NerfDepthWeightConfig,
    apply_gs_bandpass,
    apply_nerf_depth_weight,
    depth_band,
    gs_bandpass_weight,
    nerf_depth_weight,
)


# ----------------------------------------------------------------------------- NeRF
def test_nerf_minmax_weight_hand_values():
    d = np.array([[1.0, 2.0], [3.0, 5.0]])
    # Ẑ = (D − 1) / 4 → [[0, .25], [.5, 1]]
    np.testing.assert_allclose(nerf_depth_weight(d), [[1.0, 0.75], [0.5, 0.0]])
    m = np.array([[0.8, 0.8], [1.0, 1.0]], np.float32)
    out = apply_nerf_depth_weight(m, d)
    np.testing.assert_allclose(out, [[0.8, 0.6], [0.5, 0.0]], rtol=1e-6)
    assert out.dtype == np.float32


def test_nerf_min_max_over_valid_pixels_only():
    d = np.array([[0.0, 2.0], [np.nan, 4.0], [np.inf, 3.0]])
    np.testing.assert_allclose(nerf_depth_weight(d), [[0.0, 1.0], [0.0, 0.0], [0.0, 0.5]])
    # a caller mask (e.g. accumulated opacity) also excludes pixels from min/max
    valid = np.array([[True, True], [True, False], [True, True]])
    np.testing.assert_allclose(nerf_depth_weight(d, valid), [[0, 1], [0, 0], [0, 0]])
    cfg = NerfDepthWeightConfig(invalid_weight=1.0)
    assert nerf_depth_weight(d, config=cfg)[0, 0] == 1.0


def test_nerf_floored_denominator():
    np.testing.assert_allclose(nerf_depth_weight(np.full((2, 3), 3.0)), 1.0)  # 0/floor, not 0/0
    d = np.array([[3.0, 3.0 + 1e-7]])
    np.testing.assert_allclose(nerf_depth_weight(d), [[1.0, 0.9]], rtol=1e-5)  # 1e-7 / 1e-6
    np.testing.assert_allclose(
        nerf_depth_weight(d, config=NerfDepthWeightConfig(denom_floor=1e-9)),
        [[1.0, 0.0]],
        atol=1e-6,
    )
    assert not nerf_depth_weight(np.zeros((2, 2))).any()  # no valid pixel at all
    with pytest.raises(ValueError, match="shape"):
        apply_nerf_depth_weight(np.ones((2, 2)), np.ones((3, 2)))


# ----------------------------------------------------------------------------- 2DGS
D = np.array(
    [[1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 2.0, 6.0], [1.0, 2.0, 2.5, 6.0], [10.0, 10.0, 10.0, 0.0]]
)  # [3,3] = 0: no surface


def test_band_from_positive_prompts_and_view_centre():
    # positive (1.5, 1.5) → pixel row 1 col 1 = 2.0; centre (w/2, h/2) = (2, 2) → 2.5;
    # the negative at (3.5, 0.5) (depth 1.0) is not part of 𝒟_s
    band = depth_band(D, np.array([[1.5, 1.5], [3.5, 0.5]]), np.array([1, 0]))
    assert (band.d_min, band.d_max) == (2.0, 2.5)
    np.testing.assert_array_equal(np.sort(band.samples), [2.0, 2.5])
    # P98 of the 15 valid depths: position 0.98·14 = 13.72 between sorted[13] = sorted[14] = 10
    assert band.d_far == pytest.approx(10.0)
    band = depth_band(
        D, np.array([[1.5, 1.5]]), np.array([1]), config=GsBandpassConfig(include_view_center=False)
    )
    assert (band.d_min, band.d_max) == (2.0, 2.0)


def test_bandpass_weight_hand_values():
    m = np.full(D.shape, 0.5, np.float32)
    out, band = apply_gs_bandpass(m, D, np.array([[1.5, 1.5]]), np.array([1]))
    # denominator d_far − d_max = 10 − 2.5 = 7.5
    w = np.array(
        [
            [1 - 1 / 7.5] * 4,
            [1 - 1 / 7.5, 1.0, 1.0, 1 - 3.5 / 7.5],
            [1 - 1 / 7.5, 1.0, 1.0, 1 - 3.5 / 7.5],
            [0.0, 0.0, 0.0, 0.0],
        ]
    )  # 10 = d_far → 0; D_med = 0 is invalid → 0
    np.testing.assert_allclose(out, 0.5 * w, rtol=1e-6)
    assert band.denominator == pytest.approx(7.5)


def test_band_spanning_to_far_edge_uses_floor():
    # clicking the far wall: d_max = 10 = d_far → denominator floored at 1e-6,
    # so the weight is an indicator
    out, band = apply_gs_bandpass(np.ones(D.shape), D, np.array([[0.5, 3.5]]), np.array([1]))
    assert (band.d_min, band.d_max, band.d_far) == (2.5, 10.0, 10.0)
    inside = (D >= 2.5) & (D <= 10.0)
    np.testing.assert_array_equal(out, inside.astype(np.float32))
    # d_max beyond P98 (negative denominator) is floored the same way
    d = np.ones((10, 10))
    d[0, 0] = 100.0  # P98 of 99 ones and one 100 is 1
    band = depth_band(
        d, np.array([[0.5, 0.5]]), np.array([1]), config=GsBandpassConfig(include_view_center=False)
    )
    assert band.d_far == pytest.approx(1.0) and band.denominator < 0
    w = gs_bandpass_weight(d, band)
    assert w[0, 0] == 1.0 and not w[1:, :].any() and not w[0, 1:].any()


def test_bandpass_without_valid_sample_and_valid_mask():
    d = np.zeros((4, 4))
    d[0, 0] = 3.0
    m = np.full((4, 4), 0.7, np.float32)
    out, band = apply_gs_bandpass(m, d, np.array([[2.5, 2.5]]), np.array([1]))
    assert band is None
    np.testing.assert_array_equal(out, m)
    # a caller validity mask removes a sample from 𝒟_s and from the percentile
    valid = np.ones(D.shape, bool)
    valid[2, 2] = False
    band = depth_band(D, np.array([[1.5, 1.5]]), np.array([1]), valid)
    assert (band.d_min, band.d_max) == (2.0, 2.0)
    assert gs_bandpass_weight(D, band, valid)[2, 2] == 0.0
