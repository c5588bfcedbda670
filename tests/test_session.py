"""The interactive Session (click → centroid view → prompt → accept →
fuse + map → overlay), exact undo, reset, save / autosave / replay, multiple objects and
the labelled PLY, the NeRF asynchronous SAM groups, and bad inputs."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from divas_engine import Camera, DivasInputError, load_scene
from divas_engine.errors import InputErrorCode
from divas_engine.io.ply import iter_vertex_chunks, read_ply_header
from divas_engine.kinds import RejectReason
from divas_engine.segment import OracleSegmenter, Rejection
from divas_engine.session import LABEL_PROPERTY, Session, SessionConfig, WideningConfig
from divas_engine.synthetic import generate_scene

from .stub_segmenters import ConstantSegmenter

SCALE = 0.5


@pytest.fixture(scope="module")
def ribs(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs")
    sc = generate_scene("ribs", out, size=20_000, seed=0, grid_resolution=64)
    scene = load_scene(out / "scene.ply")
    names = [c.name for c in sc.cameras]
    # one training camera per metadata click (spread over the ones that see it)
    anchors, clicks = [], []
    n = len(sc.metadata["clicks"])
    for k, c in enumerate(sc.metadata["clicks"]):
        vis = c["visible_in"]
        cam = sc.cameras[names.index(vis[(2 * k + 1) * len(vis) // (2 * n)])]
        anchors.append(cam)
        clicks.append(np.array(c["xyz"]))
    return sc, scene, anchors, clicks, out


def _click_xy(session, i, xyz):
    uv, _ = session.anchors[i].camera.project(xyz[None])
    return uv[0]


def _open(ribs, tmp_path=None, **cfg):
    sc, scene, anchors, clicks, _ = ribs
    config = SessionConfig(render_scale=SCALE, **cfg)
    return Session.open(
        scene,
        sc.cameras,
        config,
        OracleSegmenter(),
        "cpu",
        anchors=anchors,
        gt_values=sc.labels,
        render_anchors=False,
    )


def _open_grid(ribs, n_anchors, segmenter=None):
    """A NeRF-grid session on the ribs grid with the first ``n_anchors`` anchors."""
    sc, _, anchors, _, _ = ribs
    return Session.open(
        sc.grid,
        sc.cameras,
        SessionConfig(render_scale=SCALE),
        segmenter or OracleSegmenter(),
        "cpu",
        anchors=anchors[:n_anchors],
        gt_values=sc.grid_labels,
        render_anchors=False,
    )


def test_click_accept_undo_reset_save_replay(ribs, tmp_path):
    sc, scene, anchors, clicks, _ = ribs
    auto = tmp_path / "auto" / "session.json"
    # the paper's loop, one view per click (wider views: tests/test_widening.py)
    s = _open(ribs, autosave=str(auto), widening=WideningConfig(enabled=False))
    assert s.kind == "2dgs" and s.forward_facing and len(s.anchors) == 4
    assert s.anchors[0].camera.width == round(anchors[0].width * SCALE)
    v0 = s.click(0, _click_xy(s, 0, clicks[0]))
    assert v0.status == "open" and v0.buffers.rgb.shape[:2] == (v0.camera.height, v0.camera.width)
    assert v0.box is not None and v0.centroid.d_cam > 0
    prev = s.prompt(v0)
    assert prev.accepted and prev.mask.shape == v0.buffers.alpha.shape and prev.band is not None
    assert prev.labels.tolist() == [1]
    # saved from the open on (anchors), and after every click
    assert auto.exists() and len(Session.load(auto, scene, device="cpu").current.views) == 1
    r0 = s.accept(v0)
    assert r0.status == "fused" and r0.synced and r0.fused == [v0.id]
    sel0 = s.selection.copy()
    assert sel0.sum() > 100 and (sel0 & sc.labels).sum() / sel0.sum() > 0.95
    assert r0.overlay is not None and r0.overlay.mask.any()
    # the arrays file is content-addressed (named in the manifest), the arrays
    # of earlier saves are gone
    arrays_file = json.loads(auto.read_text())["arrays"]["file"]
    assert auto.exists() and (auto.parent / arrays_file).exists()
    assert sorted(p.name for p in auto.parent.iterdir()) == sorted(["session.json", arrays_file])
    acc0 = s.fusion.accumulators()
    # autosave replays to the same selection
    s_auto = Session.load(auto, scene, device="cpu")
    assert s_auto.replay_matches and np.array_equal(s_auto.selection, sel0)
    # a second view grows the selection
    v1 = s.click(1, _click_xy(s, 1, clicks[1]))
    v2 = s.click(2, _click_xy(s, 2, clicks[2]))
    r1 = s.accept(v1)
    assert r1.next_view is v2 and r1.next_overlay is not None  # propagation to the next view
    sel1 = s.selection.copy()
    assert sel1.sum() > sel0.sum()
    # exact undo: accumulators and selection as before
    assert s.undo() is v1 and v1.status == "open"
    assert np.array_equal(s.selection, sel0)
    for k, a in s.fusion.accumulators().items():
        assert np.array_equal(a, acc0[k]), k
    s.accept(v1)
    assert np.array_equal(s.selection, sel1)
    s.accept(v2)
    sel2 = s.selection.copy()
    with pytest.raises(ValueError, match="already accepted"):
        s.accept(v2)
    # save + replay: identical labels
    path = s.save(tmp_path / "manual.json")
    s2 = Session.load(path, scene, device="cpu")
    assert s2.replay_matches and np.array_equal(s2.selection, sel2)
    assert [v.status for v in s2.views] == ["fused", "fused", "fused"]
    assert s2.undo().id == v2.id and np.array_equal(s2.selection, sel1)
    rep = s.report()
    assert rep["timings"]["kernel"]["calls"] == 4 and rep["timings"]["mapping"]["calls"] >= 4
    assert {"render", "segmenter", "centroid", "overlay"} <= set(rep["timings"])
    assert rep["counts"]["accepted"] == 3 and rep["memory"]["peak_rss_bytes"] > 0
    # reset
    s.reset()
    assert not s.selection.any() and s.views == [] and s.fusion.view_ids == []
    assert s.undo() is None
    s.close()


def test_manual_anchor_is_clicked_saved_and_replayed(ribs, tmp_path):
    """Manual anchor selection: a training camera added after opening is an anchor like
    the planned ones — clickable, autosaved with the session and replayed."""
    sc, scene, anchors, clicks, _ = ribs
    auto = tmp_path / "session.json"
    s = _open(ribs, autosave=str(auto))
    names = [c.name for c in sc.cameras]
    cam = anchors[3]
    a = s.add_anchor(cam, "training", names.index(cam.name))
    assert a.index == 4 and len(s.anchors) == 5 and a.full_camera is cam
    assert a.camera.width == round(cam.width * SCALE)
    assert auto.exists()  # adding an anchor is user work: autosaved at once
    v = s.click(4, _click_xy(s, 4, clicks[3]))
    assert v.anchor == 4
    s.accept(v)
    sel = s.selection.copy()
    assert sel.any()
    s2 = Session.load(auto, scene, device="cpu")
    assert len(s2.anchors) == 5 and s2.anchors[4].source == "training"
    assert s2.anchors[4].source_index == names.index(cam.name)
    assert s2.replay_matches and np.array_equal(s2.selection, sel)
    with pytest.raises(TypeError, match="Camera"):
        s.add_anchor("IMG_0001")
    # a tampered hint (the view's advice) is a clear error naming the file, not a crash
    doc = json.loads(auto.read_text())
    doc["objects"][0]["views"][0]["advice"] = {"not": "text"}
    bad = tmp_path / "tampered.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(DivasInputError, match=r"tampered\.json.*advice"):
        Session.load(bad, scene, device="cpu")
    s.close()
    s2.close()


def test_multi_object_labels_and_labelled_ply(ribs, tmp_path):
    sc, scene, anchors, clicks, out = ribs
    s = _open(ribs)
    s.accept(s.click(1, _click_xy(s, 1, clicks[1])))
    first = s.selection.copy()
    rec = s.finish_object("skull")
    assert rec.label == 1 and rec.finished and not s.selection.any()
    s.accept(s.click(0, _click_xy(s, 0, clicks[0])))
    s.accept(s.click(3, _click_xy(s, 3, clicks[3])))
    second = s.selection.copy()
    labels = s.label_set()
    assert np.array_equal(labels == 1, first)
    assert np.array_equal(labels == 2, second & ~first)  # earlier objects keep their surfels
    assert s.current.label == 2
    files = s.export_objects(tmp_path / "objs")
    assert [o["label"] for o in files["objects"]] == [1, 2]
    assert read_ply_header(files["objects"][0]["path"]).vertex.count == first.sum()
    # labelled PLY: original rows byte-identical plus the divas_label column
    src = read_ply_header(out / "scene.ply")
    lab = read_ply_header(files["labelled"])
    assert lab.property_names == src.property_names + [LABEL_PROPERTY]
    orig = np.concatenate([c for _, c in iter_vertex_chunks(src)])
    got = np.concatenate([c for _, c in iter_vertex_chunks(lab)])
    names = list(orig.dtype.names)
    assert np.asarray(got[names], dtype=orig.dtype).tobytes() == orig.tobytes()
    assert np.array_equal(got[LABEL_PROPERTY], labels)
    # save/replay of a multi-object session
    s2 = Session.load(s.save(tmp_path / "multi.json"), scene, device="cpu")
    assert s2.replay_matches and np.array_equal(s2.label_set(), labels)
    assert [o.name for o in s2.objects] == ["skull", "object_2"]
    s.close()


def test_overwrite_labels_option(ribs):
    sc, scene, anchors, clicks, _ = ribs
    s = _open(ribs, overwrite_labels=True)
    s.accept(s.click(0, _click_xy(s, 0, clicks[0])))
    a = s.selection.copy()
    s.finish_object("a")
    s.accept(s.click(0, _click_xy(s, 0, clicks[0])))
    b = s.selection
    # the same click selects (almost) the same surfels: the oracle's mask noise is
    # seeded by the view's id, which names the object
    assert (a & b).sum() >= 0.99 * max(a.sum(), b.sum())
    labels = s.label_set()
    assert np.array_equal(labels == 2, b)  # the later object takes every surfel it selects
    assert np.array_equal(labels == 1, a & ~b)
    s.close()


def test_labelled_ply_of_a_generated_scene(ribs, tmp_path):
    from divas_engine.session import write_labelled_ply

    sc = ribs[0]
    lab = np.zeros(len(sc.scene), np.int32)
    lab[sc.labels] = 3
    p = write_labelled_ply(sc.scene, lab, tmp_path / "gen.ply")
    back = load_scene(p)
    assert len(back) == len(sc.scene) and np.allclose(back.means, sc.scene.means)
    rows = np.concatenate([c for _, c in iter_vertex_chunks(read_ply_header(p))])
    assert np.array_equal(rows[LABEL_PROPERTY], lab)


def test_bad_clicks_and_rejected_views(ribs):
    sc, scene, anchors, clicks, _ = ribs
    away = Camera.look_at(
        np.array([0.0, 0.0, 50.0]),
        np.array([0.0, 0.0, 100.0]),
        np.array([0.0, 1.0, 0.0]),
        width=200,
        height=150,
        fx=150,
        name="away",
    )
    s = Session.open(
        scene,
        sc.cameras,
        SessionConfig(render_scale=SCALE),
        OracleSegmenter(),
        "cpu",
        anchors=[anchors[0], away],
        gt_values=np.zeros(len(scene), bool),
        render_anchors=False,
    )
    with pytest.raises(DivasInputError, match="anchor 1: no surface under the click") as e:
        s.click(1, (50, 40))
    assert e.value.code is InputErrorCode.NO_SURFACE and e.value.details == {"x": 50, "y": 40}
    with pytest.raises(DivasInputError, match="outside") as e:
        s.click(0, (10_000, 5))
    assert e.value.code is InputErrorCode.CLICK_OUTSIDE
    with pytest.raises(DivasInputError, match="anchor 7 does not exist") as e:
        s.click(7, (5, 5))
    assert e.value.code is InputErrorCode.NO_ANCHOR and e.value.details == {
        "anchor": 7,
        "anchors": 2,
    }
    v = s.click(0, _click_xy(s, 0, clicks[0]))
    with pytest.raises(DivasInputError, match="outside"):
        s.prompt(v, [[1e4, 1.0]], [1])
    # ground truth absent from the view: the oracle's mask is empty → rejected, not a crash
    r = s.accept(v)
    assert r.status == "rejected" and "score 0.200 < 0.5" in r.reason
    low = Rejection(RejectReason.LOW_SCORE, pytest.approx(0.2), 0.5, 1)
    assert v.rejection == low and v.rejection.message == r.reason
    # the click stands (its patch selected: corrections.constrain); undo takes it back
    patch = s.current.corrections[-1].patch
    assert len(patch) and np.array_equal(np.flatnonzero(s.selection), patch)
    assert s.undo() is v and v.status == "open" and not s.selection.any()
    with pytest.raises(DivasInputError, match="already accepted") as e:
        v.status = "fused"  # (as an accept would leave it)
        s.prompt(v)
    v.status = "rejected"
    assert e.value.code is InputErrorCode.VIEW_ACCEPTED
    # no positive prompt
    r = s.accept(v, [[10.0, 10.0]], [0], include_default=False)
    assert r.status == "rejected" and r.reason == "no positive prompt"
    assert v.rejection == Rejection(RejectReason.NO_POSITIVE_PROMPT)
    assert s.report()["counts"]["rejected"] == 1
    s.close()


def test_empty_mask_is_rejected_with_reason(ribs, tmp_path):
    sc, scene, anchors, clicks, _ = ribs
    s = Session.open(
        scene,
        sc.cameras,
        SessionConfig(render_scale=SCALE),
        ConstantSegmenter(0.0),
        "cpu",
        anchors=[anchors[0]],
        render_anchors=False,
    )
    v = s.click(0, _click_xy(s, 0, clicks[0]))
    r = s.accept(v)
    assert r.status == "rejected" and r.reason == "empty mask after depth weighting"
    assert v.rejection == Rejection(RejectReason.EMPTY_MASK)
    assert s.fusion.view_ids == []
    # the rejection is saved as data and read back; a save without it (older) still loads
    path = tmp_path / "s.json"
    s.save(path)
    s.close()
    back = Session.load(path, scene, ConstantSegmenter(0.0), "cpu")
    assert back.view(v.id).rejection == v.rejection and back.view(v.id).reason == r.reason
    back.close()
    doc = json.loads(path.read_text())
    for vd in doc["objects"][0]["views"]:
        del vd["rejection"]
    path.write_text(json.dumps(doc))
    old = Session.load(path, scene, ConstantSegmenter(0.0), "cpu")
    assert old.view(v.id).rejection is None and old.view(v.id).reason == r.reason
    old.close()


def test_negative_anchor_click_becomes_negative_prompt(ribs):
    sc, scene, anchors, clicks, _ = ribs
    s = _open(ribs)
    a = s.anchors[1]
    v = s.click(1, _click_xy(s, 1, clicks[1]))
    # a negative click on a surface visible in the centroid view: the view centre's surface
    ctr = v.camera.unproject(
        np.array([[v.camera.cx + 20, v.camera.cy]]),
        np.array([v.buffers.D_ref[int(v.camera.cy), int(v.camera.cx) + 20]]),
    )
    uv, _ = a.camera.project(ctr)
    neg = s.click(1, uv[0], positive=False)
    assert not neg.positive and neg.point is not None and neg.index == 1
    pts, labs = s.default_prompts(v)
    assert labs.tolist() == [1, 0]
    s.close()


class _ThreadRecorder(OracleSegmenter):
    def __init__(self):
        super().__init__()
        self.threads = []

    def _encode(self, rgb, depth, view_id):
        self.threads.append(threading.current_thread().name)
        return super()._encode(rgb, depth, view_id)


def test_nerf_async_groups_and_replay(ribs, tmp_path):
    sc, _, anchors, clicks, _ = ribs
    grid = sc.grid
    seg = _ThreadRecorder()
    s = _open_grid(ribs, 2, seg)
    assert s.kind == "nerf" and s.preset == "llff"
    views = [s.click(i % 2, _click_xy(s, i % 2, clicks[i])) for i in range(4)]
    assert [v.id for v in views] == ["o0:a0:c0", "o0:a1:c0", "o0:a0:c1", "o0:a1:c1"]
    r = s.accept(views[0])
    assert r.status == "pending" and not r.synced and r.pending == 1 and not s.selection.any()
    r = s.accept(views[1])
    assert not r.synced and r.pending == 2
    # undo of a pending view drops it before any fusion
    assert s.undo() is views[1] and views[1].status == "open"
    s.accept(views[1])
    r = s.accept(views[2])  # last open view of anchor 0's group (and 3 pending): sync
    assert r.synced and r.fused == ["o0:a0:c0", "o0:a1:c0", "o0:a0:c1"] and r.pending == 0
    sel3 = s.selection.copy()
    assert sel3.shape == grid.density.shape and sel3.any()
    assert (sel3 & sc.grid_labels).sum() / sel3.sum() > 0.9
    r = s.accept(views[3])  # end of anchor 1's group
    assert r.synced and r.fused == ["o0:a1:c1"] and r.overlay is not None
    assert s.selection.sum() >= sel3.sum()
    assert any(t.startswith("divas-sam") for t in seg.threads)  # SAM ran in the worker
    assert s.report()["timings"]["segmenter_wait"]["calls"] == 2
    s2 = Session.load(s.save(tmp_path / "nerf.json"), grid, device="cpu")
    assert s2.replay_matches and np.array_equal(s2.selection, s.selection)
    res = s.export(tmp_path / "seg.npz", labels_path=tmp_path / "seg_labels.npy")
    assert res.format == "npz" and np.array_equal(np.load(tmp_path / "seg_labels.npy"), s.selection)
    s.close()


def test_nerf_pending_views_resubmitted_on_load(ribs, tmp_path):
    sc, _, anchors, clicks, _ = ribs
    s = _open_grid(ribs, 1)
    v0 = s.click(0, _click_xy(s, 0, clicks[0]))
    s.click(0, _click_xy(s, 0, clicks[2]))
    s.accept(v0)
    assert v0.status == "pending"
    path = s.save(tmp_path / "pending.json")
    with pytest.raises(DivasInputError, match="no segmenter"):
        Session.load(path, sc.grid, device="cpu")
    s2 = Session.load(path, sc.grid, OracleSegmenter(), device="cpu", gt_values=sc.grid_labels)
    assert s2.view(v0.id).status == "fused" and s2.selection.any()
    s.sync()
    assert np.array_equal(s2.selection, s.selection)
    s.close()
    s2.close()


def _capped_add_view(fusion, capacity: list[int]):
    """``fusion.add_view`` with at most ``capacity[0]`` live views (a tiny bitmask)."""
    from divas_engine.fusion import FusionCapacityError

    add = fusion.add_view

    def add_view(view, view_id=None):
        if len(fusion.view_ids) >= capacity[0]:
            raise FusionCapacityError(f"capacity {capacity[0]} views: all in use")
        return add(view, view_id)

    return add_view


def test_capacity_error_mid_group_keeps_state_consistent(ribs, monkeypatch):
    """A FusionCapacityError partway through a fused NeRF group keeps the
    views fused before it (and selects them); the rest go back to open, undo works and a
    retry fuses them."""
    sc, _, anchors, clicks, _ = ribs

    def open_four():
        s = _open_grid(ribs, 2)
        return s, [s.click(i % 2, _click_xy(s, i % 2, clicks[i])) for i in range(4)]

    # reference selections: view 0 alone, views 0-2 together
    ref, rv = open_four()
    ref.accept(rv[0])
    sel_0 = ref.sync().selection.copy()
    ref.accept(rv[1])
    r = ref.accept(rv[2])
    assert r.fused == [rv[1].id, rv[2].id]
    sel_012 = ref.selection.copy()
    ref.close()
    assert sel_0.any() and sel_012.sum() > sel_0.sum()

    s, v = open_four()
    capacity = [1]
    monkeypatch.setattr(s.fusion, "add_view", _capped_add_view(s.fusion, capacity))
    s.accept(v[0])
    s.accept(v[1])
    with pytest.raises(DivasInputError, match="capacity 1 views"):
        s.accept(v[2])  # group sync of views 0, 1, 2: view 1 does not fit
    assert [x.status for x in v] == ["fused", "open", "open", "open"]
    assert s.current.accept_order == [v[0].id] and s.fusion.view_ids == [v[0].fusion_id]
    c = s.counts()
    assert c["accepted"] == 1 and c["pending"] == 0 and c["open"] == 3
    assert np.array_equal(s.selection, sel_0)  # the fused view is selected
    # undo works on the consistent state
    assert s.undo() is v[0] and v[0].status == "open" and not s.selection.any()
    assert s.undo() is None
    # retry with room: the same group fuses to the reference selection
    capacity[0] = 8
    s.accept(v[0])
    s.accept(v[1])
    r = s.accept(v[2])
    assert r.synced and r.fused == [v[0].id, v[1].id, v[2].id]
    assert np.array_equal(s.selection, sel_012)
    assert [s.undo() for _ in range(4)] == [v[2], v[1], v[0], None]
    s.close()


def test_capacity_error_of_the_view_bitmask_leaves_the_view_open(ribs):
    """A surfel session with a one-view bitmask: the second accept is refused with one
    clear error; the first view stays fused and selected, the second is open again."""
    from divas_engine.fusion import GsFusionConfig

    sc, _, _, clicks, _ = ribs
    s = _open(ribs, gs_fusion=GsFusionConfig(max_views=1))
    v0 = s.click(0, _click_xy(s, 0, clicks[0]))
    v1 = s.click(1, _click_xy(s, 1, clicks[1]))
    sel0 = s.accept(v0).selection.copy()
    with pytest.raises(DivasInputError, match="bitmask holds 1 views"):
        s.accept(v1)
    assert (v0.status, v1.status) == ("fused", "open")
    assert s.current.accept_order == [v0.id] and np.array_equal(s.selection, sel0)
    assert s.undo() is v0 and not s.selection.any()
    assert s.accept(v1).fused == [v1.id]
    s.close()


def test_render_iou_protocol(ribs):
    from divas_engine.evaluation import render_iou, surfel_scores

    sc = ribs[0]
    cams = sc.test_cameras[:2]
    same = render_iou(sc.scene, cams, sc.labels, sc.labels, scale=0.25, device="cpu")
    # prediction ≥ 0.1 vs ground truth ≥ 0.5: the same labels give recall 1, IoU just below 1
    assert same.recall == 1.0 and 0.9 < same.iou < 1.0 and len(same.per_camera) == 2
    none = render_iou(sc.scene, cams, np.zeros_like(sc.labels), sc.labels, scale=0.25, device="cpu")
    assert none.iou == 0.0 and none.recall == 0.0
    g = sc.grid_labels
    grid = render_iou(sc.grid, cams, g, g, scale=0.25, device="cpu")
    assert grid.iou == 1.0 and grid.per_camera[0]["gt_pixels"] > 0
    assert surfel_scores(sc.labels, sc.labels)["iou"] == 1.0
