"""A render projects only the surfels of the scene blocks that can reach its
pixel window (:meth:`SurfelBlocks.in_window`) — every channel, the kept binning's
surfel order, the value renders and the centroid views equal a render that projects
every surfel, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.render import RenderConfig
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.views.centroid_gs import GsCentroidPlanner
from divas_kernels import rasterize_surfels

from .centroid_checks import same_centroid_views
from .reference_render import random_surfel_scene


@pytest.fixture(scope="module")
def case():
    # surfels on both sides of the near plane, large and small; cameras from wide to
    # zoomed in (a zoomed view meets few blocks)
    sc = random_surfel_scene(6000, seed=7, z_range=(-0.5, 6.0), scale_range=(0.01, 0.3))
    cams = [
        Camera.look_at(
            [0.1 * k, -0.1, -0.3 + 0.8 * k],
            [0.3 * k - 0.4, 0.2, 4],
            [0, -1, 0],
            width=96,
            height=72,
            fx=80 * (1 + 2 * k),
            cx=48.3,
            cy=35.7,
        )  # fmt: skip
        for k in range(4)
    ]
    return sc, cams


class _AllRows(SurfelRenderer):
    """The reference: every surfel projected (no block culling)."""

    def _candidates(self, cam, window):
        return None


def _pair(sc, **kw):
    cfg = RenderConfig(**kw)
    culled, ref = (
        SurfelRenderer(sc, device="cpu", config=cfg),
        _AllRows(sc, device="cpu", config=cfg),
    )
    culled.sparse_index()  # built: full renders cull by blocks too
    seen = []
    plain = culled._candidates
    culled._candidates = lambda cam, w: (lambda r: (seen.append(r), r)[1])(plain(cam, w))
    return culled, ref, seen


def _same(a, b):
    for k, v in a.as_dict().items():
        assert np.array_equal(v, getattr(b, k)), k


@pytest.mark.parametrize("max_duplicates", [1 << 25, 300])
def test_block_culled_renders_are_bit_identical(case, max_duplicates):
    sc, cams = case
    culled, ref, seen = _pair(sc, max_duplicates=max_duplicates)
    v = np.random.default_rng(1).random((len(sc), 2), dtype=np.float32)
    for cam in cams:
        _same(culled.render(cam), ref.render(cam))
        a, b = culled.kept_binning(cam), ref.kept_binning(cam)
        assert a.n_visible == b.n_visible
        assert np.array_equal(a.ids.numpy()[: a.n_visible], b.ids.numpy()[: b.n_visible])
        assert np.array_equal(culled.render_values(cam, v), ref.render_values(cam, v))
        _same(culled.render(cam, scale=0.3), ref.render(cam, scale=0.3))
        h, w = int(0.5 * cam.height), int(0.5 * cam.width)
        for win in [
            (w // 4, h // 4, w // 4 + w // 2, h // 4 + h // 2),
            (0, 0, 7, 5),
            (w - 3, h - 9, w, h),
        ]:
            _same(culled.render_depth(cam, 0.5, win), ref.render_depth(cam, 0.5, win))
    used = [r for r in seen if r is not None]
    assert used and min(len(r) for r in used) < 0.5 * len(sc)  # the culling did cut


def test_rasterizer_rows_superset_is_bit_identical(case, device):
    """The kernel level, on every device: projecting a superset of the surfels a view
    keeps (ascending rows) gives the same output and the same surfel order."""
    sc, cams = case
    r = SurfelRenderer(sc, device="cpu")
    buf = SurfelRenderer(sc, device=device).surfel_buffers
    cam = cams[2]
    args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    s = r.config.raster_settings(cam)
    full = rasterize_surfels(buf, *args, s, keep_binning=True)
    vis = np.sort(full.binning.ids.numpy()[: full.binning.n_visible])
    extra = np.random.default_rng(2).choice(len(sc), len(sc) // 5, replace=False)
    rows = np.union1d(vis, extra)
    part = rasterize_surfels(buf, *args, s, keep_binning=True, rows=rows)
    for k in ("feat", "alpha", "d_min", "d_med", "d_max", "d_mw", "d_exp", "n_samp"):
        assert np.array_equal(getattr(full.out, k).numpy(), getattr(part.out, k).numpy()), k
    assert np.array_equal(full.binning.ids.numpy(), part.binning.ids.numpy())
    # not a superset (half the visible surfels left out): a different image
    missing = rasterize_surfels(buf, *args, s, rows=np.setdiff1d(rows, vis[::2]))
    assert not np.array_equal(full.out.n_samp.numpy(), missing.out.n_samp.numpy())


def test_block_culled_probes_give_the_same_centroid_views():
    from divas_engine.synthetic import generate_scene

    s = generate_scene("occluded", None, size=20_000, seed=0)
    culled, ref, seen = _pair(s.scene)
    a_pl, b_pl = GsCentroidPlanner(s.scene, culled), GsCentroidPlanner(s.scene, ref)
    clicks = 0
    for a, b in same_centroid_views(s, ref.render, a_pl, b_pl):
        _same(culled.render(a.camera), ref.render(b.camera))
        clicks += 1
    assert clicks == 12
    assert any(r is not None and len(r) < 0.5 * len(s.scene) for r in seen)


@pytest.mark.parametrize("max_duplicates", [1 << 25, 300])
def test_culling_pass_first_is_bit_identical(case, max_duplicates, device):
    """Culling as a pass of its own, then only the visible surfels projected in depth
    order (``cull_pass_min``; the render peak of a 3M scene): the same images and the
    same kept surfel order, with and without candidate rows, on every device; a view
    that sees nothing too."""
    sc, cams = case
    buf = SurfelRenderer(sc, device=device).surfel_buffers
    base = RenderConfig(max_duplicates=max_duplicates)
    away = Camera.look_at([0, 0, -50], [0, 0, -90], [0, -1, 0], width=40, height=30, fx=40)
    rng = np.random.default_rng(4)
    for cam in [*cams, away]:
        args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        one = base.raster_settings(cam)
        two = base.raster_settings(cam)
        two.cull_pass_min = 0
        full = rasterize_surfels(buf, *args, one, keep_binning=True).binning
        vis = full.ids.numpy()[: full.n_visible]
        rows = np.union1d(vis, rng.choice(len(sc), len(sc) // 4, replace=False))  # with gaps
        for rw in (None, rows):
            a = rasterize_surfels(buf, *args, one, keep_binning=True, rows=rw)
            b = rasterize_surfels(buf, *args, two, keep_binning=True, rows=rw)
            for k in ("feat", "alpha", "d_min", "d_med", "d_max", "d_mw", "d_exp", "n_samp"):
                assert np.array_equal(getattr(a.out, k).numpy(), getattr(b.out, k).numpy()), k
            n = a.binning.n_visible
            assert n == b.binning.n_visible
            assert np.array_equal(a.binning.ids.numpy()[:n], b.binning.ids.numpy()[:n])
            v = np.random.default_rng(3).random(len(sc), dtype=np.float32)
            va = rasterize_surfels(buf, *args, one, values=v, rows=rw).out.feat.numpy()
            vb = rasterize_surfels(buf, *args, two, values=v, binning=b.binning).out.feat.numpy()
            assert np.array_equal(va, vb)
    assert a.binning.n_visible == 0  # the view away from the scene
