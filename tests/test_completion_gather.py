"""The 3DGS completion's sparse gather: a view's records are gathered only for
the Gaussians of a cover of the selection's neighbourhood, from the surfels that can blend
before them. References: the full rasterizer pass's records (``sparse_gather=False``) —
bit-equal on every covered Gaussian — and the completion decided on full records: the
same selection, also when the fill grows the neighbourhood beyond the first cover (the
re-gather fires), under undo, and with the full-pass fallback."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.fusion import GridConfig, build_occupancy
from divas_engine.mapping import CompletionConfig, SurfelMapper
from divas_engine.mapping.completion import VolumetricCompletion
from divas_engine.mapping.completion_gather import sparse_contributions
from divas_engine.render.surfel_blocks import screen_box

from .test_completion import CPU, _ball_scene, _divas_like, _views


@pytest.fixture(scope="module")
def ball():
    """The solid ball of ``test_completion`` (surface, interior, floater, back wall),
    four views."""
    scene, labels, parts = _ball_scene()
    grid = build_occupancy(scene, GridConfig(), CPU)
    act = SurfelMapper(scene, grid, device=CPU).active_index
    views = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3), (-1, 0.2, -0.3), (0, 1, -0.5)])
    return scene, labels, parts, grid, act, views


def _cap(labels, parts, act, a, scene, lo=0.4):
    """A part of the ball: its surface Gaussians with ``x > lo`` and their voxels."""
    sel = np.zeros(len(labels), bool)
    idx = np.arange(parts["surface"].start, parts["surface"].stop)
    sel[idx[np.asarray(scene.means)[idx, 0] > lo]] = True
    seg = np.zeros(a, bool)
    seg[act[sel & (act >= 0)]] = True
    return sel, seg


def _covered(comp, rec) -> np.ndarray:
    out = np.ones(comp.n, bool)
    if rec.cover is not None:
        out[:] = False
        out[comp.cells.members(rec.cover)] = True
    return out


def _same_records(comp, full) -> int:
    """Every live record of ``comp`` equals ``full``'s on its covered Gaussians (and
    holds nothing else); returns the number of Gaussians left uncovered."""
    left = 0
    for key, (_, rec) in comp._records.items():
        ref = full._records[key][1]
        cov = _covered(comp, rec)
        left += int((~cov).sum())
        keep = cov[ref.gauss]
        o = np.argsort(rec.gauss)
        for f in ("gauss", "q1", "q0", "seen", "deep"):
            assert np.array_equal(getattr(ref, f)[keep], getattr(rec, f)[o]), (key, f)
        # the voxel part: the full record's on the cover's voxels, nothing else
        vcov = np.ones(comp.a, bool)
        if rec.cover is not None:
            vcov[:] = False
            vcov[comp.cells.voxels_in(np.flatnonzero(rec.cover))] = True
        keep = vcov[ref.voxels]
        o = np.argsort(rec.voxels)
        assert np.array_equal(ref.voxels[keep], rec.voxels[o]), key
        assert np.array_equal(ref.flags[keep], rec.flags[o]), key
    return left


def _pair(ball, **kw):
    """A sparse and a full completion; the sparse one never declines the sparse pass
    (the ball scene is small: the surfels before a part of it are most of the scene)
    unless ``gather_max_fraction`` is given."""
    scene, labels, parts, grid, act, views = ball
    kw.setdefault("gather_max_fraction", 1.0)
    sp = VolumetricCompletion(scene, grid, act, CompletionConfig(**kw), device=CPU)
    full = VolumetricCompletion(
        scene, grid, act, CompletionConfig(sparse_gather=False, **kw), device=CPU
    )
    return sp, full


def test_sparse_sums_equal_the_full_pass(ball):
    """The contribution sums of a few Gaussians from the surfels that can blend before
    them are the full pass's, bit for bit, from a sub-scene smaller than the scene."""
    scene, labels, parts, grid, act, views = ball
    sp, _ = _pair(ball)
    rows = np.flatnonzero(_cap(labels, parts, act, len(grid), scene)[0])
    _, reach = sp._renderer.sparse_index()
    means = sp._renderer.surfel_buffers.means.numpy()
    shown, boxes = [], []
    for v in views:
        boxes.append(screen_box(v.camera, means[rows], reach[rows], sp._renderer._margin_px))
        pos = np.asarray(v.mask) >= 0.5
        full = sp._renderer.contributions(v.camera, pos)
        a1, a0, n_sub = sparse_contributions(sp._renderer, v.camera, pos, rows, 1.0)
        assert 0 < n_sub < len(labels)
        assert np.array_equal(a1, full.a1.numpy()[rows])
        assert np.array_equal(a0, full.a0.numpy()[rows])
        shown.append(float((a1 + a0).sum()))
    assert max(shown) > 20.0  # the Gaussians do show (pixels of weight)
    # the pass walked a window smaller than the image in some view (the windowed walk)
    assert any(
        isinstance(b, tuple) and (b[2] - b[0]) * (b[3] - b[1]) < 0.5 * 96 * 96 for b in boxes
    )
    # above the fraction the sparse pass declines (the caller takes the full pass)
    v = views[0]
    pos = np.asarray(v.mask) >= 0.5
    assert sparse_contributions(sp._renderer, v.camera, pos, rows, 0.0) is None


