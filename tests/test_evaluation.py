"""Evaluation: metrics on hand cases, the contribution kernel against a NumPy
reference, both baselines on hand cases, the pipeline helpers, and a small end-to-end
run of the table on the occluded scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.evaluation import (
    ContributionVoteConfig,
    EvalConfig,
    MaskView,
    ViewEvaluator,
    centre_vote,
    contribution_vote,
    evaluate_selection,
    mask_scores,
    surfel_scores,
)
from divas_engine.evaluation.baselines import ContributionVoter
from divas_engine.evaluation.pipeline import CachingRenderer, variant_config
from divas_engine.render import RenderConfig, make_renderer
from divas_engine.scene import DensityGrid, SurfelScene
from divas_kernels import RasterSettings, resolve_device, upload_surfels
from divas_kernels.contrib import accumulate_contributions

from .reference_render import random_surfel_scene, surfel_hits
from .stub_segmenters import ConstantSegmenter

CPU = "cpu"


def _cam(w=64, h=48, f=60.0, c2w=None, name="") -> Camera:
    return Camera(w, h, f, f, w / 2, h / 2, np.eye(4) if c2w is None else c2w, name)


def _plane(cx, cy, z, half, spacing, scale, opacity=1.0) -> dict:
    """A square of camera-facing surfels (normal −z) centred at (cx, cy, z)."""
    g = np.arange(-half + spacing / 2, half, spacing)
    xs, ys = np.meshgrid(g + cx, g + cy)
    n = xs.size
    return {
        "means": np.stack([xs.ravel(), ys.ravel(), np.full(n, z)], 1),
        "scales": np.full((n, 2), scale),
        "opacities": np.full(n, opacity),
    }


def _scene(*planes) -> SurfelScene:
    means = np.concatenate([p["means"] for p in planes]).astype(np.float32)
    n = len(means)
    quats = np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32)  # identity: normal = +z
    sh = np.full((n, 1, 3), 0.5, np.float32)
    return SurfelScene(
        means,
        quats,
        np.concatenate([p["scales"] for p in planes]).astype(np.float32),
        np.concatenate([p["opacities"] for p in planes]).astype(np.float32),
        sh,
        0,
    )


# ----------------------------------------------------------------------------- metrics
def test_mask_scores_hand_case():
    pred = np.zeros((4, 5), bool)
    gt = np.zeros((4, 5), bool)
    pred[0, :3] = True  # 3 pixels
    gt[0, 1:5] = True  # 4 pixels, overlap 2
    s = mask_scores(pred, gt, "v")
    assert (s.intersection, s.union) == (2, 5)
    assert s.iou == pytest.approx(2 / 5)
    assert s.accuracy == pytest.approx((20 - 3) / 20)  # 1 FP + 2 FN wrong
    assert s.precision == pytest.approx(2 / 3) and s.recall == pytest.approx(2 / 4)
    empty = mask_scores(np.zeros((2, 2), bool), np.zeros((2, 2), bool))
    assert empty.iou == 1.0 and empty.accuracy == 1.0 and empty.precision == 1.0
    with pytest.raises(ValueError):
        mask_scores(np.zeros((2, 2)), np.zeros((2, 3)))


def test_surfel_scores_hand_case():
    sel = np.array([1, 1, 1, 0, 0, 0], bool)
    gt = np.array([0, 1, 1, 1, 1, 0], bool)
    s = surfel_scores(sel, gt)
    assert s["precision"] == pytest.approx(2 / 3) and s["recall"] == pytest.approx(2 / 4)
    assert s["iou"] == pytest.approx(2 / 5) and s["f1"] == pytest.approx(
        2 * (2 / 3) * 0.5 / (2 / 3 + 0.5)
    )
    assert surfel_scores(np.zeros(3, bool), np.zeros(3, bool))["precision"] == 1.0


@pytest.fixture(scope="module")
def two_planes():
    """Two 1×1 opaque squares at depth 4, side by side (gap 0.5), seen head-on by a
    60 px-focal camera: each covers 15×15 px (4 units → 60 px: 1 unit = 15 px)."""
    a = _plane(-0.75, 0.0, 4.0, 0.5, 0.02, 0.015)
    b = _plane(0.75, 0.0, 4.0, 0.5, 0.02, 0.015)
    scene = _scene(a, b)
    na = len(a["means"])
    labels = np.zeros(len(scene), bool)
    labels[:na] = True
    return scene, labels, _cam()


def test_two_planes_iou_by_hand(two_planes):
    scene, labels, cam = two_planes
    r = make_renderer(scene, device=CPU)
    same = EvalConfig(pred_threshold=0.5, gt_threshold=0.5)
    # selecting both planes when only A is the object. Each square is 1 unit = 15 px at
    # depth 4, plus a rim of at most 1.5 px (surfel σ = 0.2 px beyond the edge and the
    # 0.7 px low-pass): |A| = |B| ∈ [15², 18²]. By hand: IoU = |A| / (|A| + |B|) = 1/2,
    # accuracy = 1 − |B| / (64·48), precision 1/2, recall 1.
    both = evaluate_selection(
        scene, [cam], np.ones(len(scene), bool), labels, config=same, renderer=r
    )
    v = both.views[0]
    assert 15**2 <= v.gt_pixels <= 18**2 and v.pred_pixels == 2 * v.gt_pixels
    assert both.iou == pytest.approx(0.5, abs=1e-9)
    assert both.accuracy == pytest.approx(1 - v.gt_pixels / (64 * 48))
    assert both.precision == pytest.approx(0.5) and both.recall == 1.0
    assert both.primitives["precision"] == pytest.approx(0.5) and both.primitives["recall"] == 1.0
    # the exact selection scores 1 with equal thresholds …
    exact = evaluate_selection(scene, [cam], labels, labels, config=same, renderer=r)
    assert exact.iou == 1.0 and exact.accuracy == 1.0
    # … and with the NOTES thresholds (0.1 vs 0.5) the prediction only grows at the rim
    notes = evaluate_selection(scene, [cam], labels, labels, renderer=r)
    assert notes.recall == 1.0 and notes.iou > 0.85
    assert notes.views[0].pred_pixels >= notes.views[0].gt_pixels


def test_3dgs_scores_prediction_and_truth_at_the_same_level(two_planes):
    """On trained 3DGS the default thresholds are 0.5 / 0.5: the exact selection scores
    exactly 1 (its soft rim no longer counts against it); 2DGS keeps NOTES' 0.1 / 0.5."""
    import dataclasses

    from divas_engine.kinds import SceneKind

    scene, labels, cam = two_planes
    assert EvalConfig().pred_threshold_for(scene) == 0.1
    gs3d = dataclasses.replace(scene, kind=SceneKind.GS3D)
    assert EvalConfig().pred_threshold_for(gs3d) == 0.5
    assert EvalConfig(pred_threshold=0.2).pred_threshold_for(gs3d) == 0.2
    r2, r3 = make_renderer(scene, device=CPU), make_renderer(gs3d, device=CPU)
    paper = evaluate_selection(scene, [cam], labels, labels, renderer=r2).views[0]
    same = evaluate_selection(gs3d, [cam], labels, labels, renderer=r3)
    assert same.iou == 1.0 and same.views[0].pred_pixels == same.views[0].gt_pixels
    assert paper.pred_pixels > paper.gt_pixels  # the rim between 0.1 and 0.5 (2DGS)
    # a selection of both planes: by hand |A| / (|A| + |B|) = 1/2 at 0.5 / 0.5
    both = evaluate_selection(gs3d, [cam], np.ones(len(gs3d), bool), labels, renderer=r3)
    assert both.iou == pytest.approx(0.5, abs=1e-9)


