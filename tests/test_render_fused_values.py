"""Per-surfel values known before a view is rendered (the oracle's ground
truth) are composited in the view's own RGB blend, as extra channels of the same
per-pixel loop; the later value render of that camera is read back, not blended again,
and equals a separate value render bit for bit — on 2DGS and 3DGS-derived scenes, with
block culling, the culling pass, several tile bands, windows and row subsets."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.render import RenderConfig
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.synthetic import generate_scene
from divas_kernels import RasterSettings, rasterize_surfels

from .reference_render import random_surfel_scene


@pytest.fixture(scope="module")
def scenes():
    # 2DGS: surfels on both sides of the near plane, large and small; 3DGS-derived:
    # trained-looking Gaussians (interior, haze, needles) as surfels, SH degree 3
    sc2 = random_surfel_scene(5000, seed=11, z_range=(-0.5, 6.0), scale_range=(0.01, 0.3))
    cams2 = [
        Camera.look_at(
            [0.1 * k, -0.1, -0.3 + 0.6 * k],
            [0.2 * k - 0.3, 0.1, 4],
            [0, -1, 0],
            width=96,
            height=72,
            fx=80 * (1 + k),
            cx=48.3,
            cy=35.7,
        )  # fmt: skip
        for k in range(3)
    ]
    g = generate_scene("occluded", None, size=6000, seed=4, kind="3dgs")
    cams3 = [c.scaled(0.15) for c in g.cameras[:: len(g.cameras) // 3][:3]]
    return {"2dgs": (sc2, cams2), "3dgs": (g.scene, cams3, g.labels)}


def _counting(r: SurfelRenderer) -> list:
    """Records every rasterization ``r`` runs (its ``_run`` calls: values or None)."""
    calls, run = [], r._run
    r._run = lambda cam, values, *a, **k: (calls.append(values), run(cam, values, *a, **k))[1]
    return calls


def _same_buffers(a, b):
    for k, v in a.as_dict().items():
        assert np.array_equal(v, getattr(b, k)), k


@pytest.mark.parametrize("kind", ["2dgs", "3dgs"])
@pytest.mark.parametrize(
    "cfg",
    [{}, {"max_duplicates": 300}, {"cull_pass_min": 1}],  # one band / bands / cull pass first
)
def test_attached_values_blended_with_the_rgb_equal_a_value_render(scenes, kind, cfg, device):
    sc, cams = scenes[kind][:2]
    rc = RenderConfig(**{k: v for k, v in cfg.items() if k != "cull_pass_min"})
    fused, plain = (SurfelRenderer(sc, device=device, config=rc) for _ in range(2))
    for r in (fused, plain):
        if "cull_pass_min" in cfg:  # the culling pass first, then the visible ones
            base = r.config.raster_settings
            r.config.raster_settings = lambda c, base=base: _with(base(c), cull_pass_min=1)
        if device == "cpu":
            r.sparse_index()  # block culling of the projected candidates
    rng = np.random.default_rng(3)
    one = (rng.random(len(sc)) < 0.3).astype(np.float32)
    if kind == "3dgs":
        one = scenes[kind][2].astype(np.float32)  # the scene's own ground truth
    two = np.stack([one, rng.standard_normal(len(sc)).astype(np.float32)], 1)
    for vals in (one, two):
        fused.attach_values(vals)
        views = cams + [cams[0].scaled(0.5)]
        for cam in views:  # the RGB render: the same buffers as without the channels
            _same_buffers(fused.render(cam), plain.render(cam))
        plain.clear_cache()
        calls = _counting(fused)
        for cam in views[::-1]:
            got = fused.render_values(cam, vals)
            ref = plain.render_values(cam, vals)
            assert got.shape == ref.shape and got.dtype == ref.dtype
            assert np.array_equal(got, ref)
            assert np.array_equal(got.view(np.uint32), ref.view(np.uint32))
        assert calls == []  # read back: no blend ran
        del fused._run  # the class method again
    assert np.abs(plain.render_values(cams[0], one)).sum() > 0  # something was drawn


def _with(s: RasterSettings, **kw) -> RasterSettings:
    from dataclasses import replace

    return replace(s, **kw)


def test_extra_channels_in_the_rasterizer_windowed_and_on_rows(scenes, device):
    """``rasterize_surfels(extra=…)``: channels 0–2 are the RGB render's, the rest the
    value render's, bit for bit — over the image, a pixel window and a row subset."""
    sc, cams = scenes["2dgs"][:2]
    r = SurfelRenderer(sc, device=device)
    buf, cam = r.surfel_buffers, cams[1]
    proj = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    vals = np.random.default_rng(5).random((len(sc), 3), dtype=np.float32)
    s = r.config.raster_settings(cam)
    rows = None
    if device == "cpu":
        blocks, _ = r.sparse_index()
        rows = blocks.in_window(cam, (0, 0, cam.width, cam.height), r._margin_px)
        assert 0 < len(rows) < len(sc)
    for window in (None, (13, 9, 70, 50)):
        for rw in (None, rows):
            kw = {"window": window, "rows": rw}
            both = rasterize_surfels(buf, *proj, s, background=(0.2, 0.3, 0.4), extra=vals, **kw)
            rgb = rasterize_surfels(buf, *proj, s, background=(0.2, 0.3, 0.4), **kw)
            val = rasterize_surfels(buf, *proj, s, values=vals, **kw)
            f, fr, fv = (x.out.feat.numpy() for x in (both, rgb, val))
            P = np.zeros((cam.height, cam.width), bool)
            x0, y0, x1, y1 = window or (0, 0, cam.width, cam.height)
            P[y0:y1, x0:x1] = True
            P = P.ravel()  # outside a window the pixels are not rendered
            assert f.shape == (cam.width * cam.height, 6)
            assert np.array_equal(f[P, :3], fr[P]) and np.array_equal(f[P, 3:], fv[P])
            for k in ("alpha", "d_min", "d_med", "d_max", "d_mw", "d_exp", "n_samp"):
                a, b = getattr(both.out, k).numpy(), getattr(rgb.out, k).numpy()
                assert np.array_equal(a[P], b[P]), k
    with pytest.raises(ValueError, match="RGB"):
        rasterize_surfels(buf, *proj, s, values=vals, extra=vals)
    with pytest.raises(ValueError, match="rows"):
        rasterize_surfels(buf, *proj, s, extra=vals[:-1])


