"""The ground search converts only the rows it uses to
float64 (no ``[N,3]`` float64 copies of the scene's centres); the planes are the same as
converting everything first. The reference here is the earlier code's first step — all
rows in float64, the in-range rows, the seeded sample — fed to the search, which then
keeps every row and samples nothing: the rest of the search is the same code."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.views.config import ViewConfig
from divas_engine.views.ground import ground_candidates


def _old_sample(points, weights, center, r_fg, cfg, seed=0):
    """The earlier code's in-range filter and sample (all rows in float64 first)."""
    c = np.asarray(center, np.float64)
    p = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    keep = np.linalg.norm(p - c, axis=1) <= r_fg
    p, w = p[keep], w[keep]
    if len(p) > cfg.ground_points:
        idx = np.random.default_rng(seed).choice(len(p), cfg.ground_points, replace=False)
        p, w = p[np.sort(idx)], w[np.sort(idx)]
    return p, w


def _scene(seed, n):
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-2, 2, (n // 2, 2)), rng.normal(0, 0.01, n // 2)]
    blob = rng.normal([0, 0, 0.8], 0.3, (n - n // 2, 3))
    p = np.vstack([floor, blob]).astype(np.float32)
    p[:3] = np.nan  # never in range
    return p, rng.uniform(0.05, 1.0, n).astype(np.float32)


def _same(a, b):
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.normal, y.normal)
        for f in ("offset", "support", "sharpness", "coverage", "axis_deg", "below"):
            assert getattr(x, f) == getattr(y, f), f


@pytest.mark.parametrize("n", [3000, 700_000])  # fewer / more rows than the sample
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lean_ground_search_equals_converting_everything(n, dtype):
    cfg = ViewConfig(ground_points=2000, ground_directions=300)
    p, w = _scene(n, n)
    p, w = p.astype(dtype), w.astype(dtype)
    center, r_fg = np.array([0.1, -0.2, 0.3]), 1.9
    ps, ws = _old_sample(p, w, center, r_fg, cfg)
    assert len(ps) == min(cfg.ground_points, len(ps)) and len(ps) < n - 3
    got = ground_candidates(p, w, center, r_fg, cfg)
    ref = ground_candidates(ps, ws, center, r_fg, cfg)  # in range, no sample: as given
    _same(got, ref)
    # the float32 scene arrays and their float64 copies give the same planes
    _same(got, ground_candidates(p.astype(np.float64), w.astype(np.float64), center, r_fg, cfg))


def test_graph3d_primitives_share_the_scenes_arrays_when_all_are_kept(tmp_path):
    """Every surfel above the opacity floor: the graph's positions and masses are the
    scene's own float32 arrays (no copy); with some left out, a copy of those rows."""
    from divas_engine.segment.graph3d.primitives import ScenePrimitives
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("plant", tmp_path, size=4000, seed=3, sh_degree=1).scene
    floor = float(sc.opacities.min())
    every = ScenePrimitives.from_scene(sc, min_opacity=floor, up=np.array([0.0, 0.0, 1.0]))
    assert len(every) == len(sc)
    assert np.shares_memory(every.points, sc.means) and np.shares_memory(every.mass, sc.opacities)
    assert every.index is None  # primitive i is surfel i
    np.testing.assert_array_equal(every.rows_of(np.arange(len(every))), np.arange(len(sc)))
    cut = float(np.median(sc.opacities))
    some = ScenePrimitives.from_scene(sc, min_opacity=cut, up=np.array([0.0, 0.0, 1.0]))
    assert 0 < len(some) < len(sc) and not np.shares_memory(some.points, sc.means)
    np.testing.assert_array_equal(some.points, sc.means[some.index])
    np.testing.assert_array_equal(some.mass, sc.opacities[some.index])
    # the rows both keep have the same features
    both = np.flatnonzero(np.isin(np.arange(len(sc)), some.index))
    mine = np.arange(len(some))
    np.testing.assert_array_equal(every.points[both], some.points)
    np.testing.assert_array_equal(every.mass[both], some.mass)
    for f in ("lab_of", "normals_of", "kappa_of", "reach_of", "sigma_of"):
        np.testing.assert_array_equal(getattr(every, f)(both), getattr(some, f)(mine))
