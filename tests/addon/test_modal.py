"""The click-to-segment modal. The event →
step logic is pure (:mod:`blender_addon.modal_logic`) and tested as a table; the
operator's ``modal()`` is driven with stand-in events, a stand-in region and a stubbed
click → pixel mapping (headless Blender has no 3D view) against a real session on a
small synthetic scene — through anchor / view cameras and in a free view, with
Blender's own undo and redo (``ed.undo`` / ``ed.redo`` run for real)."""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from blender_addon import bridge, session_registry
from blender_addon.modal_logic import (
    HEADER_TEXT,
    Gesture,
    Key,
    KeyKind,
    StepKind,
    Target,
    decide,
    gesture_mode,
    plan,
    target_from_props,
)
from blender_addon.operators.segment_modal import DIVAS_OT_segment_modal, ModalController
from divas_engine.point_attributes import INDEX, SELECTED, scene_selection

SCALE = 0.5


# ----------------------------------------------------------------------------- pure logic
@pytest.mark.parametrize(
    "event, expect",
    [
        (("LEFTMOUSE", "PRESS", False, True), Key(KeyKind.CLICK, True)),
        (("LEFTMOUSE", "PRESS", True, True), Key(KeyKind.CLICK, False)),
        (("RIGHTMOUSE", "PRESS", False, True), Key(KeyKind.CLICK, False)),
        (("LEFTMOUSE", "RELEASE", False, True), Key(KeyKind.IGNORE)),
        (("LEFTMOUSE", "DOUBLE_CLICK", False, True), Key(KeyKind.CLICK, True)),
        (("LEFTMOUSE", "CLICK_DRAG", False, True), Key(KeyKind.IGNORE)),
        (("LEFTMOUSE", "PRESS", False, False), Key(KeyKind.PASS)),  # over the sidebar / header
        (("RET", "PRESS", False, True), Key(KeyKind.ACCEPT)),
        (("NUMPAD_ENTER", "PRESS", False, False), Key(KeyKind.ACCEPT)),
        (("RET", "RELEASE", False, True), Key(KeyKind.IGNORE)),
        (("BACK_SPACE", "PRESS", False, True), Key(KeyKind.UNDO)),
        (("Z", "PRESS", False, True, True), Key(KeyKind.UNDO)),
        (("Z", "PRESS", True, True, True), Key(KeyKind.REDO)),
        (("Z", "RELEASE", False, True, True), Key(KeyKind.IGNORE)),
        (("Z", "PRESS", False, True), Key(KeyKind.PASS)),  # plain Z: Blender's
        (("ESC", "PRESS", False, True), Key(KeyKind.EXIT)),
        (("MIDDLEMOUSE", "PRESS", False, True), Key(KeyKind.PASS)),
        (("WHEELUPMOUSE", "PRESS", False, True), Key(KeyKind.PASS)),
        (("MOUSEMOVE", "NOTHING", False, True), Key(KeyKind.PASS)),
        (("A", "PRESS", False, True), Key(KeyKind.PASS)),
        (("A", "RELEASE", False, True), Key(KeyKind.PASS)),
    ],
)
def test_decide(event, expect):
    t, v, shift, inside, *ctrl = event
    assert decide(t, v, shift=shift, in_region=inside, ctrl=bool(ctrl and ctrl[0])) == expect


ANCHOR, OPEN, FUSED = Target(2), Target(2, "o0:a2:c0", "open"), Target(2, "o0:a2:c0", "fused")
NONE, FREE = Target(), Target(free=True)
POS, NEG = Key(KeyKind.CLICK, True), Key(KeyKind.CLICK, False)


