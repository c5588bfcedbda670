"""The completion's contribution walk on the CPU: the tile walk of
``accumulate_contributions`` that keeps per pixel only the transmittance (not the depth
tuple's state) and looks the targets' slots up in a kept ``[N]`` table. Reference: the
generic tile walk of :mod:`divas_kernels.tile_walk` (``ContribSink``; the path before this
change, still used on CUDA) — every A₁ / A₀ must be equal bit for bit, for the full pass,
target subsets, a sub-scene (``rows``), a window and a kept view binning."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from divas_engine.render import make_renderer
from divas_kernels.contrib import _accumulate, _SlotTable

from .test_completion import CPU, _ball_scene, _views
from .test_contrib_targets import _args


@pytest.fixture(scope="module")
def ball():
    scene, labels, parts = _ball_scene()
    views = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3), (-1, 0.2, -0.3), (0, 1, -0.5)])
    return scene, labels, parts, views


def _same(a, b) -> bool:
    return np.array_equal(a.a1.numpy(), b.a1.numpy()) and np.array_equal(a.a0.numpy(), b.a0.numpy())


def _targets(scene, parts, n):
    rng = np.random.default_rng(5)
    means = np.asarray(scene.means)
    surf = np.arange(parts["surface"].start, parts["surface"].stop)
    return {
        "cap": surf[means[surf, 0] > 0.4],
        "random": np.sort(rng.choice(n, 300, replace=False)),
        "one": np.array([surf[len(surf) // 3]]),
        "all": np.arange(n),
    }


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_transmittance_walk_equals_the_generic_walk(ball, threads):
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    buf, n = r.surfel_buffers, len(scene)
    for v in views:
        st = r.config.raster_settings(v.camera)
        st.threads = threads
        ref = _accumulate(buf, *_args(v), st, None, generic=True)
        got = _accumulate(buf, *_args(v), st, None)
        assert got.stats["pairs"] == ref.stats["pairs"] > 0
        assert _same(got, ref), v.name
        a1 = ref.a1.numpy()
        assert (a1 > 0).sum() > 50 and (ref.a0.numpy() > 0).sum() > 50  # both sides seen
        for name, t in _targets(scene, parts, n).items():
            g = _accumulate(buf, *_args(v), st, None, targets=t, generic=True)
            f = _accumulate(buf, *_args(v), st, None, targets=t)
            assert _same(f, g), (name, v.name)
            assert f.stats["walked"] == g.stats["walked"]
            assert np.array_equal(f.a1.numpy(), a1[t]), (name, v.name)


def test_transmittance_walk_from_a_kept_binning_a_part_and_a_window(ball):
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    buf, n = r.surfel_buffers, len(scene)
    cap = _targets(scene, parts, n)["cap"]
    blocks, reach = r.sparse_index()
    means = buf.means.numpy()
    for v in views:
        st = r.config.raster_settings(v.camera)
        r.render(v.camera)
        kept = r.kept_binning(v.camera)
        assert kept is not None
        for t in (None, cap):
            ref = _accumulate(buf, *_args(v), st, kept, targets=t, generic=True)
            assert ref.stats["reused"]
            assert _same(_accumulate(buf, *_args(v), st, kept, targets=t), ref)
        sub = blocks.near(v.camera, means[cap], reach[cap], r._margin_px)
        at = np.searchsorted(sub, cap)
        ref = _accumulate(buf, *_args(v), st, None, rows=sub, targets=at, generic=True)
        assert _same(_accumulate(buf, *_args(v), st, None, rows=sub, targets=at), ref)
        W, H = v.camera.width, v.camera.height
        win = (W // 5, H // 4, W - W // 6, H - H // 5)
        ref = _accumulate(buf, *_args(v), st, None, window=win, generic=True)
        got = _accumulate(buf, *_args(v), st, None, window=win)
        assert _same(got, ref) and (ref.a1.numpy() > 0).any()


def test_slot_table_is_reset_and_private_to_a_pass(ball):
    """The kept slot table holds no target of an earlier pass, and a pass that finds it
    in use (another thread) makes its own: results equal fresh passes."""
    scene, labels, parts, views = ball
    r = make_renderer(scene, device=CPU)
    buf, n = r.surfel_buffers, len(scene)
    v = views[0]
    st = r.config.raster_settings(v.camera)
    full = _accumulate(buf, *_args(v), st, None, generic=True)
    f1, f0 = full.a1.numpy(), full.a0.numpy()
    sets = list(_targets(scene, parts, n).values())
    for t in sets + sets[::-1]:
        out = _accumulate(buf, *_args(v), st, None, targets=t)
        assert np.array_equal(out.a1.numpy(), f1[t]) and np.array_equal(out.a0.numpy(), f0[t])
    kept = _SlotTable._kept.get(("cpu", n))
    assert kept is not None and (kept == -1).all()
    # held by "another thread": this pass must not use (or reset) the kept table
    table = _SlotTable.take(n, sets[2], buf.device)
    assert table.kept
    try:
        out = _accumulate(buf, *_args(v), st, None, targets=sets[0])
        assert np.array_equal(out.a1.numpy(), f1[sets[0]])
        assert (kept[sets[2]] == np.arange(len(sets[2]))).all()
    finally:
        table.give_back()
    assert (kept == -1).all()
    errors = []

    def worker(t):
        for _ in range(3):
            o = _accumulate(buf, *_args(v), st, None, targets=t)
            if not np.array_equal(o.a0.numpy(), f0[t]):
                errors.append(len(t))

    th = [threading.Thread(target=worker, args=(t,)) for t in sets[:3]]
    for x in th:
        x.start()
    for x in th:
        x.join()
    assert not errors and (kept == -1).all()
