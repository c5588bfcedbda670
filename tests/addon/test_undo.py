"""Every session step is one Blender undo step, and after Blender's undo
(``bpy.ops.ed.undo``) or redo (``ed.redo``) — run for real, headless — the session
equals the restored Blender state and the state before / after the step: selection
attribute, labels, views and their cameras, anchors."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge, session_registry
from blender_addon.modal_logic import ANCHOR_PROP, VIEW_PROP
from blender_addon.session_actions import LABEL_ATTRIBUTE
from blender_addon.session_registry import STEP_PROP
from divas_engine.point_attributes import INDEX, SELECTED, point_values
from divas_engine.session.masks import TimedSegmenter
from divas_engine.viewport import region_matrices
from tests.stub_segmenters import ConstantSegmenter

SCALE = 0.5
UNDO = ("EXEC_DEFAULT", True)  # a script's operator call that pushes its undo step


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_undo")
    sc = generate_scene("ribs", out, size=8000, seed=2, grid_resolution=24)
    return out, sc


def _start(scene_dir):
    out, _ = scene_dir
    bpy.ops.divas.import_splats(*UNDO, filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(
        *UNDO, segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy")
    ) == {"FINISHED"}
    return obj.name, session_registry.get(obj)


def _click_xy(live, i, sc, k=0):
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"][k:] + sc.metadata["clicks"][:k]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            return f"{float(uv[0, 0])!r} {float(uv[0, 1])!r}"
    pytest.skip("no click point visible in this anchor")


def _state(live) -> dict:
    """The session's state, for equality after undo / redo."""
    s = live.session
    return {
        "selection": s.selection.copy(),
        "labels": s.label_set().copy(),
        "views": [(v.id, str(v.status)) for v in s.views],
        "anchors": len(s.anchors),
        "objects": [(o.name, o.finished) for o in s.objects],
        "step": s.history.current.id,
        "prompts": {k: list(v) for k, v in live.extra_prompts.items()},
    }


def _assert_state(live, ref, where):
    got = _state(live)
    for k in ("selection", "labels"):
        np.testing.assert_array_equal(got[k], ref[k], err_msg=f"{where}: {k}")
    for k in ("views", "anchors", "objects", "step", "prompts"):
        assert got[k] == ref[k], f"{where}: {k}"


def _assert_blender_matches(name, live, where):
    """What Blender holds (the file undo restored) equals the session."""
    obj = bpy.data.objects[name]
    s = live.session
    index = bridge.read_attribute(obj.data, INDEX)
    np.testing.assert_array_equal(
        bridge.read_attribute(obj.data, SELECTED),
        point_values(s.scene, index, s.selection),
        err_msg=f"{where}: divas_selected",
    )
    np.testing.assert_array_equal(
        bridge.read_attribute(obj.data, LABEL_ATTRIBUTE),
        point_values(s.scene, index, s.label_set()),
        err_msg=f"{where}: divas_label",
    )
    cams = [o for o in bpy.data.objects if o.type == "CAMERA" and o.parent == obj]
    views = sorted(str(c[VIEW_PROP]) for c in cams if c.get(VIEW_PROP))
    anchors = sorted(int(c[ANCHOR_PROP]) for c in cams if not c.get(VIEW_PROP))
    assert views == sorted(v.id for v in s.views), f"{where}: view cameras"
    assert anchors == list(range(len(s.anchors))), f"{where}: anchor cameras"
    assert sorted(live.view_cameras) == views and len(live.anchor_cameras) == len(anchors)
    assert obj[STEP_PROP] == s.history.current.id, f"{where}: step id"


def _step(name, live, what, op):
    """Run one step, then undo it and redo it, checking the state each time."""
    before = _state(live)
    assert op() == {"FINISHED"}, what
    after = _state(live)
    assert after["step"] != before["step"], f"{what}: no session step recorded"
    assert live.session.history.current.what.startswith(what.split(" (")[0])
    _assert_blender_matches(name, live, f"{what} (done)")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    live = session_registry.get(bpy.data.objects[name])
    _assert_state(live, before, f"{what} (undone)")
    _assert_blender_matches(name, live, f"{what} (undone)")
    assert bpy.ops.ed.redo() == {"FINISHED"}
    _assert_state(live, after, f"{what} (redone)")
    _assert_blender_matches(name, live, f"{what} (redone)")
    return live