@pytest.mark.parametrize("margin", [0, 2])
def test_selection_equals_full_gather(ball, margin):
    """The completion on sparse records equals the completion on full records, for the
    DivAS-like start, a part of the ball and random selections; the records are the full
    ones on their covers, and with a part selected some Gaussians stay uncovered."""
    scene, labels, parts, grid, act, views = ball
    rng = np.random.default_rng(margin)
    starts = [
        _cap(labels, parts, act, len(grid), scene, 0.6),
        _divas_like(labels, parts, act, len(grid)),
        (rng.random(len(labels)) < 0.03, rng.random(len(grid)) < 0.01),
    ]
    for sel, seg in starts:
        sp, full = _pair(ball, gather_margin=margin)
        for i, v in enumerate(views):
            sp.add_view(i, v)
            full.add_view(i, v)
        rs, rf = sp.complete(sel, seg), full.complete(sel, seg)
        assert np.array_equal(rs.selected, rf.selected)
        assert np.array_equal(rs.filled_voxels, rf.filled_voxels)
        assert np.array_equal(rs.near, rf.near)
        _same_records(sp, full)
    # the cap alone: the records cover a part of the scene only
    sp, full = _pair(ball, gather_margin=margin)
    sel, seg = starts[0]
    sp.add_view(0, views[0])
    full.add_view(0, views[0])
    sp.complete(sel, seg)
    assert _same_records(sp, full) > 0


def test_neighbourhood_outgrows_the_cover(ball):
    """Records are gathered by the first decision for what it read (a second decision
    runs on them), widened when the voxel selection grows elsewhere (the neighbourhood
    the fill walks) and when the selection does (the drop test reads the selected
    Gaussians): the result is the full gather's each time, and undo stays exact."""
    scene, labels, parts, grid, act, views = ball
    sp, full = _pair(ball, gather_margin=0)
    for i, v in enumerate(views):
        sp.add_view(i, v)
        full.add_view(i, v)
    calls = []
    decide = sp._decide
    sp._decide = lambda s, g: calls.append(1) or decide(s, g)  # counts the decisions

    small = _cap(labels, parts, act, len(grid), scene, 0.8)
    res = sp.complete(*small)
    assert np.array_equal(res.selected, full.complete(*small).selected)
    # pending records were gathered before the first decision and widened (voxels and
    # Gaussians) to what each decision read: one decision more than widening rounds
    assert res.seconds["gathered"] >= len(views) and res.seconds["rounds"] >= 1
    assert len(calls) == res.seconds["rounds"] + 1
    calls.clear()
    res = sp.complete(*small)  # nothing new: no gather, one decision
    assert len(calls) == 1 and res.seconds["gathered"] == 0
    # the voxel selection grows to a far part of the scene (a corner of the back wall),
    # the Gaussian selection not: the records are widened to the new neighbourhood
    means = np.asarray(scene.means)
    corner = (means[:, 2] > 2.9) & (means[:, 0] > 1.7) & (means[:, 1] > 1.7)
    seg = small[1].copy()
    seg[act[corner & (act >= 0)]] = True
    before = [r.cover.copy() for _, r in sp._records.values()]
    calls.clear()
    res = sp.complete(small[0], seg)
    assert np.array_equal(res.selected, full.complete(small[0], seg).selected)
    assert res.seconds["gathered"] >= len(views) and len(calls) == res.seconds["rounds"] + 1
    for (_, r), b in zip(sp._records.values(), before):
        assert (r.cover >= b).all() and r.cover.sum() > b.sum()
        assert _covered(sp, r)[corner].all() and not _covered(sp, r).all()
    # the selection grows too (the ball's surface and the corner's Gaussians)
    big = _divas_like(labels, parts, act, len(grid))
    big[0][corner] = True
    big[1][:] |= seg
    res = sp.complete(*big)
    assert np.array_equal(res.selected, full.complete(*big).selected)
    _same_records(sp, full)
    # undo a view and re-add it (its pending record covers nothing until the decision)
    sp.remove_view(1)
    full.remove_view(1)
    sp.add_view(1, views[2])
    full.add_view(1, views[2])
    res = sp.complete(*big)
    assert np.array_equal(res.selected, full.complete(*big).selected)
    _same_records(sp, full)
    for k in list(sp.keys):
        sp.remove_view(k)
    counters = ("q1", "q0", "n_surf", "n_hidden", "n_incons", "n_seen", "n_deep_ok", "n_deep_bad")
    assert not any(getattr(sp, k).any() for k in counters)


