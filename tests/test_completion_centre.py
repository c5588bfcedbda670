"""The voxel's claim tested at the Gaussian's own centre (``CompletionConfig.centre_evidence``):
a Gaussian that joins only because its centre voxel is segmented or
filled must itself lie on / within the solid depth behind a mask-positive surface in some
view and be inconsistent in none. Hand-set counters on the ball of ``test_completion``;
the plain reference there states the rule too."""

from __future__ import annotations

import numpy as np

from divas_engine.fusion.occupancy import GridConfig, build_occupancy
from divas_engine.mapping import SurfelMapper
from divas_engine.mapping.completion import VolumetricCompletion
from divas_engine.mapping.completion_records import centre_evidence
from divas_engine.mapping.config import CompletionConfig
from tests.test_completion import (
    CPU,
    _ball_scene,
    _plain_centre_ok,
    _reference_complete,
    _views,
)


def test_voxel_claim_checked_at_the_centre():
    scene, labels, parts = _ball_scene()
    grid = build_occupancy(scene, GridConfig(), CPU)
    act = SurfelMapper(scene, grid, device=CPU).active_index
    views = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3), (-1, 0.2, -0.3)])
    means = np.asarray(scene.means, np.float64)
    k = parts["surface"].stop
    front = np.zeros(len(labels), bool)
    front[:k] = means[:k, 2] < 0
    floater = np.arange(parts["floater"].start, parts["floater"].stop)
    inner = np.arange(k, parts["interior"].stop)[:40]  # inside the ball: hidden in every view
    assert (act[floater] >= 0).all() and (act[inner] >= 0).all()
    seg = np.zeros(len(grid), bool)
    seg[act[front]] = True
    seg[act[floater]] = True  # a voxel the fusion got wrong
    seg[act[inner]] = True
    got = {}
    for on in (False, True):
        cfg = CompletionConfig(centre_evidence=on, sparse_gather=False)
        comp = VolumetricCompletion(scene, grid, act, cfg, device=CPU)
        for i, v in enumerate(views):
            comp.add_view(i, v)
        # no contribution evidence of their own: only their voxels speak for them
        for g in (floater, inner):
            comp.q1[g] = comp.q0[g] = 0
            comp.n_seen[g] = comp.n_deep_ok[g] = comp.n_deep_bad[g] = 0
        res = comp.complete(front, seg)
        assert res.near[floater].all() and res.near[inner].all()
        got[on] = (res.selected[floater].copy(), res.selected[inner].copy())
        out, _, _ = _reference_complete(comp, front, seg)
        assert np.array_equal(res.selected, out)
        if on:
            # the floater 1.2 in front of the ball floats in front of the mask in view 0
            assert not any(_plain_centre_ok(comp, means[i]) for i in floater)
            assert all(_plain_centre_ok(comp, means[i]) for i in inner)
    assert got[False][0].all() and got[False][1].all()  # the voxel alone adds both
    assert not got[True][0].any() and got[True][1].all()  # the centre test keeps the inside


def test_centre_evidence_by_hand():
    """Analytic view: a camera on −z looking at a disc mask of radius R = 10 px whose
    surface is at depth 4 (f = 80 px). Behind the disc's centre a solid of that silhouette
    reaches the full chord 2R ≈ 20–21 px, in world units at the point's depth z:
    2R z / f, plus the surface margin 2 h_v = 0.1 — 1.35 or more at z = 5, at most 1.68 at
    z = 6."""
    from divas_engine.camera import Camera
    from divas_engine.fusion.views import FusionView
    from divas_engine.mapping.completion_records import edge_distance

    cam = Camera.look_at(
        np.array([0.0, 0.0, -4.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]),
        width=96, height=96, fx=80.0,
    )  # fmt: skip
    yy, xx = np.mgrid[0:96, 0:96] + 0.5
    disc = (xx - 48) ** 2 + (yy - 48) ** 2 <= 10**2
    d_ref = np.where(disc, 4.0, 0.0).astype(np.float32)
    z0 = np.zeros((96, 96), np.float32)
    view = FusionView(cam, disc.astype(np.float32), z0, d_ref, z0, z0.astype(np.int32), 4.0)

    from divas_engine.render.config import RenderConfig

    class _C:  # what centre_evidence reads of a completion
        config = CompletionConfig(surface_margin=2.0)
        h = 0.05
        render_config = RenderConfig()

    rho = edge_distance(disc)
    pts = np.array(
        [
            [0.0, 0.0, 0.0],  # on the surface (planar depth 4 = D_med)
            [0.0, 0.0, 1.0],  # 1 behind (z = 5): within the solid depth (≥ 1.35)
            [0.0, 0.0, 2.0],  # 2 behind (z = 6): deeper than it (≤ 1.68) — says nothing
            [0.0, 0.0, -1.0],  # 1 in front of the surface: a floater
            [3.0, 0.0, 0.0],  # beside the disc, on a negative pixel it is visible at
        ]
    )
    ok = centre_evidence(_C, [(view, disc, rho)], pts)
    assert ok.tolist() == [True, True, False, False, False]
    # a point good in one view and inconsistent in another fails
    ok2 = centre_evidence(_C, [(view, disc, rho), (view, ~disc, edge_distance(~disc))], pts[:1])
    assert ok2.tolist() == [False]


def test_centre_masks_follow_undo_and_sync():
    """The per-view masks the rule reads are those of the live views after any add / undo
    / sync (a key whose view changed gets the new view's mask), and the decision with the
    rule on equals the one of the same views added once."""
    scene, labels, parts = _ball_scene()
    grid = build_occupancy(scene, GridConfig(), CPU)
    act = SurfelMapper(scene, grid, device=CPU).active_index
    views = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3), (-1, 0.2, -0.3)])
    cfg = CompletionConfig(centre_evidence=True)
    means = np.asarray(scene.means, np.float64)
    k = parts["surface"].stop
    sel = np.zeros(len(labels), bool)
    sel[:k] = means[:k, 2] < 0
    seg = np.zeros(len(grid), bool)
    seg[act[sel]] = True
    inc = VolumetricCompletion(scene, grid, act, cfg, device=CPU)
    inc.add_view(0, views[0])
    inc.add_view(1, views[1])
    assert len(inc._live_masks()) == 2
    inc.complete(sel, seg)
    inc.sync([(0, views[0]), (1, views[2])])  # key 1 now holds another view
    for (v, pos, rho), key in zip(inc._live_masks(), inc.keys):
        ref_pos, ref_rho = inc._mask(v)
        assert np.array_equal(pos, ref_pos) and np.array_equal(rho, ref_rho)
        assert v is inc._records[key][0]
    inc.remove_view(0)
    assert 0 not in inc._masks
    inc.add_view(0, views[0])
    batch = VolumetricCompletion(scene, grid, act, cfg, device=CPU)
    batch.add_view(0, views[0])
    batch.add_view(1, views[2])
    assert np.array_equal(inc.complete(sel, seg).selected, batch.complete(sel, seg).selected)
