"""What the add-on keeps off the user's time, and that
the result stays the same.

* anchors render lazily — only the first at Start — and an anchor looked through later
  (Look Through Camera, the scene camera set by hand, the depsgraph handler's timer)
  shows exactly the engine's render of its camera;
* Start right after an import reads the scene file no more (the importer's scene is
  the session's);
* click and accept write back exactly the points whose values changed (one element at
  a time, or in bulk above a size), and the attributes then equal a full write;
* the selection overlay of an accepted view is rendered when it is first drawn, and
  equals the engine's overlay of that view.
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge, handlers, overlays, session_registry, source
from blender_addon.session_actions import LABEL_ATTRIBUTE, loop_steps, points
from blender_addon.session_actions.view_cameras import has_background
from divas_engine.point_attributes import INDEX, SELECTED, point_values
from divas_engine.render import make_renderer

SCALE = 0.5


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_perf")
    sc = generate_scene("ribs", out, size=12_000, seed=4, grid_resolution=24)
    return out, sc


def _start(scene_dir, **kw):
    out, _ = scene_dir
    assert bpy.ops.divas.import_splats(filepath=str(out / "scene.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = False
    kw.setdefault("segmenter", "oracle")
    kw.setdefault("gt_labels", str(out / "labels.npy"))
    assert bpy.ops.divas.start_session(device="cpu", **kw) == {"FINISHED"}
    return obj, session_registry.get(obj)


def _click_xy(live, i, sc, k=0):
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"][k:] + sc.metadata["clicks"][:k]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            return f"{float(uv[0, 0])!r} {float(uv[0, 1])!r}"
    pytest.skip("no click point visible in this anchor")


def _image_rgb(img) -> np.ndarray:
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1, :, :3]


def _independent_render(live, camera) -> np.ndarray:
    """The camera rendered by a renderer of its own (nothing shared with the session)."""
    s = live.session
    return make_renderer(s.scene, device="cpu", config=s.config.render).render(camera).rgb


def _assert_shows_render(live, cam, i):
    assert has_background(cam)
    img = cam.data.background_images[0].image
    a = live.session.anchors[i]
    assert tuple(img.size) == (a.camera.width, a.camera.height)
    bridge.pack_pending()  # what the idle timer does (no event loop runs here)
    assert img.packed_file is not None
    expect = np.clip(_independent_render(live, a.camera), 0, 1)
    np.testing.assert_allclose(_image_rgb(img), expect, atol=1.0 / 254)  # 8-bit image


def test_start_renders_the_first_anchor_only_and_reads_no_file(scene_dir, monkeypatch):
    out, _ = scene_dir

    def no_reading(*_a, **_k):
        raise AssertionError("Start DivAS read the scene file again")

    assert bpy.ops.divas.import_splats(filepath=str(out / "scene.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    cached = source.load_source_scene(source.source_of(obj))
    monkeypatch.setattr(source, "load_scene", no_reading)
    bpy.context.scene.divas.autosave = False
    bpy.context.scene.divas.render_scale = SCALE
    assert bpy.ops.divas.start_session(device="cpu") == {"FINISHED"}
    live = session_registry.get(obj)
    s = live.session
    assert s.scene is cached  # one engine copy: the importer's
    # the click operator previews the mask at once: graph3d's cut starts while the view
    # renders (the engine's own default is off)
    assert type(s.segmenter).__name__ == "Graph3DSegmenter" and s.segmenter.prefetch_cuts
    assert len(s.anchors) >= 3
    assert [a.rendered for a in s.anchors] == [True] + [False] * (len(s.anchors) - 1)
    cams = [bpy.data.objects[n] for n in live.anchor_cameras]
    assert bpy.context.scene.camera == cams[0]
    assert [has_background(c) for c in cams] == [True] + [False] * (len(cams) - 1)
    _assert_shows_render(live, cams[0], 0)


def test_lazy_anchors_show_their_render_when_looked_through(scene_dir):
    obj, live = _start(scene_dir)
    s = live.session
    cams = [bpy.data.objects[n] for n in live.anchor_cameras]
    # Look Through Camera on anchor 1
    bpy.context.view_layer.objects.active = cams[1]
    assert bpy.ops.divas.activate_camera() == {"FINISHED"}
    assert s.anchors[1].rendered and bpy.context.scene.camera == cams[1]
    _assert_shows_render(live, cams[1], 1)
    assert not s.anchors[2].rendered and not has_background(cams[2])
    # the scene camera set by hand: the depsgraph handler schedules the render by timer
    # (timers do not run headless: the test runs the scheduled function itself)
    assert handlers._on_depsgraph_update in bpy.app.handlers.depsgraph_update_post

    def timer_ran():  # what Blender does with a one-shot timer
        if bpy.app.timers.is_registered(handlers._fill_timer):
            bpy.app.timers.unregister(handlers._fill_timer)
            handlers._fill_timer()

    timer_ran()  # (one may be pending from the operator's own depsgraph update)
    bpy.context.view_layer.objects.active = obj
    bpy.context.scene.camera = cams[2]
    assert handlers.request_background_fill(bpy.context)
    assert not handlers.request_background_fill(bpy.context)  # once until it ran
    assert not s.anchors[2].rendered
    timer_ran()
    _assert_shows_render(live, cams[2], 2)
    assert not handlers.request_background_fill(bpy.context)  # nothing left to do here
    # a click on a lazy anchor renders it (the engine needs its depth) and works
    last = len(s.anchors) - 1
    if not s.anchors[last].rendered:
        _, sc = scene_dir
        assert bpy.ops.divas.session_click(anchor=last, xy=_click_xy(live, last, sc)) == {
            "FINISHED"
        }
        assert s.anchors[last].rendered and len(s.views) == 1


def test_counts_never_wait_for_the_warm_up(scene_dir, monkeypatch):
    """Start (and every step) recounts without waiting for the engine's background
    warm-up; the voxel counts come once it is done."""
    from blender_addon.ui import panel  # noqa: F401 - the panel draws these counts

    obj, live = _start(scene_dir)
    s = live.session
    backend = type(s.backend)

    def must_not_wait(self):
        raise AssertionError("waited for the warm-up")

    monkeypatch.setattr(backend, "ready", property(lambda self: False))
    monkeypatch.setattr(backend, "_ready", must_not_wait)
    c = s.counts(wait=False)
    assert c["active_voxels"] is None and c["segmented_voxels"] is None
    live.changed()
    assert live.counts()["active_voxels"] is None
    monkeypatch.undo()
    assert s.warmed_up or s.grid is not None
    assert live.counts()["active_voxels"] == len(s.grid) > 0  # recounted once ready


def _attrs(obj):
    return (
        bridge.read_attribute(obj.data, SELECTED).copy(),
        bridge.read_attribute(obj.data, LABEL_ATTRIBUTE).copy(),
    )


def _full_reference(obj, live):
    s = live.session
    index = bridge.read_attribute(obj.data, INDEX)
    return point_values(s.scene, index, s.selection), point_values(s.scene, index, s.label_set())


@pytest.mark.parametrize("partial_max", [10**9, 0])
def test_click_and_accept_write_exactly_the_changed_points(scene_dir, monkeypatch, partial_max):
    """``partial_max``: every change written element by element, or every change in bulk."""
    monkeypatch.setattr(points, "PARTIAL_MAX", partial_max)
    _, sc = scene_dir
    obj, live = _start(scene_dir)
    writes = []
    plain = loop_steps.write_selection

    def recording(o, lv, **kw):
        wb = plain(o, lv, **kw)
        writes.append(wb)
        return wb

    monkeypatch.setattr(loop_steps, "write_selection", recording)
    before = _attrs(obj)
    assert bpy.ops.divas.session_click(anchor=0, xy=_click_xy(live, 0, sc)) == {"FINISHED"}
    assert writes == []  # a click changes no selection: nothing written
    np.testing.assert_array_equal(_attrs(obj)[0], before[0])
    for k in range(2):  # two accepts: the second changes a selection already written
        assert bpy.ops.divas.session_accept() == {"FINISHED"}
        after = _attrs(obj)
        wb = writes[-1]
        assert not wb.full
        np.testing.assert_array_equal(wb.selected, np.flatnonzero(after[0] != before[0]))
        np.testing.assert_array_equal(wb.labels, np.flatnonzero(after[1] != before[1]))
        if k == 0:
            assert len(wb.selected) > 0
        ref_sel, ref_lab = _full_reference(obj, live)
        np.testing.assert_array_equal(after[0], ref_sel)
        np.testing.assert_array_equal(after[1], ref_lab)
        before = after
        if k == 0:
            assert bpy.ops.divas.session_click(anchor=1, xy=_click_xy(live, 1, sc, 1)) == {
                "FINISHED"
            }
    # finishing the object clears the selection and sets the labels: both written
    assert bpy.ops.divas.session_finish_object(name="thing") == {"FINISHED"}
    after = _attrs(obj)
    ref_sel, ref_lab = _full_reference(obj, live)
    np.testing.assert_array_equal(after[0], ref_sel)
    np.testing.assert_array_equal(after[1], ref_lab)
    assert not after[0].any() and after[1].any()


def test_write_after_the_points_changed_behind_the_session_is_full(scene_dir):
    obj, live = _start(scene_dir)
    geom = obj.data
    # something outside the session rewrote the attribute: a full write puts it right
    bridge.write_attribute(geom, SELECTED, np.ones(bridge.point_count(geom), bool))
    wb = points.write_selection(obj, live, full=True)
    assert wb.full
    np.testing.assert_array_equal(_attrs(obj)[0], _full_reference(obj, live)[0])
    # a removed attribute is noticed without being told
    bridge.remove_attribute(geom, LABEL_ATTRIBUTE)
    assert points.write_selection(obj, live).full
    np.testing.assert_array_equal(_attrs(obj)[1], _full_reference(obj, live)[1])
    # nothing changed: nothing written
    wb = points.write_selection(obj, live)
    assert not wb.full and len(wb.selected) == 0 and len(wb.labels) == 0


def test_accept_renders_no_overlay_until_the_view_is_drawn(scene_dir):
    _, sc = scene_dir
    obj, live = _start(scene_dir)
    s = live.session
    for i in (0, 1):
        assert bpy.ops.divas.session_click(anchor=i, xy=_click_xy(live, i, sc, i)) == {"FINISHED"}
    v0, v1 = s.views
    bpy.context.scene.camera = bpy.data.objects[live.view_cameras[v0.id]]
    n_values = len(s.timings.calls("overlay"))
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    assert bpy.context.scene.camera.name == live.view_cameras[v1.id]
    assert len(s.timings.calls("overlay")) == n_values  # nothing rendered in accept
    assert callable(live.coverage[v1.id][1]) and callable(live.coverage[v0.id][1])
    # drawn through the next view: rendered now, equal to the engine's overlay
    frame = np.array([[10, 10], [10, 0], [0, 0], [0, 10]], np.float64)
    items = overlays.camera_items(live, _view_target(live, v1), frame)
    cov = live.coverage_of(v1.id)
    expect = s.overlay(v1, s.selection).coverage
    np.testing.assert_array_equal(cov, expect)
    assert any(getattr(it, "key", (None,))[0] == "coverage" for it in items)
    assert len(s.timings.calls("overlay")) == n_values + 2  # v1's (drawn) + the reference
    assert callable(live.coverage[v0.id][1])  # never looked at: never rendered


def _view_target(live, v):
    from blender_addon.session_actions import camera_target

    return camera_target(live, bpy.data.objects[live.view_cameras[v.id]])