@pytest.mark.parametrize(
    "key, target, xy, kind",
    [
        (POS, ANCHOR, (3.0, 4.0), StepKind.SPAWN),
        (NEG, ANCHOR, (3.0, 4.0), StepKind.ANCHOR_NEGATIVE),
        (POS, OPEN, (3.0, 4.0), StepKind.PROMPT),
        (NEG, OPEN, (3.0, 4.0), StepKind.PROMPT),
        (POS, Target(2, "v", "rejected"), (3.0, 4.0), StepKind.PROMPT),  # re-prompt a rejected view
        (POS, FUSED, (3.0, 4.0), StepKind.CORRECT_VIEW),  # a correction of the selection
        (NEG, FUSED, (3.0, 4.0), StepKind.CORRECT_VIEW),
        (NEG, Target(2, "v", "pending"), (3.0, 4.0), StepKind.CORRECT_VIEW),
        (POS, ANCHOR, None, StepKind.MESSAGE),  # outside the camera frame
        (POS, NONE, (3.0, 4.0), StepKind.MESSAGE),  # not a DivAS camera
        (POS, FREE, (3.0, 4.0), StepKind.VIEWPORT_CLICK),  # a free 3D view
        (NEG, FREE, (3.0, 4.0), StepKind.VIEWPORT_CLICK),
        (POS, FREE, None, StepKind.MESSAGE),
        (Key(KeyKind.ACCEPT), FREE, None, StepKind.ACCEPT),  # the next open view
        (Key(KeyKind.REDO), OPEN, None, StepKind.REDO),
        (Key(KeyKind.ACCEPT), OPEN, None, StepKind.ACCEPT),
        (Key(KeyKind.ACCEPT), FUSED, None, StepKind.MESSAGE),
        (Key(KeyKind.ACCEPT), ANCHOR, None, StepKind.MESSAGE),
        (Key(KeyKind.ACCEPT), NONE, None, StepKind.MESSAGE),
        (Key(KeyKind.UNDO), NONE, None, StepKind.UNDO),
        (Key(KeyKind.EXIT), OPEN, None, StepKind.EXIT),
        (Key(KeyKind.PASS), OPEN, None, StepKind.PASS),
        (Key(KeyKind.IGNORE), OPEN, None, StepKind.NOTHING),
    ],
)
def test_plan(key, target, xy, kind):
    step = plan(key, target, xy)
    assert step.kind is kind
    if kind in (StepKind.SPAWN, StepKind.ANCHOR_NEGATIVE, StepKind.PROMPT, StepKind.CORRECT_VIEW):
        assert step.xy == xy and step.positive == key.positive and step.anchor == 2
    if kind is StepKind.VIEWPORT_CLICK:
        assert step.xy == xy and step.positive == key.positive
    if kind is StepKind.MESSAGE:
        assert step.message


def test_target_from_props():
    assert target_from_props({}) == NONE
    assert target_from_props({"divas_anchor": 3}) == Target(3)
    assert target_from_props({"divas_anchor": 3, "divas_view": "v"}, lambda v: "fused") == Target(
        3, "v", "fused"
    )
    assert target_from_props({"divas_anchor": 3, "divas_view": "gone"}, lambda v: None) == NONE


def test_gesture_box_lasso_brush():
    assert [gesture_mode(s, c) for s, c in ((0, 0), (1, 0), (0, 1), (1, 1))] == [
        "SET",
        "ADD",
        "SUB",
        "AND",
    ]
    g = Gesture("BOX")
    assert g.feed("LEFTMOUSE", "PRESS", 10, 20, shift=True).kind == "none"
    g.feed("MOUSEMOVE", "NOTHING", 30, 25)
    g.feed("MOUSEMOVE", "NOTHING", 50, 60)
    a = g.feed("LEFTMOUSE", "RELEASE", 50, 60)
    assert (a.kind, a.shape, a.points, a.mode, a.final) == (
        "apply",
        "BOX",
        ((10.0, 20.0), (50.0, 60.0)),
        "ADD",
        True,
    )
    g = Gesture("LASSO")
    g.feed("LEFTMOUSE", "PRESS", 0, 0, ctrl=True)
    for x, y in ((10, 0), (10, 10), (10, 10), (0, 10)):
        g.feed("MOUSEMOVE", "NOTHING", x, y)
    a = g.feed("LEFTMOUSE", "RELEASE", 0, 10)
    assert a.shape == "LASSO" and a.mode == "SUB" and len(a.points) == 4  # repeats dropped
    g = Gesture("LASSO")  # too short: cancelled
    g.feed("LEFTMOUSE", "PRESS", 0, 0)
    assert g.feed("LEFTMOUSE", "RELEASE", 0, 0).kind == "cancel"
    g = Gesture("CIRCLE", radius=10)
    assert g.feed("WHEELUPMOUSE", "PRESS", 0, 0).kind == "none" and g.radius == 12.0
    a = g.feed("LEFTMOUSE", "PRESS", 5, 5)
    assert (a.kind, a.points, a.mode, a.final) == ("apply", ((5.0, 5.0),), "ADD", False)
    a = g.feed("MOUSEMOVE", "NOTHING", 7, 5)
    assert a.kind == "apply" and a.points == ((7.0, 5.0),)
    assert g.feed("LEFTMOUSE", "RELEASE", 7, 5).final
    assert Gesture("BOX").feed("ESC", "PRESS", 0, 0).kind == "cancel"
    assert Gesture("BOX").feed("A", "PRESS", 0, 0).kind == "pass"