def test_undo_redo_of_every_step_type(scene_dir):
    out, sc = scene_dir
    name, live = _start(scene_dir)
    ops = bpy.ops.divas
    s = live.session
    live = _step(name, live, "Click on anchor 0",
                 lambda: ops.session_click(*UNDO, anchor=0, xy=_click_xy(live, 0, sc)))  # fmt: skip
    live = _step(name, live, "Negative click on anchor 1",
                 lambda: ops.session_click(*UNDO, anchor=1, xy=_click_xy(live, 1, sc, 2),
                                           positive=False))  # fmt: skip
    live = _step(name, live, "Accept view", lambda: ops.session_accept(*UNDO))
    assert s.selection.sum() > 50
    # a rejected accept is a step too (the view is marked; undo opens it again)
    good = s._seg
    s._seg = TimedSegmenter(ConstantSegmenter(0.0), s.timings)  # sure of an empty mask
    xy2 = _click_xy(live, 2, sc, 1)
    live = _step(name, live, "Click on anchor 2",
                 lambda: ops.session_click(*UNDO, anchor=2, xy=xy2))  # fmt: skip
    live = _step(name, live, "Accept view (rejected)", lambda: ops.session_accept(*UNDO))
    assert s.views[-1].status == "rejected"
    s._seg = good
    live = _step(name, live, "Take back last view", lambda: ops.session_undo(*UNDO))
    # a viewport click: a new anchor and its camera, both undone
    a = s.anchors[0]
    vm, wm = region_matrices(a.full_camera)
    uv = np.array([float(v) for v in _click_xy(live, 0, sc).split()]) / SCALE
    live = _step(name, live, "Click in a 3D view",
                 lambda: ops.session_viewport_click(
                     *UNDO, view_matrix=vm.ravel(), window_matrix=wm.ravel(),
                     region_size=(a.full_camera.width, a.full_camera.height),
                     mouse=(int(uv[0]), int(a.full_camera.height - uv[1]))))  # fmt: skip
    assert len(s.anchors) == len(live.anchor_cameras) and s.anchors[-1].source == "viewport"
    # manual edits: a box in the anchor's view, grow, delete (points leave the object)
    live = _step(name, live, "Invert",
                 lambda: ops.select_all(*UNDO, action="INVERT"))  # fmt: skip
    live = _step(name, live, "Box select", lambda: ops.select_region(
        *UNDO, shape="BOX", points="[[0, 0], [400, 300]]", mode="SUB",
        perspective_matrix=(wm @ vm).ravel(),
        region_size=(a.full_camera.width, a.full_camera.height)))  # fmt: skip
    n_points = len(bpy.data.objects[name].data.points)
    live = _step(name, live, "Select by opacity",
                 lambda: ops.select_by_attribute(*UNDO, attribute="OPACITY", use_maximum=True,
                                                 maximum=0.3, mode="SET"))  # fmt: skip
    live = _step(name, live, "Delete splats", lambda: ops.delete_selected(*UNDO))
    assert len(bpy.data.objects[name].data.points) < n_points
    live = _step(name, live, "Finish object", lambda: ops.session_finish_object(*UNDO, name="a"))
    live = _step(name, live, "Reset", lambda: ops.session_reset(*UNDO, all_objects=True))


def test_undo_before_the_start_closes_the_session(scene_dir):
    name, live = _start(scene_dir)
    assert bpy.ops.ed.undo() == {"FINISHED"}  # back to the imported object, no session
    assert session_registry.all_sessions() == [] and live.session._closed
    obj = bpy.data.objects[name]
    assert STEP_PROP not in obj
    assert not [o for o in bpy.data.objects if o.type == "CAMERA" and o.parent == obj]


def test_a_failed_step_leaves_no_partial_change(scene_dir):
    out, sc = scene_dir
    name, live = _start(scene_dir)
    s = live.session
    bpy.ops.divas.session_click(*UNDO, anchor=0, xy=_click_xy(live, 0, sc))
    before = _state(live)

    xy = [float(v) for v in _click_xy(live, 1, sc).split()]

    def boom(*_a, **_k):
        s.click(1, xy)  # a partial change inside the step (a view spawned) …
        s.apply_selection(~s.selection)
        raise RuntimeError("simulated failure")  # … then it fails

    from blender_addon.session_actions import run_step

    with pytest.raises(RuntimeError, match="simulated"):
        run_step(bpy.data.objects[name], live, "boom", boom)
    _assert_state(live, before, "after the failed step")
    _assert_blender_matches(name, live, "after the failed step")