def test_full_pass_fallback(ball):
    """When the surfels that can blend before the cover exceed ``gather_max_fraction`` of
    the scene the record is the full pass's (cover None), same decision."""
    scene, labels, parts, grid, act, views = ball
    sp, full = _pair(ball, gather_max_fraction=0.0)
    for i, v in enumerate(views):
        sp.add_view(i, v)
        full.add_view(i, v)
    sel, seg = _divas_like(labels, parts, act, len(grid))
    res = sp.complete(sel, seg)
    assert all(r.cover is None for _, r in sp._records.values())
    assert np.array_equal(res.selected, full.complete(sel, seg).selected)
    assert _same_records(sp, full) == 0
    for k in ("q1", "q0", "n_seen", "n_deep_ok", "n_deep_bad"):
        assert np.array_equal(getattr(sp, k), getattr(full, k)), k


def test_gather_config():
    with pytest.raises(ValueError):
        CompletionConfig(gather_margin=-1)
    with pytest.raises(ValueError):
        CompletionConfig(gather_max_fraction=1.5)
    from divas_engine.mapping import MappingConfig
    from divas_engine.session import SessionConfig

    c = CompletionConfig(sparse_gather=False, gather_margin=3)
    cfg = SessionConfig(mapping=MappingConfig(completion=c))
    assert SessionConfig.from_dict(cfg.to_dict()).mapping.completion == c


def test_window_pass_is_the_full_pass_inside_the_window(ball):
    """``accumulate_contributions(window=…)``: a surfel whose footprint bound lies inside the
    window gets the whole pass's A₁ / A₀ bit for bit; one the window cuts gets less; one
    outside it nothing."""
    from divas_engine.render.surfel_blocks import ball_pixel_bounds
    from divas_kernels import accumulate_contributions

    scene, labels, parts, grid, act, views = ball
    sp, _ = _pair(ball)
    r = sp._renderer
    _, reach = r.sparse_index()
    means = r.surfel_buffers.means.numpy()
    v = views[1]
    cam, pos = v.camera, np.asarray(v.mask) >= 0.5
    full = r.contributions(cam, pos)
    f1, f0 = full.a1.numpy(), full.a0.numpy()
    box = (20, 16, 70, 80)
    args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, pos)
    out = accumulate_contributions(
        r.surfel_buffers, *args, r.config.raster_settings(cam), window=box
    )
    w1, w0 = out.a1.numpy(), out.a0.numpy()
    lo, hi, front, _ = ball_pixel_bounds(cam, means, reach)
    m = r._margin_px + 1.0
    inside = front & (lo[:, 0] - m >= box[0]) & (lo[:, 1] - m >= box[1])
    inside &= (hi[:, 0] + m < box[2]) & (hi[:, 1] + m < box[3])
    outside = front & ((hi[:, 0] + m < box[0]) | (lo[:, 0] - m >= box[2]))
    shown = f1 + f0 > 0
    assert (inside & shown).sum() > 50 and (outside & shown).sum() > 50
    assert np.array_equal(w1[inside], f1[inside]) and np.array_equal(w0[inside], f0[inside])
    assert not (w1 + w0)[outside].any()
    cut = shown & ~inside & ~outside & (w1 + w0 > 0)
    assert cut.any() and ((w1 + w0)[cut] <= (f1 + f0)[cut] + 1e-6).all()
    assert ((w1 + w0)[cut] < (f1 + f0)[cut]).any()