# ----------------------------------------------------------------------------- the modal
@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_modal")
    sc = generate_scene("ribs", out, size=15_000, seed=0, grid_resolution=32)
    return out, sc


def _event(type_, value="PRESS", shift=False, x=100, y=100, ctrl=False):
    return SimpleNamespace(type=type_, value=value, shift=shift, ctrl=ctrl, mouse_x=x, mouse_y=y)


class _Harness:
    """The operator's ``modal()`` with a stand-in ``self``: a controller over a stand-in
    region whose click → pixel mapping returns the next queued pixel."""

    def __init__(self, obj, rv3d=None, size=(800, 600)):
        self.reports: list[tuple[set, str]] = []
        self.pixels: list = []
        self.headers: list = []
        region = SimpleNamespace(type="WINDOW", x=10, y=20, width=size[0], height=size[1])
        # the sidebar drawn over the main region's right edge (Region Overlap)
        sidebar = SimpleNamespace(type="UI", x=610, y=20, width=200, height=600)
        area = SimpleNamespace(
            regions=[region, sidebar], header_text_set=self.headers.append, tag_redraw=lambda: None
        )
        self.ctl = ModalController(
            obj.name,
            lambda kind, msg: self.reports.append((kind, msg)),
            region=region,
            rv3d=rv3d or SimpleNamespace(view_perspective="CAMERA"),
            area=area,
            pixel_fn=self._pixel,
        )
        self.op = SimpleNamespace(_ctl=self.ctl)

    def _pixel(self, region, rv3d, scene, cam, mouse):
        assert mouse == (90, 80)  # window (100, 100) in the region at (10, 20)
        return self.pixels.pop(0)

    def send(self, event, pixel=None):
        if pixel is not None or event.type in ("LEFTMOUSE", "RIGHTMOUSE"):
            self.pixels.append(pixel)
        return DIVAS_OT_segment_modal.modal(self.op, bpy.context, event)