def test_other_values_and_changed_values_render_afresh(scenes):
    """Only values equal to the attached ones bit for bit are read back: other values,
    the attached ones changed by the caller afterwards (a private copy is held), a
    ``-0.0`` for a ``0.0``, another camera or a depth-only render blend afresh."""
    sc, cams = scenes["2dgs"][:2]
    fused, plain = SurfelRenderer(sc, device="cpu"), SurfelRenderer(sc, device="cpu")
    gt = (np.arange(len(sc)) % 3 == 0).astype(np.float32)
    fused.attach_values(gt)
    fused.render(cams[0])
    fused.render_depth(cams[1])
    fused.render_depth(cams[2], window=(10, 10, 40, 30))
    calls = _counting(fused)
    neg = gt.copy()
    neg[gt == 0] = -0.0
    other = gt[::-1].copy()
    for vals, cam, fresh in [
        (gt, cams[0], False),
        (gt.astype(np.float64), cams[0], False),  # what a value render composites: float32
        (gt[:, None], cams[0], False),  # [N, 1]: the same channel, [H, W, 1]
        (other, cams[0], True),
        (neg, cams[0], True),
        (np.stack([gt, gt], 1), cams[0], True),
        (gt, cams[1], True),  # rendered depth-only: nothing composited
        (gt, cams[2], True),
        (gt, cams[0].scaled(0.5), True),
    ]:
        n = len(calls)
        got = fused.render_values(cam, vals)
        assert np.array_equal(got, plain.render_values(cam, vals))
        assert (len(calls) > n) == fresh
    gt[:7] = 0.5  # the caller changes its array: the copy composited is unchanged
    assert np.array_equal(fused.render_values(cams[0], gt), plain.render_values(cams[0], gt))
    fused.attach_values(None)  # detached: no channel, nothing read back
    calls.clear()
    fused.render(cams[0])
    fused.render_values(cams[0], gt)
    assert len(calls) == 2
    with pytest.raises(ValueError, match="attach_values"):
        fused.attach_values(gt[:-1])


def test_the_oracle_reads_its_truth_from_the_views_render(tmp_path):
    """A session with the oracle and ground truth: the truth is attached to the
    renderer, each clicked view's render composites it, and the oracle's ground-truth
    render of that view runs no blend; the previews equal a session that renders it
    apart."""
    from divas_engine import load_scene
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    sc = generate_scene("ribs", tmp_path, size=20_000, seed=0, grid_resolution=32)
    scene = load_scene(tmp_path / "scene.ply")
    c = sc.metadata["clicks"][0]
    cam = next(k for k in sc.cameras if k.name == c["visible_in"][0])
    out = []
    for fused in (True, False):
        s = Session.open(
            scene, sc.cameras, SessionConfig(render_scale=0.5), OracleSegmenter(), "cpu",
            anchors=[cam], gt_values=sc.labels,
        )  # fmt: skip
        assert (s.renderer._attached is not None) and s.renderer._attached[0].shape == (
            len(scene),
            1,
        )
        if not fused:
            s.renderer.attach_values(None)
        # the anchor (rendered by open) is never segmented: no truth channel in its blend
        assert s.anchors[0].rendered and s.renderer._images == []
        uv, _ = s.anchors[0].camera.project(np.array([c["xyz"]]))
        v = s.click(0, uv[0])
        assert (len(s.renderer._images) > 0) == fused  # the view's render carries it
        calls = _counting(s.renderer)
        prev = s.prompt(v)
        assert (calls == []) == fused  # the oracle's truth: read back, or a value render
        out.append((s.anchors[0].buffers, v.buffers, prev.mask.copy()))
        out[-1] += (s.accept(v).selection.copy(),)
        s.close()
    for a, b in zip(out[0][:2], out[1][:2]):
        _same_buffers(a, b)
    assert np.array_equal(out[0][2], out[1][2]) and out[0][2].any()
    assert np.array_equal(out[0][3], out[1][3])


