"""The session history (undo / redo of any step,
the fusion reconciled bit-exactly) and manual edits composed with the semantic
selection, saved and replayed."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.kinds import ViewStatus
from divas_engine.segment import OracleSegmenter
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene

SCALE = 0.5


@pytest.fixture(scope="module")
def ribs(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs_history")
    sc = generate_scene("ribs", out, size=12_000, seed=1, grid_resolution=40)
    scene = load_scene(out / "scene.ply")
    names = [c.name for c in sc.cameras]
    anchors, clicks = [], []
    for c in sc.metadata["clicks"][:3]:
        vis = c["visible_in"]
        anchors.append(sc.cameras[names.index(vis[len(vis) // 2])])
        clicks.append(np.array(c["xyz"]))
    return sc, scene, anchors, clicks


def _open(ribs, **cfg):
    sc, scene, anchors, _ = ribs
    return Session.open(
        scene,
        sc.cameras,
        SessionConfig(render_scale=SCALE, **cfg),
        OracleSegmenter(),
        "cpu",
        anchors=anchors,
        gt_values=sc.labels,
        render_anchors=False,
    )


def _xy(s, i, xyz):
    return s.anchors[i].camera.project(xyz[None])[0][0]


def _state(s):
    """What must be equal after going back to a step: the selection (semantic and
    final), the labels, the views with their status, the clicks, the fusion
    accumulators (bit-exact) and the manual layers."""
    return {
        "selection": s.selection.copy(),
        "semantic": s.semantic_selection.copy(),
        "labels": s.label_set().copy(),
        "views": [(v.id, str(v.status)) for v in s.views],
        "objects": [(o.name, o.finished, len(o.views)) for o in s.objects],
        "clicks": {a: [c.xy for c in cs] for a, cs in s.current.clicks.items()},
        "anchors": len(s.anchors),
        "acc": s.fusion.accumulators(),
        "fusion_ids": sorted(s.fusion.view_ids),
        "deleted": None if s.edits.deleted is None else s.edits.deleted.copy(),
    }


def _assert_state(s, ref, where):
    got = _state(s)
    for k in ("selection", "semantic", "labels"):
        np.testing.assert_array_equal(got[k], ref[k], err_msg=f"{where}: {k}")
    for k in ("views", "objects", "clicks", "anchors", "fusion_ids"):
        assert got[k] == ref[k], f"{where}: {k}"
    for k, a in ref["acc"].items():
        np.testing.assert_array_equal(got["acc"][k], a, err_msg=f"{where}: accumulator {k}")
    if ref["deleted"] is None:
        assert got["deleted"] is None, where
    else:
        np.testing.assert_array_equal(got["deleted"], ref["deleted"], err_msg=where)


def test_undo_redo_any_step_is_exact(ribs):
    sc, scene, anchors, clicks = ribs
    s = _open(ribs)
    h = s.history
    refs = [(h.current.id, _state(s))]

    def step(what):
        h.record(what)
        refs.append((h.current.id, _state(s)))

    v0 = s.click(0, _xy(s, 0, clicks[0]))
    s.prompt(v0)
    step("click")
    s.accept(v0)
    step("accept")
    assert s.selection.sum() > 50
    v1 = s.click(1, _xy(s, 1, clicks[1]))
    step("click")
    s.prompt(v1, [(1.5, 1.5)], [0])
    step("prompt")
    s.accept(v1)
    step("accept")
    s.click(2, _xy(s, 2, clicks[2]), positive=False)
    step("negative click")
    # manual edit: drop the first 40 selected, add 25 unselected primitives
    sel = s.selection.copy()
    idx_on, idx_off = np.flatnonzero(sel)[:40], np.flatnonzero(~sel)[:25]
    new = sel.copy()
    new[idx_on], new[idx_off] = False, True
    s.apply_selection(new)
    step("manual edit")
    np.testing.assert_array_equal(s.selection, new)
    s.finish_object("ribs")
    step("finish")
    s.delete_primitives(np.arange(len(scene)) % 97 == 0)
    step("delete")
    s.add_anchor(anchors[0].scaled(0.5), "viewport", -1)
    step("anchor")
    assert [x[0] for x in refs] == [st.id for st in h.steps]
    # undo every step, checking each state; then redo every step
    for k in range(len(refs) - 2, -1, -1):
        assert h.undo() is h.steps[k]
        _assert_state(s, refs[k][1], f"undo to step {k} ({h.steps[k].what})")
    assert h.undo() is None and not h.can_undo
    for k in range(1, len(refs)):
        assert h.redo() is h.steps[k]
        _assert_state(s, refs[k][1], f"redo to step {k} ({h.steps[k].what})")
    assert h.redo() is None
    # jumps in both directions
    for k in (2, 9, 0, 5, 8, 3):
        h.goto(refs[k][0])
        _assert_state(s, refs[k][1], f"goto {k}")
    # the session goes on from a restored step; recording drops the redo branch
    h.goto(refs[4][0])
    assert v1.status == ViewStatus.OPEN and v1.preview is not None
    s.accept(v1)
    _assert_state(s, refs[5][1], "accept again after undo")
    h.record("accept again")
    assert not h.can_redo and len(h.steps) == 6
    with pytest.raises(KeyError):
        h.goto(refs[7][0])
    s.close()


def test_manual_edits_compose_with_later_views(ribs):
    """A splat removed by hand stays removed and one added stays added when a later
    view changes the semantic selection: F = ((S ∖ R) ∪ A) ∖ (D ∪ H)."""
    sc, scene, anchors, clicks = ribs
    s = _open(ribs)
    v0 = s.click(0, _xy(s, 0, clicks[0]))
    s.accept(v0)
    s0 = s.selection.copy()
    removed = np.zeros(len(scene), bool)
    removed[np.flatnonzero(s0)[::3]] = True
    added = np.zeros(len(scene), bool)
    added[np.flatnonzero(~s0)[:50]] = True
    s.apply_selection((s0 & ~removed) | added)
    v1 = s.click(1, _xy(s, 1, clicks[1]))
    s.accept(v1)
    sem = s.semantic_selection
    assert (sem & ~s0).any()  # the second view grew the semantic selection
    np.testing.assert_array_equal(s.selection, (sem & ~removed) | added)
    # hide deselects (by hand: it stays after reveal); delete is out for good
    hide = np.zeros(len(scene), bool)
    hide[np.flatnonzero(sem & ~removed)[:30]] = True
    s.hide_primitives(hide)
    np.testing.assert_array_equal(s.selection, ((sem & ~removed) | added) & ~hide)
    gone = np.zeros(len(scene), bool)
    gone[np.flatnonzero(sem)[30:60]] = True
    assert s.delete_primitives(gone) == 30
    assert s.delete_primitives(gone) == 0
    revealed = s.reveal_primitives()
    np.testing.assert_array_equal(revealed, hide)
    assert s.edits.hidden is None
    np.testing.assert_array_equal(s.selection, ((sem & ~removed) | added) & ~hide & ~gone)
    # ``within``: only those primitives change
    within = np.zeros(len(scene), bool)
    within[: len(scene) // 2] = True
    before = s.selection.copy()
    s.apply_selection(np.zeros(len(scene), bool), within=within)
    np.testing.assert_array_equal(s.selection, before & ~within)
    # a finished object's label never covers a deleted primitive
    s.finish_object()
    s.delete_primitives(s.objects[0].selection & (np.arange(len(scene)) % 2 == 0))
    assert not (s.label_set()[s.edits.deleted] != 0).any()
    assert not (s.objects[0].selection & s.edits.deleted).any()
    with pytest.raises(Exception, match="shape"):
        s.apply_selection(np.zeros(3, bool))
    s.close()


def test_edits_are_saved_and_replayed(ribs, tmp_path):
    sc, scene, anchors, clicks = ribs
    s = _open(ribs)
    v0 = s.click(0, _xy(s, 0, clicks[0]))
    s.accept(v0)
    sel = s.selection.copy()
    sel[np.flatnonzero(sel)[:20]] = False
    s.apply_selection(sel)
    s.finish_object("first")
    v1 = s.click(1, _xy(s, 1, clicks[1]))
    s.accept(v1)
    extra = np.zeros(len(scene), bool)
    extra[np.flatnonzero(~s.selection)[:10]] = True
    s.apply_selection(s.selection | extra)
    s.delete_primitives(np.arange(len(scene)) % 50 == 0)
    s.hide_primitives(np.arange(len(scene)) % 51 == 0)
    path = s.save(tmp_path / "edits.json")
    s2 = Session.load(path, scene, device="cpu")
    assert s2.replay_matches
    np.testing.assert_array_equal(s2.selection, s.selection)
    np.testing.assert_array_equal(s2.label_set(), s.label_set())
    np.testing.assert_array_equal(s2.edits.deleted, s.edits.deleted)
    np.testing.assert_array_equal(s2.edits.hidden, s.edits.hidden)
    s.close()
    s2.close()


def test_anchor_long_side(ribs):
    sc, scene, anchors, clicks = ribs
    s = _open(ribs, anchor_long_side=200)
    for a in s.anchors:
        assert max(a.camera.width, a.camera.height) == 200
        assert a.camera.fx / a.camera.width == pytest.approx(a.full_camera.fx / a.full_camera.width)
    b = s.add_anchor(anchors[0], "training", 0)
    assert max(b.camera.width, b.camera.height) == 200
    s.close()
    with pytest.raises(ValueError, match="anchor_long_side"):
        SessionConfig(anchor_long_side=-1)


def test_nerf_pending_views_follow_the_history(ribs):
    """NeRF: an accepted view waits for its anchor group (pending); undo forgets it,
    redo re-submits it, and the group's sync fuses it as without the detour."""
    sc, scene, anchors, clicks = ribs
    s = Session.open(
        sc.grid,
        sc.cameras,
        SessionConfig(render_scale=SCALE),
        OracleSegmenter(),
        "cpu",
        anchors=anchors[:1],
        gt_values=sc.grid_labels,
        render_anchors=False,
    )
    h = s.history
    xy = _xy(s, 0, clicks[0])
    v0 = s.click(0, xy)
    v1 = s.click(0, (xy[0] + 2.0, xy[1] + 1.0))
    h.record("clicks")
    r = s.accept(v0)
    assert r.status == ViewStatus.PENDING and not r.synced
    h.record("accept (pending)")
    h.undo()
    assert v0.status == ViewStatus.OPEN and s.state.pending == []
    h.redo()
    assert v0.status == ViewStatus.PENDING and s.state.pending == [v0]
    r = s.accept(v1)  # ends the anchor group: both are segmented and fused together
    assert r.synced and sorted(r.fused) == sorted([v0.id, v1.id])
    sel = s.selection.copy()
    assert sel.any()
    h.record("accept (sync)")
    h.goto(h.steps[1].id)
    assert not s.selection.any() and s.fusion.view_ids == []
    h.goto(h.steps[-1].id)
    np.testing.assert_array_equal(s.selection, sel)
    s.close()