def _start(scene_dir):
    """Import and start as the UI does: each one Blender undo step."""
    out, _ = scene_dir
    bpy.ops.divas.import_splats("EXEC_DEFAULT", True, filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(
        "EXEC_DEFAULT", True, segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy")
    ) == {"FINISHED"}
    return obj, session_registry.get(obj)


def _visible_click(cam, sc):
    for c in sc.metadata["clicks"]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            return float(uv[0, 0]), float(uv[0, 1])
    pytest.skip("no click point visible")


def _selected(name: str) -> np.ndarray:
    return bridge.read_attribute(bpy.data.objects[name].data, SELECTED)


def _scene():
    return bpy.context.scene  # re-read: Blender's undo replaces the file's data


def test_modal_click_prompt_accept_undo_redo_exit(scene_dir):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    name = obj.name
    s = live.session
    h = _Harness(obj)
    anchor_cam = _scene().camera.name
    assert anchor_cam == live.anchor_cameras[0]
    # navigation and clicks outside the main region belong to Blender
    assert h.send(_event("MIDDLEMOUSE")) == {"PASS_THROUGH"}
    assert h.send(_event("LEFTMOUSE", x=5, y=5)) == {"PASS_THROUGH"}
    assert h.send(_event("LEFTMOUSE", x=700, y=300)) == {"PASS_THROUGH"}  # over the sidebar
    h.pixels.clear()
    # Enter on an anchor: nothing to accept yet
    assert h.send(_event("RET")) == {"RUNNING_MODAL"}
    assert h.reports[-1][0] == {"WARNING"} and "Nothing to accept yet" in h.reports[-1][1]
    # a click outside the camera frame
    assert h.send(_event("LEFTMOUSE"), pixel=None) == {"RUNNING_MODAL"}
    assert "inside the camera frame" in h.reports[-1][1] and s.views == []
    # LMB on the anchor → the centroid view's camera becomes the scene camera
    xy = _visible_click(s.anchors[0].camera, sc)
    assert h.send(_event("LEFTMOUSE"), pixel=xy) == {"RUNNING_MODAL"}
    assert len(s.views) == 1
    v = s.views[0]
    vcam = _scene().camera.name
    assert vcam == live.view_cameras[v.id] and _scene().camera["divas_view"] == v.id
    assert v.preview is not None and v.preview.labels.tolist() == [1]
    # Shift+LMB on the centroid view → a negative prompt, the preview refreshed
    corner = (2.5, 2.5)
    assert h.send(_event("LEFTMOUSE", shift=True), pixel=corner) == {"RUNNING_MODAL"}
    assert live.extra_prompts[v.id] == [(2.5, 2.5, 0)]
    assert v.preview.labels.tolist() == [1, 0] and v.preview.points[-1].tolist() == [2.5, 2.5]
    # RMB is negative too
    assert h.send(_event("RIGHTMOUSE"), pixel=(4.5, 2.5)) == {"RUNNING_MODAL"}
    assert v.preview.labels.tolist() == [1, 0, 0]
    # Enter → fused; divas_selected is the session selection on the points
    assert h.send(_event("RET")) == {"RUNNING_MODAL"}
    assert v.status == "fused" and s.selection.sum() > 100
    fused_sel = s.selection.copy()
    mapped = scene_selection(
        s.scene, bridge.read_attribute(obj.data, INDEX), bridge.read_attribute(obj.data, SELECTED)
    )
    np.testing.assert_array_equal(mapped, s.selection)
    assert v.labels.tolist() == [1, 0, 0]  # the previewed prompt set was the one fused
    assert _scene().camera.name == anchor_cam  # no other open view: back on the anchor
    assert [st.what for st in s.history.steps] == [
        "start",
        "Click on anchor 0",
        "Add point to view",
        "Add point to view",
        "Accept view",
    ]
    # Enter on the fused view's camera is refused with a message
    _scene().camera = bpy.data.objects[vcam]
    assert h.send(_event("RET")) == {"RUNNING_MODAL"}
    assert "already accepted" in h.reports[-1][1]
    # Ctrl+Z is Blender's undo: the accept is undone, the session follows
    assert h.send(_event("Z", ctrl=True)) == {"RUNNING_MODAL"}
    assert v.status == "open" and not s.selection.any()
    assert not _selected(name).any()
    assert _scene().camera.name == vcam  # the file is back where it was before Enter
    assert v.preview.labels.tolist() == [1, 0, 0] and live.extra_prompts[v.id][-1] == (4.5, 2.5, 0)
    # Backspace undoes too: the RMB point goes, the preview is the one before it
    assert h.send(_event("BACK_SPACE")) == {"RUNNING_MODAL"}
    assert v.preview.labels.tolist() == [1, 0] and live.extra_prompts[v.id] == [(2.5, 2.5, 0)]
    # Ctrl+Shift+Z redoes both: the view is fused again, bit for bit
    assert h.send(_event("Z", shift=True, ctrl=True)) == {"RUNNING_MODAL"}
    assert h.send(_event("Z", shift=True, ctrl=True)) == {"RUNNING_MODAL"}
    assert v.status == "fused" and np.array_equal(s.selection, fused_sel)
    mapped = scene_selection(s.scene, bridge.read_attribute(bpy.data.objects[name].data, INDEX),
                             _selected(name))  # fmt: skip
    np.testing.assert_array_equal(mapped, fused_sel)
    assert h.send(_event("Z", shift=True, ctrl=True)) == {"RUNNING_MODAL"}
    assert h.reports[-1] == ({"WARNING"}, "Nothing to redo")
    # key releases are swallowed; Esc leaves
    assert h.send(_event("RET", value="RELEASE")) == {"RUNNING_MODAL"}
    assert h.headers[-1].startswith(HEADER_TEXT) and "1 views added" in h.headers[-1]
    assert h.send(_event("ESC")) == {"FINISHED"}
    assert h.headers[-1] is None  # the header is Blender's again


def test_modal_two_views_propagate(scene_dir):
    """Two views spawned before accepting: Enter on the first keeps the engine's
    selection overlay for the second (the next open view), which becomes the scene
    camera."""
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    s = live.session
    h = _Harness(obj)
    scene = bpy.context.scene
    for i in (0, 1):
        scene.camera = bpy.data.objects[live.anchor_cameras[i]]
        h.send(_event("LEFTMOUSE"), pixel=_visible_click(s.anchors[i].camera, sc))
    v0, v1 = s.views
    scene.camera = bpy.data.objects[live.view_cameras[v0.id]]
    assert v1.id not in live.coverage
    assert h.send(_event("NUMPAD_ENTER")) == {"RUNNING_MODAL"}
    assert v0.status == "fused" and v1.status == "open"
    assert scene.camera.name == live.view_cameras[v1.id]
    sel_ref, lazy = live.coverage[v1.id]  # the 3D selection over the next view: rendered
    assert sel_ref is s.selection and callable(lazy)  # when first drawn
    cov = live.coverage_of(v1.id)
    assert cov.shape == (v1.camera.height, v1.camera.width)
    assert cov.max() > 0.5
    assert h.send(_event("RET")) == {"RUNNING_MODAL"}
    assert v1.status == "fused"


def test_modal_free_view_click(scene_dir):
    """A click in a free 3D view: the view becomes an anchor (reused while the view does
    not move) and the click opens a centroid view; Ctrl+Z takes both back."""
    from divas_engine.viewport import region_matrices

    out, sc = scene_dir
    obj, live = _start(scene_dir)
    name = obj.name
    s = live.session
    n0 = len(s.anchors)
    a = s.anchors[0]
    cam = a.full_camera  # the object is at the origin: scene frame = world
    vm, wm = region_matrices(cam)
    rv3d = SimpleNamespace(view_perspective="PERSP", view_matrix=vm, window_matrix=wm)
    h = _Harness(obj, rv3d=rv3d, size=(cam.width, cam.height))
    uv = np.array(_visible_click(a.camera, sc)) * (cam.width / a.camera.width)
    mouse = (int(uv[0]), int(cam.height - uv[1]))  # region pixel (y up)
    ev = _event("LEFTMOUSE", x=mouse[0] + 10, y=mouse[1] + 20)
    assert h.send(ev) == {"RUNNING_MODAL"}, h.reports
    assert len(s.anchors) == n0 + 1 and s.anchors[-1].source == "viewport"
    assert len(s.views) == 1 and s.views[0].anchor == n0
    assert len(live.anchor_cameras) == n0 + 1
    assert h.send(_event("LEFTMOUSE", x=mouse[0] + 14, y=mouse[1] + 20)) == {"RUNNING_MODAL"}
    assert len(s.anchors) == n0 + 1 and len(s.views) == 2  # the same view: the same anchor
    assert h.send(_event("Z", ctrl=True)) == {"RUNNING_MODAL"}
    assert h.send(_event("Z", ctrl=True)) == {"RUNNING_MODAL"}
    assert len(s.anchors) == n0 and s.views == [] and len(live.anchor_cameras) == n0, (
        h.reports,
        [st.what for st in s.history.steps],
        s.history.index,
    )
    assert bpy.data.objects.get(f"{name} Anchor {n0:02d}") is None
    # an orthographic view is refused in plain words
    rv3d.window_matrix = np.diag([0.2, 0.2, -0.01, 1.0])
    assert h.send(ev) == {"RUNNING_MODAL"}
    assert "orthographic" in h.reports[-1][1] and "Numpad 5" in h.reports[-1][1]


def test_modal_errors_keep_running(scene_dir):
    obj, live = _start(scene_dir)
    h = _Harness(obj)
    # an engine error (here a pixel off the image) → one error line, the modal goes on
    assert h.send(_event("LEFTMOUSE"), pixel=(-3.0, 2.0)) == {"RUNNING_MODAL"}
    assert live.session.views == []
    kind, msg = h.reports[-1]
    assert kind == {"ERROR"} and "outside the image" in msg and "click inside" in msg
    assert "Traceback" not in msg and "\n" not in msg
    assert h.send(_event("ESC")) == {"FINISHED"}


def test_modal_needs_a_3d_view_and_a_session(scene_dir):
    assert not bpy.ops.divas.segment_modal.poll()  # headless: no 3D viewport
    obj, live = _start(scene_dir)
    h = _Harness(obj)
    session_registry.drop(obj)
    assert h.send(_event("RET")) == {"CANCELLED"}
    assert "ended" in h.reports[-1][1]


def test_modal_shift_click_on_a_spill_removes_it_at_once(scene_dir):
    """A Shift-click on the selection, through an accepted view's camera,
    takes the spot out of the points' selection in the same step (the viewport's
    ``divas_selected``), the panel's last update says how many views it changed, and one
    Blender undo step brings the exact selection back."""
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    name = obj.name
    s = live.session
    h = _Harness(obj)
    h.send(_event("LEFTMOUSE"), pixel=_visible_click(s.anchors[0].camera, sc))
    v = s.views[0]
    h.send(_event("RET"))
    assert v.status == "fused"
    before = s.selection.copy()
    # a selected spot of the view's surface: the view's own click target
    uv, _ = v.camera.project(v.centroid.target[None])
    _scene().camera = bpy.data.objects[live.view_cameras[v.id]]
    n_steps = len(s.history.steps)
    assert h.send(_event("LEFTMOUSE", shift=True), pixel=tuple(uv[0])) == {"RUNNING_MODAL"}
    res = s.last_correction
    patch = res.correction.patch
    assert len(patch) and before[patch].any() and not s.selection[patch].any()
    # the points show it now: divas_selected is the engine's selection
    mapped = scene_selection(s.scene, bridge.read_attribute(bpy.data.objects[name].data, INDEX),
                             _selected(name))  # fmt: skip
    np.testing.assert_array_equal(mapped, s.selection)
    assert live.last_update["views_changed"] == res.views_changed
    assert f"{res.views_changed} view" in live.last_update["what"]
    assert "Click on accepted view" in h.reports[-1][1] and "splats out" in h.reports[-1][1]
    assert len(s.history.steps) == n_steps + 1  # one step
    # Ctrl+Z: the selection, on the points too, is back bit for bit
    assert h.send(_event("Z", ctrl=True)) == {"RUNNING_MODAL"}
    np.testing.assert_array_equal(s.selection, before)
    mapped = scene_selection(s.scene, bridge.read_attribute(bpy.data.objects[name].data, INDEX),
                             _selected(name))  # fmt: skip
    np.testing.assert_array_equal(mapped, before)
    # Shift-click on the anchor: the same, from the anchor's camera
    _scene().camera = bpy.data.objects[live.anchor_cameras[0]]
    uv, _ = s.anchors[0].camera.project(v.centroid.target[None])
    assert h.send(_event("LEFTMOUSE", shift=True), pixel=tuple(uv[0])) == {"RUNNING_MODAL"}
    res = s.last_correction
    assert res.correction.source.anchor == 0 and not s.selection[res.correction.patch].any()
    mapped = scene_selection(s.scene, bridge.read_attribute(bpy.data.objects[name].data, INDEX),
                             _selected(name))  # fmt: skip
    np.testing.assert_array_equal(mapped, s.selection)
    assert "Negative click on anchor" in h.reports[-1][1] and "view" in h.reports[-1][1]
