"""Work shared or skipped for speed gives bit-identical results — a value
render reusing the RGB render's projection and tile binning, the depth-only probe
render, the probe rendered over its central patch only, the brute-force eq:neigh
neighbourhood, and the lazily rendered accept overlays."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.spatial import cKDTree

from divas_engine.camera import Camera
from divas_engine.render import RenderConfig, Renderer
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.views.centroid_gs import GsCentroidPlanner

from .centroid_checks import same_centroid_views
from .reference_render import random_surfel_scene


@pytest.fixture(scope="module")
def case():
    sc = random_surfel_scene(2500, seed=5)
    cams = [
        Camera.look_at(
            [0.2 * k, -0.1, -0.3], [0, 0, 4], [0, -1, 0], width=90, height=70, fx=80, cx=45, cy=35
        )
        for k in range(3)
    ]
    return sc, cams


def _same(a, b):
    for k, v in a.as_dict().items():
        assert np.array_equal(v, getattr(b, k)), k


@pytest.mark.parametrize("max_duplicates", [1 << 25, 300])  # one band / several bands
def test_value_renders_reusing_the_binning_are_bit_identical(case, max_duplicates, device):
    sc, cams = case
    cfg = RenderConfig(max_duplicates=max_duplicates)
    cached = SurfelRenderer(sc, device=device, config=cfg)
    fresh = SurfelRenderer(sc, device=device, config=cfg)
    fresh.binning_cache = 0
    v = np.random.default_rng(0).random((len(sc), 2), dtype=np.float32)
    for cam in cams:  # RGB first: its binning (and colours) kept
        _same(cached.render(cam), fresh.render(cam))
    assert len(cached._binnings) == cached.binning_cache and not fresh._binnings
    for cam in cams[::-1]:  # cache hits (then RGB after values, scaled: misses)
        assert np.array_equal(cached.render_values(cam, v), fresh.render_values(cam, v))
        assert np.array_equal(cached.render_values(cam, v[:, 0]), fresh.render_values(cam, v[:, 0]))
        _same(cached.render(cam), fresh.render(cam))  # RGB after a value render
        _same(cached.render(cam, scale=0.5), fresh.render(cam, scale=0.5))


def test_kept_binnings_make_room_before_the_next_render(case):
    """A render whose binning will be kept first drops the kept binnings that would not
    survive it (the byte budget fits one here), so two are never held at once; a
    cache only: the renders equal a renderer without one."""
    sc, cams = case
    r, fresh = SurfelRenderer(sc, device="cpu"), SurfelRenderer(sc, device="cpu")
    fresh.binning_cache = 0
    r.render(cams[0])
    one = r._binnings[0].nbytes
    r.binning_cache_bytes = int(1.5 * one)
    seen = []
    plain = r._make_room

    def make_room() -> list:
        donors = plain()
        seen.append(len(r._binnings))
        return donors

    r._make_room = make_room
    for cam in cams[1:]:
        _same(r.render(cam), fresh.render(cam))
        assert len(r._binnings) == 1 and r.kept_binning(cam) is not None
    assert seen == [0, 0]  # emptied before each render, not after
    r.binning_cache_bytes = 3 * one + 1  # room for all: nothing dropped
    r.render(cams[0])
    assert len(r._binnings) == 2


def test_depth_only_render_has_the_same_depths(case, device):
    sc, cams = case
    r = SurfelRenderer(sc, device=device)
    for cam in cams:
        full, depth = r.render(cam, scale=0.4), r.render_depth(cam, scale=0.4)
        for k in ("alpha", "D_min", "D_ref", "D_max", "D_mw", "D_exp", "D_med", "N_samp"):
            assert np.array_equal(getattr(full, k), getattr(depth, k)), k


@pytest.mark.parametrize("max_duplicates", [1 << 25, 200])  # one band / several bands
def test_windowed_depth_render_is_the_window_of_the_whole_render(case, max_duplicates, device):
    """A depth render of a pixel window: inside it every channel equals the whole
    render's bit for bit (the surfels that miss it are culled, the others clipped to
    it); outside it the empty tuple. Fewer (tile, surfel) pairs than the whole image."""
    sc, cams = case
    r = SurfelRenderer(sc, device=device, config=RenderConfig(max_duplicates=max_duplicates))
    r.binning_cache = 0
    chans = ("alpha", "D_min", "D_ref", "D_max", "D_mw", "D_exp", "D_med", "N_samp")
    for cam in cams:
        full = r.render(cam, scale=0.5)
        h, w = full.alpha.shape
        centre = (w // 4, h // 4, w // 4 + w // 2, h // 4 + h // 2)
        for x0, y0, x1, y1 in [centre, (0, 0, 7, 5), (w - 3, h - 20, w + 9, h), (17, 9, 18, 10)]:
            part = r.render_depth(cam, scale=0.5, window=(x0, y0, x1, y1))
            inside = np.zeros((h, w), bool)
            inside[y0:y1, x0:x1] = True
            for k in chans:
                a, b = getattr(part, k), getattr(full, k)
                assert np.array_equal(a[inside], b[inside]), k
                assert not a[~inside].any(), k
        assert (full.D_med > 0).mean() > 0.3  # the windows see surfaces
    with pytest.raises(ValueError, match="no pixel"):
        r.render_depth(cams[0], window=(5, 5, 5, 9))


def test_windowed_probes_give_the_same_centroid_views():
    """The planner's probes render only their central patch (eq:occfrac reads nothing
    else): the centroid cameras and the probe logs equal those of whole-image probe
    renders (a renderer without ``render_depth``), here with rejected probes too."""
    from divas_engine.synthetic import generate_scene

    s = generate_scene("occluded", None, size=20_000, seed=0)
    r = SurfelRenderer(s.scene, device="cpu")

    class WholeImage(Renderer):  # the probes' fallback: a full render of the whole image
        def render(self, camera, scale=1.0, *, attached=True):  # (Renderer.render_depth's)
            return r.render(camera, scale)

        def render_values(self, camera, values, scale=1.0):
            return r.render_values(camera, values, scale)

    windowed, whole = GsCentroidPlanner(s.scene, r), GsCentroidPlanner(s.scene, WholeImage())
    rejected = 0
    for a, _ in same_centroid_views(s, r.render, windowed, whole):
        rejected += sum(not p.accepted for p in a.probes)
    assert rejected > 0  # some probe was occluded: the comparison covers rejections


def test_neighbourhood_matches_a_kd_tree(case):
    sc, _ = case
    p = GsCentroidPlanner(sc, renderer=None)
    opaque = np.flatnonzero(sc.opacities > p.config.alpha_min)
    pts = np.asarray(sc.means[opaque], dtype=np.float64)
    tree = cKDTree(pts)
    rng = np.random.default_rng(1)
    for x, r in zip(pts[rng.integers(0, len(pts), 20)], rng.uniform(0.05, 1.5, 20)):
        idx = np.asarray(tree.query_ball_point(x, r), dtype=np.int64)
        idx = idx[np.linalg.norm(pts[idx] - x, axis=1) < r]
        ref = np.sort(opaque[idx])
        got = p.neighbourhood(x, r)
        assert got.size > 0 and np.array_equal(got, ref)


def test_accept_overlays_are_lazy_and_show_the_accepted_selection(tmp_path):
    from divas_engine import load_scene
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("ribs", tmp_path, size=20_000, seed=0, grid_resolution=32)
    scene = load_scene(tmp_path / "scene.ply")
    c = sc.metadata["clicks"][0]
    cam = next(k for k in sc.cameras if k.name == c["visible_in"][0])
    s = Session.open(
        scene, sc.cameras, SessionConfig(render_scale=0.5), OracleSegmenter(), "cpu",
        anchors=[cam], gt_values=sc.labels,
    )  # fmt: skip
    assert s.anchors[0].rendered  # the first anchor is rendered by open
    a = s.anchors[0]
    uv, _ = a.camera.project(np.array([c["xyz"]]))
    views = [s.click(0, uv[0]), s.click(0, uv[0] + 6.0)]
    renders = s.timings.calls("render")[:]
    r0 = s.accept(views[0])
    assert s.timings.calls("render") == renders  # accept rendered nothing
    assert r0.overlay_source is not None and callable(r0.overlay_source)
    r1 = s.accept(views[1])
    assert not np.array_equal(r0.selection, r1.selection)
    ov = r0.overlay  # rendered now, after r1 changed the session's selection
    ref = s.renderer.render_values(views[0].camera, r0.selection.astype(np.float32))
    assert np.array_equal(ov.coverage, ref.astype(np.float32))
    assert r0.overlay is ov and r0.next_view is views[1]
    nxt = r0.next_overlay
    ref1 = s.renderer.render_values(views[1].camera, r0.selection.astype(np.float32))
    assert np.array_equal(nxt.coverage, ref1.astype(np.float32))
    # the anchor's overlay takes the anchor's existing render (no second RGB render)
    n = len(s.timings.calls("render"))
    ova = s.overlay(a.camera, full_camera=False)
    assert len(s.timings.calls("render")) == n
    fresh = s.renderer.render(a.camera).rgb
    cov = ova.coverage
    al = (np.clip(cov, 0.0, 1.0) * np.float32(s.config.overlay_alpha))[..., None]
    col = np.asarray(s.config.overlay_color, np.float32)
    assert np.array_equal(ova.image, (fresh * (1.0 - al) + col * al).astype(np.float32))
    s.close()


def test_accept_releases_a_binning_the_budget_cannot_keep_beside_another(tmp_path):
    """When the kept binnings' byte budget holds one view only (a 3M-surfel scene), an
    accept frees the accepted view's binning at once (the next render would drop it);
    with room for more it stays. The selection and the overlay are the same."""
    from divas_engine import load_scene
    from divas_engine.segment import OracleSegmenter
    from divas_engine.session import Session, SessionConfig
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("ribs", tmp_path, size=20_000, seed=0, grid_resolution=32)
    scene = load_scene(tmp_path / "scene.ply")
    c = sc.metadata["clicks"][0]
    cam = next(k for k in sc.cameras if k.name == c["visible_in"][0])
    out = []
    for tight in (False, True):
        s = Session.open(
            scene, sc.cameras, SessionConfig(render_scale=0.5), OracleSegmenter(), "cpu",
            anchors=[cam], gt_values=sc.labels,
        )  # fmt: skip
        uv, _ = s.anchors[0].camera.project(np.array([c["xyz"]]))
        v = s.click(0, uv[0])
        s.prompt(v)
        kept = s.renderer.kept_binning(v.camera)
        assert kept is not None  # the segmenter's value render reused it
        if tight:
            s.renderer.binning_cache_bytes = int(1.5 * kept.nbytes)
        r = s.accept(v)
        assert (s.renderer.kept_binning(v.camera) is None) == tight
        out.append((r.selection.copy(), r.overlay.coverage))
        s.close()
    assert np.array_equal(out[0][0], out[1][0]) and out[0][0].any()
    assert np.array_equal(out[0][1], out[1][1])


def test_fusion_kernel_split_over_threads_is_bit_identical(tmp_path):
    """The per-voxel fusion kernel and the hash queries run as several CPU sub-launches
    (all cores); the contributions equal a single launch's bit for bit."""
    import divas_kernels as dk
    from divas_engine.fusion import FusionView, GridConfig, GsFusion, build_occupancy

    sc = random_surfel_scene(4000, seed=3)
    cam = Camera.look_at(
        [0.1, -0.2, -0.4], [0, 0, 4], [0, -1, 0], width=80, height=60, fx=70, cx=40, cy=30
    )
    b = SurfelRenderer(sc, device="cpu").render(cam)
    mask = (b.D_med > np.median(b.D_med[b.D_med > 0])).astype(np.float32)
    grid = build_occupancy(sc, GridConfig(g_max=64), "cpu")
    f = GsFusion(grid)
    vd = f.upload(FusionView(cam, mask, b.D_min, b.D_ref, b.D_max, b.N_samp, 4.0))
    outs = []
    for threads in (1, 2, 3):
        dk.gs_fuse_view(
            grid.codes, grid.density, f._geom, vd, f._params, f._num, f._den, f._kind,
            device="cpu", threads=threads,
        )  # fmt: skip
        outs.append((f._num.numpy().copy(), f._den.numpy().copy(), f._kind.numpy().copy()))
        q = dk.hash_query(
            grid.hash_keys, grid.hash_vals, grid.hash_shift, grid.codes, "cpu", threads
        )
        assert np.array_equal(q.numpy(), np.arange(len(grid), dtype=np.int32))
    assert (outs[0][2] > 0).any()
    for o in outs[1:]:
        for x, y in zip(outs[0], o):
            assert np.array_equal(x, y)


def test_sort_visible_is_the_prefix_of_a_stable_sort_of_all_keys(device):
    """The depth order of the surfels left after culling (compacted, then sorted) equals
    the first entries of a stable sort of every key (culled keys BIG sort last)."""
    from divas_kernels.tile_binning import sort_visible

    rng = np.random.default_rng(3)
    dev = wp.get_device(device)
    for n, culled in [(1, 0.0), (50, 1.0), (20_000, 0.7), (20_000, 0.05)]:
        keys = rng.integers(1, 300, n).astype(np.float32) * np.float32(0.37)  # many ties
        keys[rng.random(n) < culled] = np.float32(1e30)
        order, n_vis = sort_visible(wp.array(keys, device=dev), n, dev, 2)
        ref = np.argsort(keys, kind="stable")
        assert n_vis == int((keys < 1e29).sum())
        assert np.array_equal(order.numpy()[:n_vis], ref[:n_vis])