def test_evaluator_scores_many_selections_in_one_pass(two_planes):
    scene, labels, cam = two_planes
    ev = ViewEvaluator(scene, [cam, cam.scaled(0.5)], labels, renderer=make_renderer(scene, CPU))
    out = ev.score({"a": labels, "none": np.zeros(len(scene), bool), "b": ~labels})
    assert out["a"].recall == 1.0
    assert out["none"].iou == 0.0 and out["none"].precision == 0.0
    assert out["b"].iou == 0.0
    for v in out[
        "b"
    ].views:  # disjoint prediction and truth: every predicted or true pixel is wrong
        assert v.accuracy == pytest.approx(1 - (v.pred_pixels + v.gt_pixels) / v.pixels)
    one = ev.score({"b": ~labels})["b"]
    assert [v.pred_pixels for v in one.views] == [v.pred_pixels for v in out["b"].views]


def test_nerf_masks_segmented_density():
    d = np.zeros((16, 16, 32), np.float32)  # [D,H,W] = z, y, x
    d[6:10, 6:10, 4:12] = 200.0  # cube A (left)
    d[6:10, 6:10, 20:28] = 200.0  # cube B (right)
    grid = DensityGrid(d, np.array([[-2.0, -1.0, 3.0], [2.0, 1.0, 5.0]]))
    labels = np.zeros(d.shape, bool)
    labels[:, :, :16] = True  # A's half of the grid
    cam = _cam(64, 48, 40.0)
    exact = evaluate_selection(grid, [cam], labels, labels)
    assert exact.iou == 1.0 and exact.views[0].gt_pixels > 50
    both = evaluate_selection(grid, [cam], np.ones(d.shape, bool), labels)
    # same-size cubes placed symmetrically about the optical axis: IoU = 1/2
    assert both.iou == pytest.approx(0.5, abs=0.02)
    assert both.primitives["precision"] == pytest.approx(0.5)


# ----------------------------------------------------------------------------- contribution kernel
def _reference_contrib(scene, cam, pos, cfg: RenderConfig):
    """A₁/A₀ in float64 by brute force (every pixel × every surfel, NOTES compositing)."""
    n = len(scene)
    zc = scene.means.astype(np.float64) @ cam.w2c[2, :3] + cam.w2c[2, 3]
    order = np.lexsort((np.arange(n), zc))
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
    xs, ys, p = xs.ravel(), ys.ravel(), pos.ravel()
    a1, a0 = np.zeros(n), np.zeros(n)
    for lo in range(0, len(xs), 256):
        a, _, _ = surfel_hits(scene, cam, xs[lo : lo + 256], ys[lo : lo + 256], cfg, order)
        t_after = np.cumprod(1 - a, axis=1)
        stop = t_after < cfg.t_min
        a = np.where(((np.cumsum(stop, 1) - stop) == 0) & (a > 0), a, 0.0)
        t_before = np.concatenate([np.ones((len(a), 1)), np.cumprod(1 - a, 1)[:, :-1]], 1)
        w = a * t_before
        pp = p[lo : lo + 256]
        a1[order] += w[pp].sum(0)
        a0[order] += w[~pp].sum(0)
    return a1, a0