def test_no_truth_attached_without_the_sessions_oracle(tmp_path):
    """Only the oracle that renders the session's truth makes the renderer composite it:
    an oracle with its own ``gt_render`` (or another segmenter) attaches nothing."""
    from divas_engine import load_scene
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    sc = generate_scene("ribs", tmp_path, size=4000, seed=0, grid_resolution=16)
    scene = load_scene(tmp_path / "scene.ply")
    cam = sc.cameras[0]
    own = OracleSegmenter(gt_render=lambda vid: None)
    s = Session.open(
        scene, sc.cameras, SessionConfig(render_scale=0.5), own, "cpu", anchors=[cam],
        gt_values=sc.labels,
    )  # fmt: skip
    assert s.renderer._attached is None
    s.close()


@pytest.mark.parametrize("kind", ["2dgs", "3dgs"])
def test_second_pass_stores_the_same_splats_in_the_same_order(scenes, kind, device):
    """The culling pass first (``cull_pass_min``), then the visible surfels projected in
    index order with each splat stored at its depth rank: the kept binning's splats are
    byte for byte those of one pass gathered in depth order, with and without rows."""
    sc, cams = scenes[kind][:2]
    buf = SurfelRenderer(sc, device=device).surfel_buffers
    rng = np.random.default_rng(8)
    for cam in cams:
        args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        one = RenderConfig().raster_settings(cam)
        two = _with(one, cull_pass_min=0)
        ref = rasterize_surfels(buf, *args, one, keep_binning=True).binning
        vis = ref.ids.numpy()[: ref.n_visible]
        rows = np.union1d(vis, rng.choice(len(sc), len(sc) // 3, replace=False))
        for rw in (None, rows):
            a = rasterize_surfels(buf, *args, one, keep_binning=True, rows=rw).binning
            b = rasterize_surfels(buf, *args, two, keep_binning=True, rows=rw).binning
            n = a.n_visible
            assert n == b.n_visible == ref.n_visible > 0
            assert a.splats.numpy()[:n].tobytes() == b.splats.numpy()[:n].tobytes()
            assert np.array_equal(a.ids.numpy()[:n], b.ids.numpy()[:n])


@pytest.mark.parametrize("tile", [16, 5, 64])
def test_tile_walk_skipping_finished_rows_is_bit_identical(tile):
    """The CPU tile walk skips a tile row once all its pixels are done (T < T_min): on a
    dense, opaque scene where most rows finish early, every channel, the value render
    equal the pixel walk's (which has no such skip), and so do the per-surfel
    contributions (up to the order of their float sums)."""
    from dataclasses import replace as _replace

    sc = random_surfel_scene(6000, seed=21, z_range=(1.0, 4.0), scale_range=(0.05, 0.4))
    sc = _replace(sc, opacities=np.maximum(sc.opacities, np.float32(0.9)))
    cam = Camera.look_at(
        [0.05, -0.02, -0.2], [0, 0, 3], [0, -1, 0], width=83, height=61, fx=70, cx=41.5, cy=30.5
    )
    out = {}
    for mode in ("tile", "pixel"):
        r = SurfelRenderer(sc, device="cpu", config=RenderConfig(blend=mode, tile=tile))
        b = r.render(cam)
        v = np.random.default_rng(2).random((len(sc), 2), dtype=np.float32)
        pos = b.D_med > np.median(b.D_med)
        out[mode] = (b, r.render_values(cam, v), r.contributions(cam, pos))
    (bt, vt, ct), (bp, vp, cp) = out["tile"], out["pixel"]
    assert (bt.alpha > 0.9999).mean() > 0.5  # most pixels finish before their lists end
    _same_buffers(bt, bp)
    assert np.array_equal(vt, vp)
    for k in ("a1", "a0"):  # sums of the same weights, added in another order
        np.testing.assert_allclose(getattr(ct, k).numpy(), getattr(cp, k).numpy(), 1e-5, 1e-7)
