"""The sparse value render's working arrays come from buffers kept across calls
(:mod:`divas_kernels.scratch`: no fresh pages to fault in per mask render):
the images are the dense render's bit for bit, call after call, as the row sets grow and
shrink; a repeated call allocates nothing new; nothing that outlives a call (a kept
binning) may come from a pool."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from divas_engine.camera import Camera
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_kernels import ScratchPool, rasterize_surfels
from divas_kernels.scratch import scratch_active, scratch_empty
from tests.reference_render import random_surfel_scene
from tests.test_render_sparse import _dense


@pytest.fixture(scope="module")
def case():
    sc = random_surfel_scene(4000, seed=7, z_range=(0.5, 6.0), scale_range=(0.01, 0.25))
    cam = Camera.look_at(
        [0.1, -0.2, -0.4], [0, 0, 4], [0, -1, 0], width=90, height=70, fx=75, cx=45.2, cy=34.6
    )
    return sc, cam


def test_repeated_sparse_renders_are_the_dense_renders(case):
    sc, cam = case
    r = SurfelRenderer(sc, device="cpu")
    assert not r.scratch_sparse  # off by default (the add-on switches it on at 3M)
    r.scratch_sparse = True
    ref = SurfelRenderer(sc, device="cpu")  # dense renders: no pool in play
    rng = np.random.default_rng(3)
    sizes = []
    for frac, c in [(0.02, 1), (0.4, 3), (0.05, 2), (0.6, 1), (0.01, 3)]:
        rows = np.flatnonzero(rng.random(len(sc)) < frac)
        vals = rng.uniform(0.1, 1.0, (len(rows), c)).astype(np.float32)
        for cc in (cam, cam.cropped(11, 7, 50, 41)):
            got = r.render_values_sparse(cc, rows, vals)
            want = ref.render_values(cc, _dense(len(sc), rows, vals))
            assert np.abs(want).max() > 1e-4
            assert np.array_equal(got, want)
        sizes.append(r._scratch.nbytes)
    assert sizes[0] > 0 and sizes == sorted(sizes)  # grown to the largest, never shrunk
    r.clear_cache()
    assert r._scratch.nbytes == 0


def test_a_repeated_call_allocates_nothing_new(case):
    sc, cam = case
    r = SurfelRenderer(sc, device="cpu")
    r.scratch_sparse = True
    r.render(cam)
    assert r._scratch.nbytes == 0  # a view render pools nothing by default
    rows = np.arange(0, len(sc), 3)
    vals = np.linspace(0.1, 1.0, len(rows), dtype=np.float32)
    first = r.render_values_sparse(cam, rows, vals)
    held = [b.ctypes.data for b in r._scratch._buffers]
    assert len(held) > 5
    second = r.render_values_sparse(cam, rows, vals)
    assert [b.ctypes.data for b in r._scratch._buffers] == held
    assert np.array_equal(first, second) and first is not second


def test_the_pool_hands_out_distinct_buffers_in_order_and_only_in_scope():
    pool = ScratchPool()
    assert not scratch_active()
    outside = scratch_empty(1000, wp.float32, "cpu")
    with pool.active():
        assert scratch_active()
        a = scratch_empty(1000, wp.float32, "cpu")
        b = scratch_empty((10, 3), wp.vec3, "cpu")
        a.numpy()[:] = 1.0
        b.numpy()[:] = 2.0
        assert np.all(a.numpy() == 1.0) and b.shape == (10, 3)  # no overlap
        with pytest.raises(RuntimeError), pool.active():
            pass
        with pytest.raises(RuntimeError):
            pool.release()
    assert pool.nbytes >= 1000 * 4 + 30 * 12 and outside.ptr not in (a.ptr, b.ptr)
    with pool.active():  # the k-th array of a scope reuses the k-th buffer
        a2 = scratch_empty(800, wp.float32, "cpu")
        b2 = scratch_empty(20, wp.vec3, "cpu")
    assert a2.ptr == a.ptr and b2.ptr == b.ptr


def test_a_kept_binning_never_uses_a_pool(case):
    sc, cam = case
    r = SurfelRenderer(sc, device="cpu")
    with ScratchPool().active(), pytest.raises(ValueError, match="kept binning"):
        rasterize_surfels(r.surfel_buffers, *_proj(cam), keep_binning=True)


def _proj(cam: Camera) -> tuple:
    return cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height


def test_ball_bounds_in_row_blocks_are_the_one_pass_bounds(case, monkeypatch):
    """:func:`ball_pixel_bounds` in blocks of rows (small temporaries) gives the bounds
    of one pass over every row, bit for bit — and so does ``near``'s depth map."""
    from divas_engine.render import surfel_blocks as sb

    sc, cam = case
    rng = np.random.default_rng(5)
    centres = sc.means.astype(np.float64) + rng.normal(0, 0.01, sc.means.shape)
    radii = rng.uniform(0.0, 2.0, len(centres))  # some reach the camera plane
    monkeypatch.setattr(sb, "_BOUNDS_CHUNK", 1 << 30)
    whole = sb.ball_pixel_bounds(cam, centres, radii)
    r = SurfelRenderer(sc, device="cpu")
    blocks, reach = r.sparse_index()
    rows = np.flatnonzero(rng.random(len(sc)) < 0.3)
    near = blocks.near(cam, sc.means[rows], reach[rows], r._margin_px)
    monkeypatch.setattr(sb, "_BOUNDS_CHUNK", 37)
    parts = sb.ball_pixel_bounds(cam, centres, radii)
    assert whole[3].any() and whole[2].any()
    for a, b in zip(whole, parts):
        assert np.array_equal(a, b)
    assert np.array_equal(blocks.near(cam, sc.means[rows], reach[rows], r._margin_px), near)


def test_kept_binnings_survive_the_renders_that_reuse_the_pool(case):
    """RGB renders reuse the pool for what no binning keeps: a camera's kept binning,
    read after other cameras' renders refilled the pool, still gives the value render
    of a fresh renderer bit for bit, and every render equals a fresh renderer's."""
    sc, cam = case
    other = Camera.look_at(
        [0.6, 0.3, -0.2], [0, 0, 4], [0, -1, 0], width=80, height=64, fx=70, cx=40.1, cy=31.9
    )
    r = SurfelRenderer(sc, device="cpu")
    r.scratch_renders = True  # off by default (memory held between renders)
    vals = np.random.default_rng(2).uniform(0, 1, (len(sc), 2)).astype(np.float32)
    first = r.render(cam)
    assert r.kept_binning(cam) is not None and r._scratch.nbytes > 0
    for c in (other, cam.cropped(5, 5, 40, 30)):
        r.render(c)
        r.render_depth(c, scale=0.5)
    assert r.kept_binning(cam) is not None  # still kept: its value render only blends
    fresh = SurfelRenderer(sc, device="cpu")
    assert np.array_equal(r.render_values(cam, vals), fresh.render_values(cam, vals))
    again = fresh.render(cam)
    for name in ("rgb", "alpha", "D_min", "D_med", "D_max", "D_mw", "D_exp", "N_samp"):
        assert np.array_equal(getattr(first, name), getattr(again, name)), name