@pytest.mark.parametrize("blend,threads", [("tile", 1), ("tile", 2), ("pixel", 2)])
def test_contrib_kernel_matches_reference(blend, threads):
    scene = random_surfel_scene(300, seed=1, sh_degree=0)
    cam = _cam()
    pos = np.random.default_rng(0).random((48, 64)) < 0.4
    dev = resolve_device(CPU)
    buf = upload_surfels(
        scene.means,
        scene.rotations(),
        scene.scales,
        scene.opacities,
        scene.sh,
        scene.sh_degree,
        dev,
    )
    out = accumulate_contributions(
        buf,
        cam.w2c,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        64,
        48,
        pos,
        RasterSettings(blend=blend, threads=threads, tile=8),
    )
    r1, r0 = _reference_contrib(scene, cam, pos, RenderConfig())
    assert (r1 + r0 > 0).sum() > 100
    for got, ref in ((out.a1.numpy(), r1), (out.a0.numpy(), r0)):
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-6)
    # Σ_i (A₁ + A₀) = Σ_p accumulated opacity (the weights of every pixel sum to 1 − T)
    alpha = make_renderer(scene, CPU).render(cam).alpha
    assert float(out.a1.numpy().sum() + out.a0.numpy().sum()) == pytest.approx(
        float(alpha.sum()), rel=1e-4
    )


def test_contrib_front_surfel_hides_back_one():
    front = {
        "means": np.array([[0.0, 0.0, 2.0]]),
        "scales": np.array([[3.0, 3.0]]),
        "opacities": np.array([1.0]),
    }  # one big opaque surfel
    back = {
        "means": np.array([[0.0, 0.0, 3.0]]),
        "scales": np.array([[0.1, 0.1]]),
        "opacities": np.array([1.0]),
    }
    alone = _scene(back)
    scene = _scene(front, back)
    cam = _cam()
    pos = np.ones((48, 64), bool)
    res = contribution_vote(scene, [MaskView(cam, pos.astype(np.float32))], device=CPU)
    res_alone = contribution_vote(alone, [MaskView(cam, pos.astype(np.float32))], device=CPU)
    assert res.negative.sum() == 0.0  # every pixel is mask-positive
    assert res.positive[0] > 100 and res_alone.positive[0] > 5
    assert res.positive[1] < 0.0105 * res_alone.positive[0]  # T ≈ 0.01 behind α ≈ 0.99


