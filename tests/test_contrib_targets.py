"""``accumulate_contributions(targets=…)``: the sums of a few surfels from a walk
that stops, in each tile, right after the last of them — from a kept view binning or a
fresh projection of the scene or of a part of it (``rows``). Reference: the same pass
without ``targets`` over the whole scene; each target's A₁ / A₀ must be equal bit for bit,
and the walk must really be shorter (fewer (tile, surfel) pairs walked)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from divas_engine.render import make_renderer
from divas_kernels import accumulate_contributions
from divas_kernels._launch import launch_split

from .test_completion import CPU, _ball_scene, _views


@pytest.fixture(scope="module")
def ball():
    scene, labels, parts = _ball_scene()
    views = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3), (-1, 0.2, -0.3), (0, 1, -0.5)])
    return scene, labels, parts, views


def _args(v):
    cam = v.camera
    pos = np.asarray(v.mask) >= 0.5
    return (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, pos)


def _target_sets(scene, parts, n):
    rng = np.random.default_rng(3)
    means = np.asarray(scene.means)
    surf = np.arange(parts["surface"].start, parts["surface"].stop)
    return {
        "cap": surf[means[surf, 0] > 0.4],
        "random": np.sort(rng.choice(n, 200, replace=False)),
        "one": np.array([surf[len(surf) // 2]]),
        "all": np.arange(n),
        "none": np.zeros(0, np.int64),
    }


def test_target_sums_equal_the_full_pass(ball):
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    buf, n = r.surfel_buffers, len(scene)
    shorter = 0
    for v in views:
        st = r.config.raster_settings(v.camera)
        full = accumulate_contributions(buf, *_args(v), st)
        f1, f0 = full.a1.numpy(), full.a0.numpy()
        r.render(v.camera)  # keeps the view's binning
        kept = r.kept_binning(v.camera)
        assert kept is not None
        for name, t in _target_sets(scene, parts, n).items():
            for binning in (None, kept):
                out = accumulate_contributions(buf, *_args(v), st, binning=binning, targets=t)
                assert out.stats["reused"] == (binning is not None)
                assert out.a1.shape == (len(t),), name
                assert np.array_equal(out.a1.numpy(), f1[t]), (name, v.name, binning is None)
                assert np.array_equal(out.a0.numpy(), f0[t]), (name, v.name, binning is None)
                assert out.stats["walked"] <= full.stats["pairs"]
                if name == "all":
                    # the dump slot takes nothing; the lists are cut after their last
                    # surfel at most
                    assert out.stats["walked"] == full.stats["pairs"]
                if name in ("cap", "one") and out.stats["walked"] < full.stats["pairs"]:
                    shorter += 1
                if name == "none":
                    assert out.stats["walked"] == 0
    assert shorter >= 8  # the cut walk is shorter in every view, from both sources


def test_target_sums_from_a_part_of_the_scene(ball):
    """``rows`` projects only those surfels (positions in ``rows`` index the sums and the
    targets): with every surfel the sums are the full pass's; with the surfels that can
    blend before a cap (the completion's sub-scene) the cap's sums are too."""
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    buf, n = r.surfel_buffers, len(scene)
    cap = _target_sets(scene, parts, n)["cap"]
    blocks, reach = r.sparse_index()
    means = buf.means.numpy()
    for v in views:
        st = r.config.raster_settings(v.camera)
        full = accumulate_contributions(buf, *_args(v), st)
        f1, f0 = full.a1.numpy(), full.a0.numpy()
        every = accumulate_contributions(buf, *_args(v), st, rows=np.arange(n))
        assert np.array_equal(every.a1.numpy(), f1) and np.array_equal(every.a0.numpy(), f0)
        sub = blocks.near(v.camera, means[cap], reach[cap], r._margin_px)
        assert len(sub) < n
        at = np.searchsorted(sub, cap)
        assert np.array_equal(sub[at], cap)
        out = accumulate_contributions(buf, *_args(v), st, rows=sub, targets=at)
        assert np.array_equal(out.a1.numpy(), f1[cap]) and np.array_equal(out.a0.numpy(), f0[cap])


def test_targets_must_be_ascending(ball):
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    st = r.config.raster_settings(views[0].camera)
    with pytest.raises(ValueError):
        accumulate_contributions(r.surfel_buffers, *_args(views[0]), st, targets=np.array([5, 3]))
    with pytest.raises(ValueError):
        accumulate_contributions(
            r.surfel_buffers, *_args(views[0]), st, targets=np.array([len(scene)])
        )


@wp.kernel
def _row_of_item(out: wp.array(dtype=int), rows: int, base: int, stride: int):
    i = base + wp.tid() * stride
    out[i] = base % rows


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_item_range_keeps_each_items_sub_launch(threads):
    """``launch_split(items=(a, b))`` runs items ``a … b−1`` only, each in the sub-launch
    (``base`` residue: the contribution walk's accumulator row) of the whole launch."""
    dev = wp.get_device("cpu")
    n = 23
    whole = wp.array(np.full(n, -1), dtype=int, device=dev)
    launch_split(_row_of_item, n, [whole, threads], dev, threads, "interleave")
    ref = whole.numpy()
    assert (ref >= 0).all()
    for a, b in ((0, n), (5, 6), (7, 19), (22, 30), (4, 4)):
        part = wp.array(np.full(n, -1), dtype=int, device=dev)
        launch_split(_row_of_item, n, [part, threads], dev, threads, "interleave", items=(a, b))
        got = part.numpy()
        b = min(b, n)
        assert (
            np.array_equal(got[a:b], ref[a:b]) and (got[:a] == -1).all() and (got[b:] == -1).all()
        )
    with pytest.raises(ValueError):
        launch_split(_row_of_item, n, [whole, threads], dev, threads, "chunk", items=(1, 3))