def test_gather_from_the_kept_binning_equals_full(ball):
    """The session's case: the completion shares the renderer and each view was just
    rendered (its binning kept), so a record is gathered by walking that binning's tile
    lists up to each tile's last covered Gaussian — the same records on the cover and the
    same selections as the full pass, also after a view is undone and the cover grows."""
    from divas_engine.render import make_renderer

    scene, labels, parts, grid, act, views = ball
    r = make_renderer(scene, device=CPU)
    sp = VolumetricCompletion(
        scene, grid, act, CompletionConfig(gather_max_fraction=0.0), device=CPU, renderer=r
    )
    full = VolumetricCompletion(scene, grid, act, CompletionConfig(sparse_gather=False), device=CPU)
    assert sp._renderer is r
    cap = _cap(labels, parts, act, len(grid), scene, 0.6)
    for i, v in enumerate(views[:3]):
        r.render(v.camera)  # the accept's view: its binning is kept
        sp.add_view(i, v)
        full.add_view(i, v)
        res = sp.complete(*cap)
        assert np.array_equal(res.selected, full.complete(*cap).selected)
        # kept binnings are walked even with gather_max_fraction 0 (no sub-scene pass)
        assert all(rec.cover is not None for _, rec in sp._records.values())
    assert _same_records(sp, full) > 0
    # the direct gather reports the whole scene as walked source, and equals the pass
    v = views[2]
    pos = np.asarray(v.mask) >= 0.5
    rows = np.flatnonzero(cap[0])[::-1].copy()  # any order
    a1, a0, n_src = sparse_contributions(r, v.camera, pos, rows, 0.0)
    ref = r.contributions(v.camera, pos)
    assert n_src == len(labels)
    assert np.array_equal(a1, ref.a1.numpy()[rows]) and np.array_equal(a0, ref.a0.numpy()[rows])
    sp.remove_view(1)
    full.remove_view(1)
    big = _divas_like(labels, parts, act, len(grid))
    r.render(views[3].camera)
    sp.add_view(3, views[3])
    full.add_view(3, views[3])
    res = sp.complete(*big)
    assert np.array_equal(res.selected, full.complete(*big).selected)
    _same_records(sp, full)


def test_new_view_is_gathered_for_the_last_cover(ball):
    """After a decision, a view added for the same selection is gathered at once for the
    cover that decision needed (Gaussians and voxels): the next decision needs no
    widening round, and its result is the full records' — the accept a user waits for
    is one gather and one decision."""
    scene, labels, parts, grid, act, views = ball
    sp, full = _pair(ball)
    sel, seg = _cap(labels, parts, act, len(grid), scene, 0.5)
    for i, v in enumerate(views[:2]):
        sp.add_view(i, v)
        full.add_view(i, v)
    first = sp.complete(sel, seg)
    assert first.seconds["gathered"] >= 2
    for i in (2, 3):
        sp.add_view(i, views[i])
        full.add_view(i, views[i])
        rec = sp._records[i][1]
        assert rec.cover is not None and rec.cover.any() and rec.mask is None
        res = sp.complete(sel, seg)
        assert res.seconds["gathered"] == 0 and res.seconds["rounds"] == 0
        assert np.array_equal(res.selected, full.complete(sel, seg).selected)
    _same_records(sp, full)
    # the same view undone and added again (the bench's accept): the same records
    before = {
        k: (r.gauss.copy(), r.q1.copy(), r.voxels.copy()) for k, (_, r) in sp._records.items()
    }
    sp.remove_view(3)
    sp.add_view(3, views[3])
    res = sp.complete(sel, seg)
    assert res.seconds["gathered"] == 0
    g, q1, vox = before[3]
    r = sp._records[3][1]
    assert np.array_equal(np.sort(g), np.sort(r.gauss)) and np.array_equal(
        np.sort(vox), np.sort(r.voxels)
    )
    assert np.array_equal(q1[np.argsort(g)], r.q1[np.argsort(r.gauss)])