# ----------------------------------------------------------------------------- baselines
def test_centre_vote_hand_case():
    # three small surfels on the axis side by side, one hidden behind a big opaque one
    s0 = {
        "means": np.array([[-0.5, 0.0, 4.0]]),
        "scales": np.array([[0.05, 0.05]]),
        "opacities": np.array([1.0]),
    }
    s1 = {
        "means": np.array([[0.5, 0.0, 4.0]]),
        "scales": np.array([[0.05, 0.05]]),
        "opacities": np.array([1.0]),
    }
    wall = {
        "means": np.array([[0.0, 0.8, 3.0]]),
        "scales": np.array([[0.3, 0.3]]),
        "opacities": np.array([1.0]),
    }
    hidden = {
        "means": np.array([[0.0, 0.8, 5.0]]),
        "scales": np.array([[0.05, 0.05]]),
        "opacities": np.array([1.0]),
    }
    scene = _scene(s0, s1, wall, hidden)
    cam = _cam()
    uv, _ = cam.project(scene.means)
    masks = []
    # view 1: s0 and the hidden one's pixel positive; view 2: s0, s1; view 3: s1 only
    for pos_ids in ([0, 3], [0, 1], [1]):
        m = np.zeros((48, 64), np.float32)
        for i in pos_ids:
            m[int(uv[i, 1]), int(uv[i, 0])] = 0.9
        masks.append(MaskView(cam, m))
    res = centre_vote(scene, masks, renderer=make_renderer(scene, CPU))
    # s0: 2 of 3 positive → fg; s1: 2 of 3 → fg; wall: 0 of 3 → bg; hidden: never seen → bg
    assert res.positive.tolist() == [2, 2, 0, 0]
    assert res.negative.tolist() == [1, 1, 3, 0]
    assert res.selected.tolist() == [True, True, False, False]
    # a view that does not see a surfel (out of frame) does not vote
    far = _cam(c2w=np.array([[1, 0, 0, 50.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    res2 = centre_vote(
        scene, masks + [(far, np.zeros((48, 64), np.float32))], renderer=make_renderer(scene, CPU)
    )
    assert res2.negative.tolist() == [1, 1, 3, 0]
    # tie → background
    tie = centre_vote(
        scene,
        masks[:1] + [MaskView(cam, np.zeros((48, 64), np.float32))],
        renderer=make_renderer(scene, CPU),
    )
    assert not tie.selected[0]
    # view 1 with its own near clip at 4.5: s0, s1 (z = 4) and the wall (z = 3) are cut
    # and cast no vote there; the wall does not hide the z = 5 surfel, which votes +
    clipped = centre_vote(
        scene,
        [MaskView(cam.with_near(4.5), masks[0].mask)] + masks[1:],
        renderer=make_renderer(scene, CPU),
    )
    assert clipped.positive.tolist() == [1, 2, 0, 1]
    assert clipped.negative.tolist() == [1, 0, 2, 0]


def test_contribution_vote_rule_and_bias(two_planes):
    scene, labels, cam = two_planes
    gt = make_renderer(scene, CPU).render_values(cam, labels.astype(np.float32))
    m = (gt >= 0.5).astype(np.float32)
    res = contribution_vote(scene, [(cam, m)], device=CPU)
    assert np.array_equal(res.selected, res.positive > res.negative)
    vis = res.positive + res.negative > 0
    assert surfel_scores(res.selected[vis], labels[vis])["iou"] > 0.97
    strict = contribution_vote(
        scene, [(cam, m)], device=CPU, config=ContributionVoteConfig(gamma=0.9)
    )
    assert strict.selected.sum() < res.selected.sum()
    with pytest.raises(ValueError):
        ContributionVoteConfig(gamma=1.0)
    # the weights honour a view camera's own near clip like the renderer's near
    zc = cam.world_to_camera(scene.means.astype(np.float64))[:, 2]
    near = float(np.median(zc))
    a = ContributionVoter(scene, CPU).contributions(MaskView(cam.with_near(near), m))
    b = ContributionVoter(scene, CPU, RenderConfig(near=near)).contributions(MaskView(cam, m))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    plain = ContributionVoter(scene, CPU).contributions(MaskView(cam, m))
    assert not np.array_equal(a[0], plain[0])


# ----------------------------------------------------------------------------- pipeline helpers
def test_variant_configs():
    from divas_engine.segment.depth_weighting import apply_gs_bandpass, apply_nerf_depth_weight

    nt = variant_config("no_thin")
    assert math.isinf(nt.gs_fusion.rho_thin)
    nd = variant_config("no_depth_weight")
    rng = np.random.default_rng(0)
    mask = rng.random((20, 30)).astype(np.float32)
    depth = rng.uniform(1, 10, (20, 30))
    depth[:3] = 0.0  # no surface there
    w, band = apply_gs_bandpass(
        mask, depth, np.array([[5.0, 5.0]]), np.array([1]), config=nd.bandpass
    )
    assert band is not None and np.array_equal(w, mask)
    assert np.array_equal(apply_nerf_depth_weight(mask, depth, config=nd.nerf_weight), mask)
    assert variant_config("full") == variant_config("full")
    with pytest.raises(ValueError):
        variant_config("nope")


def test_caching_renderer_is_transparent():
    scene = random_surfel_scene(200, seed=3, sh_degree=0)
    inner = make_renderer(scene, CPU)
    c = CachingRenderer(inner)
    cam = _cam()
    a, b = c.render(cam), c.render(cam)
    assert a is b and c.hits == 1
    ref = inner.render(cam)
    assert np.array_equal(a.D_med, ref.D_med) and np.array_equal(a.rgb, ref.rgb)
    v = np.arange(len(scene), dtype=np.float32) % 2
    assert np.array_equal(c.render_values(cam, v), inner.render_values(cam, v))
    assert c.render_values(cam, 1 - v) is not c.render_values(cam, v)
    clipped = c.render(cam.with_near(3.0))  # a camera's near is part of the key
    assert clipped is not a
    assert np.array_equal(clipped.D_med, inner.render(cam.with_near(3.0)).D_med)
    with pytest.raises(ValueError):
        a.rgb[0, 0, 0] = 1.0  # cached arrays are read-only
    assert c.num_primitives == len(scene)


# ----------------------------------------------------------------------------- end to end
def test_eval_table_end_to_end_occluded():
    """The default (simulated user) protocol."""
    from divas_engine.evaluation.suite import METHODS, SuiteConfig, evaluate_scene, markdown_table
    from divas_engine.session import SessionConfig

    cfg = SuiteConfig(
        scenes=("occluded",),
        segmenters=("oracle",),
        size=20_000,
        nerf=False,
        session=SessionConfig(render_scale=0.5),
        eval=EvalConfig(scale=0.5),
    )
    rows = evaluate_scene("occluded", cfg, device=CPU)
    assert [r["method"] for r in rows] == list(METHODS)
    for r in rows:
        for k in ("iou", "accuracy", "precision_3d", "recall_3d"):
            assert 0.0 <= r[k] <= 1.0, (r["method"], k, r[k])
        assert r["views_fused"] == r["views"] > 0
    by = {r["method"]: r for r in rows}
    assert by["full"]["iou"] > 0.8  # the oracle on the occluded vase
    assert by["full"]["precision_3d"] > 0.9
    assert by["no_thin"]["recall_3d"] < by["full"]["recall_3d"]
    # the mapping chain is monotone: f ⊆ f² ⊆ f¹
    assert by["full"]["selected"] <= by["pass12"]["selected"] <= by["pass1"]["selected"]
    text = markdown_table({"rows": rows})
    assert text.count("\n") == len(rows) + 1 and "DivAS full" in text


def test_eval_cli_arguments():
    import argparse

    from divas_engine.cli import evaluate
    from divas_engine.errors import DivasInputError

    p = argparse.ArgumentParser()
    evaluate.add_parser(p.add_subparsers())
    a = p.parse_args(["eval", "--scenes", "ribs,occluded,ribs", "--segmenters", "oracle"])
    assert a.scenes == ("ribs", "occluded") and a.segmenters == ("oracle",)
    assert a.size == evaluate.DEFAULT_SIZE and not a.no_nerf
    assert a.protocol == "user"
    assert p.parse_args(["eval", "--protocol", "clicks"]).protocol == "clicks"
    with pytest.raises(SystemExit):
        p.parse_args(["eval", "--protocol", "nope"])
    with pytest.raises(DivasInputError):
        evaluate.run(p.parse_args(["eval", "--max-views", "0"]))
    with pytest.raises(SystemExit):
        p.parse_args(["eval", "--scenes", "ribs,nope"])
    with pytest.raises(DivasInputError):
        evaluate.run(p.parse_args(["eval", "--size", "10"]))


# ----------------------------------------------------------------------------- simulated user
def test_uncovered_regions_and_centre_by_hand():
    from divas_engine.evaluation.scripted_user import region_centre, uncovered_regions

    tgt = np.zeros((20, 30), bool)
    tgt[2:12, 2:12] = True  # 100 px square
    tgt[15:18, 20:29] = True  # 27 px strip
    cov = np.zeros_like(tgt)
    cov[2:12, 2:7] = True  # left half of the square covered → 50 px left
    regs = uncovered_regions(tgt, cov, min_area=10)
    assert [int(r.sum()) for r in regs] == [50, 27]
    assert not (regs[0] & cov).any() and (regs[0] <= tgt).all()
    assert uncovered_regions(tgt, cov, min_area=30)[0].sum() == 50
    assert uncovered_regions(tgt, tgt, min_area=1) == []
    # earlier clicks count as border: the next click moves away from them
    x2, y2 = region_centre(regs[0], avoid=[(9, 4)])
    assert regs[0][int(y2), int(x2)] and (int(x2), int(y2)) != (9, 4) and int(y2) >= 6
    x, y = region_centre(regs[0])  # columns 7..11, rows 2..11
    assert regs[0][int(y), int(x)] and int(x) == 9 and 4 <= int(y) <= 9  # 3 px from every side
    with pytest.raises(ValueError):
        region_centre(np.zeros((3, 3), bool))


class _Recorder:
    """Renderer wrapper recording every camera it renders."""

    def __init__(self, inner):
        self.inner, self.cameras = inner, []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def render(self, camera, scale=1.0):
        self.cameras.append(camera)
        return self.inner.render(camera, scale)

    def render_values(self, camera, values, scale=1.0):
        self.cameras.append(camera)
        return self.inner.render_values(camera, values, scale)


@pytest.fixture(scope="module")
def user_scene():
    from divas_engine.synthetic import generate_scene

    return generate_scene("occluded", size=4000, seed=0)


def _user_session(sc, budget):
    from divas_engine.evaluation.pipeline import make_segmenter
    from divas_engine.evaluation.scripted_user import ScriptedUser
    from divas_engine.session import Session, SessionConfig, anchor_plan

    rec = _Recorder(make_renderer(sc.scene, device=CPU))
    cfg = SessionConfig(render_scale=0.25)
    user = ScriptedUser(sc.labels, budget)
    s = Session.open(
        sc.scene,
        sc.cameras,
        cfg,
        make_segmenter("oracle"),
        CPU,
        anchors=user.anchors(anchor_plan(sc.scene, sc.cameras, cfg)),
        gt_values=sc.labels.astype(np.float32),
        render_anchors=False,
        renderer=rec,
    )
    checked = []
    click = s.click

    def checked_click(ai, xy, positive=True):
        # what the user saw at that moment, recomputed independently of the user
        cam = s.anchors[ai].camera
        tgt = rec.inner.render_values(cam, sc.labels.astype(np.float32)) >= 0.5
        cov = (
            rec.inner.render_values(cam, s.selection.astype(np.float32))
            >= s.config.overlay_threshold
        )
        x, y = int(xy[0]), int(xy[1])
        checked.append((ai, bool(tgt[y, x]), bool(cov[y, x])))
        return click(ai, xy, positive)

    s.click = checked_click
    return s, user, rec, checked


def test_scripted_user_follows_the_protocol(user_scene):
    from divas_engine.evaluation.scripted_user import VIEW_BUDGET, UserBudget

    sc = user_scene
    budget = UserBudget()
    s, user, rec, checked = _user_session(sc, budget)
    try:
        log = user.run(s)
        # it clicked, and only on target pixels the overlay did not cover yet
        assert checked and len(checked) == len(log.clicks)
        assert all(t and not c for _, t, c in checked), checked
        # the paper's view budget for the capture type (tab:view-budget's upper end)
        assert log.max_views == VIEW_BUDGET[s.forward_facing] == user.max_views(s)
        assert len(s.views) == sum(c.view_id is not None for c in log.clicks) <= log.max_views
        # no per-anchor cap: every anchor complete, stalled, past the view budget or unvisited
        per = np.bincount([c.anchor for c in log.clicks], minlength=len(s.anchors))
        assert len(log.anchor_status) == len(s.anchors)
        min_area = user._min_area(s.anchors[0].camera)
        for a, st in enumerate(log.anchor_status):
            assert st in ("complete", "stalled", "budget", "not visited")
            assert st != "not visited" or per[a] == 0
            if st == "stalled":  # its last max_failed_clicks clicks shrank nothing
                seq = [c.uncovered_px for c in log.clicks if c.anchor == a] + [
                    log.uncovered_after[a]
                ]
                k = budget.max_failed_clicks
                assert len(seq) > k and all(
                    seq[i] - seq[i + 1] < min_area for i in range(len(seq) - k - 1, len(seq) - 1)
                )
        assert (log.stop == "budget") == (len(s.views) == log.max_views)
        assert (log.stop == "complete") == all(log.complete)
        assert any(v.status == "fused" for v in s.views) and s.selection.any()
        # anchors from the session's own plan, then training cameras added as manual
        # anchors (every plan anchor complete here: its clicks hold their surface in the
        # selection); the user never looked at a test camera
        names = [a.full_camera.name for a in s.anchors]
        assert names[: len(s.plan.anchors)] == [a.camera.name for a in s.plan.anchors]
        plan = {a.camera.name for a in s.plan.anchors + s.plan.candidates}
        assert set(names) <= plan | {c.name for c in sc.cameras}
        test_poses = [t.c2w for t in sc.test_cameras]
        assert rec.cameras and not any(
            np.allclose(c.c2w, t) for c in rec.cameras for t in test_poses
        )
        assert not set(log.looked_at) & {t.name for t in sc.test_cameras}
    finally:
        s.close()


def test_scripted_user_per_anchor_cap(user_scene):
    """The optional hard cap on clicks per anchor."""
    from divas_engine.evaluation.scripted_user import UserBudget

    s, user, _, _ = _user_session(user_scene, UserBudget(clicks_per_anchor=1, manual_anchors=0))
    try:
        log = user.run(s)
        per = np.bincount([c.anchor for c in log.clicks], minlength=len(s.anchors))
        assert per.max() == 1
        for a, st in enumerate(log.anchor_status):
            assert st != "clicks" or per[a] == 1
        assert "clicks" in log.anchor_status or log.stop == "complete"
    finally:
        s.close()
    with pytest.raises(ValueError, match="clicks_per_anchor"):
        UserBudget(clicks_per_anchor=0)
    with pytest.raises(ValueError, match="max_failed_clicks"):
        UserBudget(max_failed_clicks=0)


def test_scripted_user_stops_at_the_view_budget(user_scene):
    from divas_engine.evaluation.scripted_user import UserBudget

    s, user, _, checked = _user_session(user_scene, UserBudget(max_views=1))
    try:
        log = user.run(s)
        assert len(s.views) == 1 and log.stop == "budget"
        assert all(t and not c for _, t, c in checked) and len(checked) == 1
        assert "budget" in log.anchor_status
        after = log.anchor_status[log.anchor_status.index("budget") + 1 :]
        assert set(after) <= {"not visited"}
    finally:
        s.close()


def test_scripted_user_adds_training_cameras_as_manual_anchors():
    """Plant: c_scene lies on the floor, below the plant, so most Fibonacci anchors miss
    it; with ``manual_anchors`` the user adds training cameras showing uncovered target
    (never a test camera) and the selection's recall grows."""
    from divas_engine.evaluation.metrics import surfel_scores
    from divas_engine.evaluation.scripted_user import UserBudget
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("plant", size=6000, seed=0)
    recall = []
    for n in (0, 3):
        s, user, rec, checked = _user_session(sc, UserBudget(manual_anchors=n))
        try:
            n_plan = len(s.anchors)
            log = user.run(s)
            assert len(log.manual) <= n and len(s.anchors) == n_plan + len(log.manual)
            for a, i in zip(s.anchors[n_plan:], log.manual):
                assert (a.source, a.source_index) == ("training", i)
                assert a.full_camera is sc.cameras[i]
            assert len(set(log.manual)) == len(log.manual)
            assert all(t and not c for _, t, c in checked), checked
            test_poses = [t.c2w for t in sc.test_cameras]
            assert not any(np.allclose(c.c2w, t) for c in rec.cameras for t in test_poses)
            recall.append(surfel_scores(s.selection, sc.labels)["recall"])
            if n:
                assert log.manual and any(c.anchor >= n_plan for c in log.clicks)
        finally:
            s.close()
    assert recall[1] > recall[0]


def test_run_session_user_protocol_feeds_the_accepted_masks(user_scene):
    from divas_engine.evaluation.pipeline import make_segmenter, run_session
    from divas_engine.evaluation.scripted_user import ScriptedUser
    from divas_engine.session import SessionConfig

    sc = user_scene
    with pytest.raises(ValueError):
        run_session(sc.scene, sc.cameras, sc.labels, segmenter=make_segmenter("oracle"))
    out = run_session(
        sc.scene,
        sc.cameras,
        sc.labels,
        segmenter=make_segmenter("oracle"),
        config=SessionConfig(render_scale=0.25),
        device=CPU,
        user=ScriptedUser(sc.labels),
    )
    fused = [vid for vid, st, _ in out.statuses if st == "fused"]
    assert out.user_log is not None and len(out.statuses) == len(out.user_log.clicks)
    assert len(out.views) == len(fused) > 0 and out.selection.any()
    assert all(v.mask.shape == (v.camera.height, v.camera.width) for v in out.views)


def test_clicks_protocol_still_selectable(user_scene):
    from divas_engine.evaluation.pipeline import make_segmenter, run_session, scripted_anchors
    from divas_engine.evaluation.suite import SuiteConfig, markdown_table
    from divas_engine.session import SessionConfig

    sc = user_scene
    anchors = scripted_anchors(sc.metadata, sc.cameras)
    out = run_session(
        sc.scene,
        sc.cameras,
        sc.labels,
        anchors,
        segmenter=make_segmenter("oracle"),
        config=SessionConfig(render_scale=0.25),
        device=CPU,
    )
    assert out.user_log is None
    assert len(out.statuses) == sum(len(a[3]) for a in anchors)
    assert [n for n, _, _ in out.anchors] == [a[0].name for a in anchors]
    with pytest.raises(ValueError):
        SuiteConfig(protocol="nope")
    text = markdown_table({"rows": [], "config": {"protocol": "clicks"}})
    assert "View protocol: clicks" in text


def test_multi_seed_means_and_targets():
    """Targets are checked on the per-scene means over the seeds; per-seed wins counted."""
    from divas_engine.evaluation.suite import (
        SuiteConfig,
        check_targets,
        markdown_table,
        scene_means,
        suite_means,
    )

    iou = {  # (scene, method) → IoU per seed 0, 1
        ("ribs", "full"): (0.90, 0.92),
        ("ribs", "no_thin"): (0.85, 0.86),
        ("ribs", "centre_vote"): (0.91, 0.89),
        ("ribs", "contrib_vote"): (0.80, 0.80),
        ("plant", "full"): (0.80, 0.78),
        ("plant", "no_thin"): (0.5, 0.5),
        ("plant", "centre_vote"): (0.81, 0.72),
        ("plant", "contrib_vote"): (0.4, 0.4),
    }
    rows = [
        {
            "scene": sc,
            "seed": k,
            "kind": "2dgs",
            "segmenter": "oracle",
            "method": m,
            "label": m,
            "iou": v[k],
            "accuracy": 0.99,
            "precision_3d": None,
            "recall_3d": 0.5 + k / 10,
        }
        for (sc, m), v in iou.items()
        for k in (0, 1)
    ]
    per = {(r["scene"], r["method"]): r for r in scene_means(rows)}
    assert per[("plant", "full")]["iou"] == pytest.approx(0.79)
    assert per[("plant", "full")]["iou_seeds"] == [0.80, 0.78]
    assert (per[("ribs", "centre_vote")]["iou_min"], per[("ribs", "centre_vote")]["iou_max"]) == (
        0.89,
        0.91,
    )
    assert per[("ribs", "full")]["recall_3d"] == pytest.approx(0.55)
    assert per[("ribs", "full")]["precision_3d"] is None
    t = check_targets(rows)
    assert t["seeds"] == [0, 1]
    assert t["mean_full_iou"] == pytest.approx((0.91 + 0.79) / 2)
    assert not t["mean_full_iou_ge_0.90"]
    # means: ribs 0.91 ≥ 0.90 (centre) — plant 0.79 ≥ 0.765; per seed: ribs wins seed 1 only,
    # plant seed 1 only (0.80 < 0.81 in seed 0)
    assert t["full_beats_baselines"] == {"plant": True, "ribs": True}
    assert t["full_beats_baselines_seeds"] == {"plant": 1, "ribs": 1}
    assert t["ribs_thin_path_helps"]
    m = {r["method"]: r for r in suite_means(scene_means(rows))}
    assert m["full"]["scenes"] == 2 and m["full"]["iou"] == pytest.approx(0.85)
    text = markdown_table(
        {
            "rows": rows,
            "scene_means": scene_means(rows),
            "means": suite_means(scene_means(rows)),
            "targets": t,
        }
    )
    assert "| ribs | 1 | oracle | full | 0.920 |" in text
    assert "Mean over seeds 0, 1" in text and "0.890–0.910" in text
    assert "plant yes (1/2 seeds)" in text
    assert SuiteConfig(seeds=(3, 4)).run_seeds == (3, 4) and SuiteConfig(seed=5).run_seeds == (5,)
    with pytest.raises(ValueError):
        SuiteConfig(seeds=(1, 1))
    # `--no-ablations`: no no_thin rows — the thin-path claim is left out, not a KeyError
    lean = check_targets([r for r in rows if r["method"] != "no_thin"])
    assert "ribs_thin_path_helps" not in lean
    assert lean["full_beats_baselines"] == {"plant": True, "ribs": True}
    only_full = check_targets([r for r in rows if r["method"] == "full"])
    assert set(only_full) == {"seeds", "mean_full_iou", "mean_full_iou_ge_0.90"}
    lean_text = markdown_table({"rows": [], "targets": only_full})
    assert "mean DivAS-full IoU 0.850" in lean_text and "baselines" not in lean_text


def test_eval_cli_seeds_argument():
    import argparse

    from divas_engine.cli import evaluate

    p = argparse.ArgumentParser()
    evaluate.add_parser(p.add_subparsers())
    assert p.parse_args(["eval", "--seeds", "0,1,2"]).seeds == (0, 1, 2)
    assert p.parse_args(["eval"]).seeds is None
    for bad in ("0,0", "a,1", ","):
        with pytest.raises(SystemExit):
            p.parse_args(["eval", "--seeds", bad])


def test_evaluate_suite_runs_every_seed(monkeypatch):
    """The suite runs each scene once per seed (scene and segmenter seeded alike) and
    averages per scene over the seeds before the targets."""
    from divas_engine.evaluation import suite

    calls = []

    def fake_scene(name, config, *, device=None, log=None):
        calls.append((name, config.seed, config.seeds))
        return [
            {
                "scene": name,
                "seed": config.seed,
                "kind": "2dgs",
                "segmenter": "oracle",
                "method": m,
                "label": m,
                "iou": 0.5 + 0.1 * config.seed + d,
                "accuracy": 1.0,
                "precision_3d": 1.0,
                "recall_3d": 1.0,
            }
            for m, d in (
                ("full", 0.02),
                ("no_thin", 0.0),
                ("centre_vote", 0.01),
                ("contrib_vote", 0.0),
            )
        ]

    monkeypatch.setattr(suite, "evaluate_scene", fake_scene)
    res = suite.evaluate_suite(
        suite.SuiteConfig(scenes=("ribs", "plant"), seeds=(2, 0), segmenters=("oracle",))
    )
    assert calls == [("ribs", 2, ()), ("plant", 2, ()), ("ribs", 0, ()), ("plant", 0, ())]
    assert res["config"]["seeds"] == [2, 0]
    full = [r for r in res["scene_means"] if r["method"] == "full"]
    assert len(full) == 2 and all(r["iou"] == pytest.approx(0.62) for r in full)
    assert res["targets"]["mean_full_iou"] == pytest.approx(0.62)
    assert res["targets"]["full_beats_baselines_seeds"] == {"plant": 2, "ribs": 2}


def test_scripted_user_declines_a_leaked_preview(user_scene):
    """A preview that selects more background than target is not accepted (precision
    < min_accept_precision): the view stays open and unfused and the user clicks again;
    with min_accept_precision = 0 every view is accepted."""
    from divas_engine.evaluation.scripted_user import ScriptedUser, UserBudget
    from divas_engine.session import Session, SessionConfig, anchor_plan

    sc = user_scene
    cfg = SessionConfig(render_scale=0.25)
    for thr, fused in ((0.5, False), (0.0, True)):
        user = ScriptedUser(
            sc.labels,
            UserBudget(
                min_accept_precision=thr,
                clicks_per_anchor=2,
                max_views=4,
                negative_clicks=False,
                manual_anchors=0,
            ),
        )
        s = Session.open(
            sc.scene,
            sc.cameras,
            cfg,
            ConstantSegmenter(1.0),
            CPU,
            anchors=user.anchors(anchor_plan(sc.scene, sc.cameras, cfg)),
            gt_values=sc.labels.astype(np.float32),
            render_anchors=False,
        )
        try:
            log = user.run(s)
            assert log.clicks
            statuses = {c.status for c in log.clicks} - {"no surface"}
            if fused:
                assert statuses == {"fused"} and s.selection.any()
            else:
                assert statuses == {"declined"} and not s.selection.any()
                assert s.fusion.view_ids == []
                assert all(v.status not in ("fused", "rejected") for v in s.views)
                assert log.as_dict()["declined"] == len(log.clicks) - sum(
                    c.status == "no surface" for c in log.clicks
                )
        finally:
            s.close()
    with pytest.raises(ValueError):
        UserBudget(min_accept_precision=1.5)


def test_scripted_user_gives_up_on_an_anchor_without_progress(user_scene):
    """A segmenter sure of an empty mask never covers anything: the user clicks each
    anchor exactly ``max_failed_clicks`` times (no hard cap), marks it stalled and
    moves on — it does not spend the whole view budget on one anchor."""
    from divas_engine.evaluation.scripted_user import ScriptedUser, UserBudget
    from divas_engine.session import CorrectionConfig, Session, SessionConfig, anchor_plan

    sc = user_scene
    # the paper's loop: a refused view changes nothing (with corrections on, its click
    # would still select the spot it was made on: tests/test_click_pixel.py)
    cfg = SessionConfig(render_scale=0.25, corrections=CorrectionConfig(enabled=False))
    for k in (1, 2):
        user = ScriptedUser(
            sc.labels,
            UserBudget(max_failed_clicks=k, manual_anchors=0, max_views=50, negative_clicks=False),
        )
        s = Session.open(
            sc.scene,
            sc.cameras,
            cfg,
            ConstantSegmenter(0.0),
            CPU,
            anchors=user.anchors(anchor_plan(sc.scene, sc.cameras, cfg)),
            gt_values=sc.labels.astype(np.float32),
            render_anchors=False,
        )
        try:
            log = user.run(s)
            per = np.bincount([c.anchor for c in log.clicks], minlength=len(s.anchors))
            visited = [a for a, st in enumerate(log.anchor_status) if st != "complete"]
            assert visited and all(log.anchor_status[a] == "stalled" for a in visited)
            assert all(per[a] == k for a in visited) and log.stop == "incomplete"
            assert not s.selection.any()
        finally:
            s.close()


def test_leak_free_fraction_by_hand():
    """Precision against the target dilated by 2⌈max(H,W)/256⌉ px (a disc)."""
    from divas_engine.evaluation.scripted_user import leak_free_fraction

    tgt = np.zeros((100, 300), bool)  # max side 300 → k = 2·⌈300/256⌉ = 4 px
    tgt[40:60, 100:110] = True
    halo = np.zeros_like(tgt)
    halo[40:60, 96:114] = True  # 4 px left and right of the target: forgiven
    halo[36:64, 100:110] = True  # 4 px above and below: forgiven
    assert leak_free_fraction(halo, tgt) == 1.0
    wide = np.zeros_like(tgt)
    wide[40:60, 100:116] = True  # columns 114, 115 lie 5–6 px off: 2 × 20 px leak
    assert leak_free_fraction(wide, tgt) == pytest.approx(1 - 40 / 320)
    spilled = np.ones_like(tgt)  # a preview spilled over the whole view
    assert leak_free_fraction(spilled, tgt) < 0.1
    assert leak_free_fraction(np.zeros_like(tgt), tgt) == 1.0
