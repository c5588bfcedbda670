"""graph3d's scene-only work made once per scene: every primitive's
colour and κ computed by the segmenter's warm-up (:meth:`ScenePrimitives.cache_features`)
give the same features, voxel graphs, cuts, masks and selections as computing them from
the scene's arrays in each cut — after a negative click and after an undone click too;
and the normals' column-wise arithmetic is the plain expressions' bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.segment.graph3d import Graph3DSegmenter
from divas_engine.segment.graph3d.config import Graph3DConfig
from divas_engine.segment.graph3d.primitives import ScenePrimitives
from divas_engine.segment.graph3d.voxel_graph import build_voxel_graph
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene
from tests.test_graph3d_lean import UP, _clicks, _same_graph, _scene, row_selections
from tests.test_graph3d_prefetch import _on_object


@pytest.fixture(scope="module", params=["gs3d", "gs2d", "boxes"])
def scene(request):
    return _scene(request.param)


@pytest.mark.parametrize("floor", ["all", "some"])
def test_cached_features_are_the_rows_features(scene, floor):
    """With the cache, ``lab_of`` / ``normals_of`` / ``kappa_of`` of any rows (sorted,
    shuffled, repeated, a mask, none, in blocks that do not divide the scene) equal the
    per-row computation bit for bit; the cache holds 12 bytes a primitive (16 with κ)."""
    op = scene.opacities
    cut = float(op.min()) if floor == "all" else float(np.quantile(op, 0.3))
    prims = ScenePrimitives.from_scene(scene, cut, UP)
    m = len(prims)
    rows_sets = row_selections(m, seed=2)
    want = [(prims.lab_of(r), prims.normals_of(r), prims.kappa_of(r)) for r in rows_sets]
    assert prims.features is None
    held = prims.cache_features(block=997)
    kap = scene.scale_n is not None
    assert held == m * (16 if kap else 12) and (prims.features[1] is not None) == kap
    for r, (lab, nrm, k) in zip(rows_sets, want, strict=True):
        for got, ref in ((prims.lab_of(r), lab), (prims.normals_of(r), nrm)):
            assert got.dtype == ref.dtype and np.array_equal(
                got.view(np.uint32), ref.view(np.uint32)
            )
        got = prims.kappa_of(r)
        assert (got is None) == (k is None) and (k is None or np.array_equal(got, k))
    prims.drop_features()
    assert prims.features is None and np.array_equal(prims.lab_of(rows_sets[0]), want[0][0])


def test_voxel_graphs_are_the_same_with_the_cache(scene):
    """The voxel graph of several regions (small and large, 3DGS extents included) is the
    same with the features cached and computed per cut."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(scene, cfg.min_opacity, UP)
    regions = _clicks(prims)
    plain = [build_voxel_graph(prims, c, r, cfg) for c, r in regions]
    prims.cache_features()
    for (c, r), g in zip(regions, plain, strict=True):
        cached = build_voxel_graph(prims, c, r, cfg)
        _same_graph(cached, g)
        for f in ("up_height", "up_dot"):
            a, b = getattr(cached, f), getattr(g, f)
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))


@pytest.fixture(scope="module")
def plant():
    return generate_scene("plant", None, size=20_000, seed=0)


def _loop(sc, cache: bool, monkeypatch, *, negative: bool, undo_first: bool):
    monkeypatch.setattr(Graph3DSegmenter, "cache_features", cache)
    seg = Graph3DSegmenter()
    s = Session.open(sc.scene, sc.cameras, SessionConfig(render_scale=0.5), seg, "cpu")
    assert s.wait_warm_up(120)
    assert (seg.prims.features is not None) == cache  # the warm-up made them (or not)
    if negative:
        s.click(*_on_object(s, sc, 1), positive=False)
    if undo_first:
        s.history.record("start")
        v0 = s.click(*_on_object(s, sc, 2))
        s.prompt(v0)
        s.accept(v0)
        s.history.record("accept")
        s.history.undo()
    v = s.click(*_on_object(s, sc, 0))
    prev = s.prompt(v)
    res = s.accept(v)
    out = (prev.masks, prev.scores, prev.mask, seg.last_cut.selected, seg.last_cut.scores)
    out += (seg.last_cut.cut.potential, res.selection.copy())
    s.close()
    return out


@pytest.mark.parametrize("negative, undo_first", [(False, False), (True, False), (False, True)])
def test_session_results_are_the_same_with_the_cache(plant, monkeypatch, negative, undo_first):
    """Masks, scores, the cut's selections and potential and the accepted selection of a
    session are equal with the warm-up's feature cache and without it."""
    on = _loop(plant, True, monkeypatch, negative=negative, undo_first=undo_first)
    off = _loop(plant, False, monkeypatch, negative=negative, undo_first=undo_first)
    for a, b in zip(on, off, strict=True):
        assert np.array_equal(a, b)
    assert on[-1].any()  # something was selected


def test_normals_are_the_plain_expressions(scene):
    """``normals_of``'s column-wise float32 arithmetic equals the expressions
    ``2(xz + wy), 2(yz − wx), 1 − 2(xx + yy)`` on the quaternion rows bit for bit, as a
    C-ordered ``[n,3]`` (how the voxel graph's BLAS products read it); so does the
    float64 quaternions' path."""
    prims = ScenePrimitives.from_scene(scene, 0.0, UP)
    rng = np.random.default_rng(7)
    for rows in (np.arange(len(prims)), rng.integers(0, len(prims), 333), np.zeros(0, int)):
        q = scene.quats[prims.rows_of(rows)]
        w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        want = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], 1)
        got = prims.normals_of(rows)
        assert got.dtype == np.float32 and got.flags["C_CONTIGUOUS"]
        assert np.array_equal(got.view(np.uint32), want.astype(np.float32).view(np.uint32))
