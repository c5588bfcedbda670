"""The manual selection tools on an imported object — box, lasso, circle
and sphere on a known point layout select exactly the expected splats (each set worked
out by hand), the modes, invert, grow / shrink, by opacity and by size, delete / hide /
reveal / separate, all undoable and all reflected in the export; with a session, the
manual edits compose with the semantic selection and reach the session's exports."""

from __future__ import annotations

import bpy
import numpy as np
import plyfile
import pytest

from blender_addon import bridge, point_edits, session_registry
from blender_addon.session_actions import LABEL_ATTRIBUTE
from divas_engine.io.ply import write_surfel_ply
from divas_engine.point_attributes import SELECTED
from divas_engine.scene import SurfelScene

UNDO = ("EXEC_DEFAULT", True)
#: a region view where world (x, y) ∈ [−1, 1]² at z = −1 fills a 200 × 100 region
#: (w = −z): region x = (x + 1)·100, y = (y + 1)·50 for points at z = −1.
VIEW = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, -1, 0]], float)
REGION = dict(perspective_matrix=VIEW.ravel(), region_size=(200, 100))


@pytest.fixture(scope="module")
def grid_ply(tmp_path_factory):
    """A 5 × 5 grid of splats at x, y ∈ {−0.8, −0.4, 0, 0.4, 0.8}, z = −1 (row-major in
    y, then x: point 5·r + c is at (xs[c], xs[r])); opacity 0.04·(i + 1), size grows
    with i."""
    xs = np.array([-0.8, -0.4, 0.0, 0.4, 0.8])
    gx, gy = np.meshgrid(xs, xs, indexing="xy")
    n = 25
    means = np.c_[gx.ravel(), gy.ravel(), -np.ones(n)].astype(np.float32)
    scene = SurfelScene(
        means=means,
        quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        scales=np.repeat(np.linspace(0.01, 0.05, n, dtype=np.float32)[:, None], 2, 1),
        opacities=(0.04 * (np.arange(n) + 1)).astype(np.float32),
        sh=np.full((n, 1, 3), 0.5, np.float32),
        sh_degree=0,
    )
    path = tmp_path_factory.mktemp("grid") / "grid.ply"
    write_surfel_ply(path, scene)
    return path


def _import(path):
    assert bpy.ops.divas.import_splats(*UNDO, filepath=str(path)) == {"FINISHED"}
    return bpy.context.active_object.name


def _shown(name) -> int:
    """Points left in the evaluated point cloud by the hide modifier (the display modifier,
    which turns the points into Gaussian quads, switched off while counting)."""
    from blender_addon import display

    obj = bpy.data.objects[name]
    mod = obj.modifiers.get(display.MODIFIER)
    if mod is not None:
        mod.show_viewport = False
    try:
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        return len(ev.data.points)
    finally:
        if mod is not None:
            mod.show_viewport = True


def _sel(name) -> list[int]:
    geom = bpy.data.objects[name].data
    if geom.attributes.get(SELECTED) is None:
        return []
    return np.flatnonzero(bridge.read_attribute(geom, SELECTED)).tolist()


def _rows(name) -> list[int]:
    return bridge.read_attribute(bpy.data.objects[name].data, "divas_index").tolist()


def test_region_tools_select_exactly_the_expected_splats(grid_ply):
    name = _import(grid_ply)
    ops = bpy.ops.divas
    assert ops.select_region(shape="BOX", points="[[110, 55], [50, 25]]", **REGION) == {"FINISHED"}
    assert _sel(name) == [6, 7, 11, 12]
    # a triangle lasso, added (Shift): its inside worked out edge by edge
    tri = "[[10, 5], [190, 5], [100, 95]]"
    ops.select_region(shape="LASSO", points=tri, mode="ADD", **REGION)
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 7, 8, 11, 12, 13, 17, 22]
    # a brush of radius 25 px at the centre, subtracted: 7, 12, 17 go
    ops.select_region(shape="CIRCLE", points="[[100, 50]]", radius=25, mode="SUB", **REGION)
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 8, 11, 13, 22]
    # intersect with the bottom two rows
    ops.select_region(shape="BOX", points="[[0, 0], [200, 35]]", mode="AND", **REGION)
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 8]
    # a sphere around a 3D point (the object at the origin: world = object frame)
    bpy.context.scene.cursor.location = (0.4, 0.4, -1.0)
    ops.select_sphere(radius=0.45, mode="SET")
    assert _sel(name) == [13, 17, 18, 19, 23]
    # the object moved: the tools follow its transform
    bpy.data.objects[name].location = (0.4, 0.0, 0.0)
    bpy.context.view_layer.update()
    ops.select_region(shape="BOX", points="[[50, 25], [110, 55]]", **REGION)
    assert _sel(name) == [5, 6, 10, 11]  # columns x ∈ {−0.8, −0.4} moved to 60 and 100
    # invert, all, none
    ops.select_all(action="INVERT")
    assert len(_sel(name)) == 21
    ops.select_all(action="DESELECT")
    assert _sel(name) == []
    ops.select_all(action="SELECT")
    assert len(_sel(name)) == 25
    with pytest.raises(RuntimeError, match="three points"):
        ops.select_region(shape="LASSO", points="[[0, 0], [1, 1]]", **REGION)


def test_grow_shrink_opacity_size(grid_ply):
    name = _import(grid_ply)
    ops = bpy.ops.divas
    ops.select_region(shape="CIRCLE", points="[[100, 50]]", radius=5, **REGION)
    assert _sel(name) == [12]
    ops.select_grow(radius=0.41)  # the 4 axis neighbours at 0.4
    assert _sel(name) == [7, 11, 12, 13, 17]
    # automatic radius: twice the median spacing = 0.8: every point within 0.8 of the
    # plus joins; only the corners are farther (√(0.4² + 0.8²) ≈ 0.89)
    ops.select_grow()
    corners = {0, 4, 20, 24}
    assert _sel(name) == sorted(set(range(25)) - corners)
    # shrink by 0.41: the corners' axis neighbours touch an unselected splat and go
    ops.select_grow(shrink=True, radius=0.41, steps=1)
    assert _sel(name) == sorted(set(range(25)) - corners - {1, 5, 3, 9, 15, 21, 19, 23})
    # by opacity: 0.04·(i+1) ≤ 0.2 → the first 5
    ops.select_by_attribute(attribute="OPACITY", use_maximum=True, maximum=0.2, mode="SET")
    assert _sel(name) == [0, 1, 2, 3, 4]
    # by size: √(s₁s₂) = linspace(0.01, 0.05) ≥ 0.045 → the last 3 (0.04667, …)
    ops.select_by_attribute(attribute="SIZE", use_minimum=True, minimum=0.045,
                            use_maximum=False, mode="SET")  # fmt: skip
    assert _sel(name) == [22, 23, 24]


def test_delete_hide_reveal_separate_undo_export(grid_ply, tmp_path):
    name = _import(grid_ply)
    ops = bpy.ops.divas
    ops.select_region(*UNDO, shape="BOX", points="[[0, 0], [200, 35]]", **REGION)  # rows 0–1
    assert _sel(name) == list(range(10))
    # hide the selected: gone from the evaluated object, deselected, out of the tools' reach
    assert ops.hide_selected(*UNDO) == {"FINISHED"}
    assert _shown(name) == 15 and _sel(name) == []
    ops.select_all(*UNDO, action="SELECT")
    assert _sel(name) == list(range(10, 25))
    assert ops.reveal_hidden(*UNDO) == {"FINISHED"}
    assert _sel(name) == list(range(10, 25))  # revealed, still deselected
    assert point_edits.visible(point_edits.EditTarget(bpy.data.objects[name], None)).all()
    assert _shown(name) == 25
    # delete the selected: 10 points left, the export writes exactly the selected rows
    ops.select_region(*UNDO, shape="BOX", points="[[0, 0], [200, 55]]", **REGION)  # rows 0–2
    ops.select_region(*UNDO, shape="BOX", points="[[0, 40], [200, 55]]", mode="SUB", **REGION)
    assert _sel(name) == list(range(10))
    assert ops.delete_selected(*UNDO) == {"FINISHED"}
    assert _rows(name) == list(range(10, 25))
    ops.select_all(*UNDO, action="SELECT")
    out = tmp_path / "kept.ply"
    assert ops.export_selection(filepath=str(out)) == {"FINISHED"}
    rows = plyfile.PlyData.read(str(out))["vertex"].data
    np.testing.assert_allclose(rows["opacity"], plyfile.PlyData.read(str(grid_ply))[
        "vertex"].data["opacity"][10:])  # fmt: skip
    # Ctrl+Z brings the deleted points back (Blender's undo restores the point cloud)
    bpy.ops.ed.undo()  # the select-all
    bpy.ops.ed.undo()  # the delete
    assert _rows(name) == list(range(25)) and _sel(name) == list(range(10))
    # separate: a new object with the selected points, the rest stays
    assert ops.separate_selected(*UNDO) == {"FINISHED"}
    new = bpy.context.active_object
    assert new.name != name and _rows(new.name) == list(range(10))
    assert _rows(name) == list(range(10, 25))
    with pytest.raises(RuntimeError, match="Nothing is selected"):
        bpy.context.view_layer.objects.active = bpy.data.objects[name]
        ops.delete_selected()


# ----------------------------------------------------------------------------- with a session
@pytest.fixture(scope="module")
def ribs(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_edits")
    sc = generate_scene("ribs", out, size=8000, seed=5, grid_resolution=24)
    return out, sc


def _click(live, i, sc, k=0):
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"][k:] + sc.metadata["clicks"][:k]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            xy = f"{float(uv[0, 0])!r} {float(uv[0, 1])!r}"
            assert bpy.ops.divas.session_click(anchor=i, xy=xy) == {"FINISHED"}
            return
    pytest.skip("no click point visible")


def test_manual_edits_compose_with_the_session_and_reach_its_exports(ribs, tmp_path):
    out, sc = ribs
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    name = obj.name
    bpy.context.scene.divas.render_scale = 0.5
    bpy.context.scene.divas.autosave = False
    bpy.ops.divas.start_session(segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy"))
    live = session_registry.get(obj)
    s = live.session
    _click(live, 0, sc)
    bpy.ops.divas.session_accept()
    sem0 = s.semantic_selection.copy()
    # remove by hand every selected splat with x > its median (a sphere around a far point
    # would do too; a box in world space is simplest through the opacity of none …)
    pts = bridge.read_attribute(obj.data, "position")
    mid = np.median(pts[bridge.read_attribute(obj.data, SELECTED), 0])
    cursor_far = pts[bridge.read_attribute(obj.data, SELECTED)].max(0)
    bpy.context.scene.cursor.location = tuple(cursor_far)
    r = float(np.linalg.norm(cursor_far - [mid, *cursor_far[1:]])) * 0.8
    bpy.ops.divas.select_sphere(radius=r, mode="SUB")
    removed = sem0 & ~s.selection
    assert removed.any() and live.session.history.current.what == "Sphere select"
    # a second view grows the semantic selection; the removed splats stay removed
    _click(live, 1, sc, 1)
    bpy.ops.divas.session_accept()
    assert not (s.selection & removed).any()
    np.testing.assert_array_equal(s.selection, s.semantic_selection & ~removed)
    # delete a few selected splats: out of the object, the selection and the exports
    bpy.ops.divas.select_by_attribute(attribute="OPACITY", use_maximum=True, maximum=0.5,
                                      mode="AND")  # fmt: skip
    n_sel = int(s.selection.sum())
    bpy.ops.divas.delete_selected()
    assert int(s.edits.deleted.sum()) == n_sel and not s.selection.any()
    assert len(bpy.data.objects[name].data.points) == len(s.scene) - n_sel
    bpy.ops.divas.select_all(action="SELECT")  # every remaining point, by hand
    assert int(s.selection.sum()) == len(s.scene) - n_sel
    bpy.ops.divas.session_finish_object(name="kept")
    exp = tmp_path / "objects"
    assert bpy.ops.divas.export_objects(directory=str(exp)) == {"FINISHED"}
    (kept,) = sorted(exp.glob("01_*.ply"))
    assert len(plyfile.PlyData.read(str(kept))["vertex"].data) == len(s.scene) - n_sel
    lab = plyfile.PlyData.read(str(exp / "labelled.ply"))["vertex"].data["divas_label"]
    assert (lab == 0).sum() == n_sel and (lab[s.edits.deleted] == 0).all()
    np.testing.assert_array_equal(
        bridge.read_attribute(bpy.data.objects[name].data, LABEL_ATTRIBUTE),
        np.ones(len(s.scene) - n_sel, np.int32),
    )


def test_gesture_modal_box_brush_cancel(grid_ply):
    """The drawing modal driven with stand-in events (headless has no 3D view): a Shift
    box extends, a Ctrl brush stroke subtracts while dragging and is one undo step, an
    Esc mid-stroke puts the selection back."""
    from types import SimpleNamespace

    from blender_addon.modal_logic import Gesture
    from blender_addon.operators.select_gesture import DIVAS_OT_select_gesture as Op

    name = _import(grid_ply)
    reports = []

    def harness(shape, radius=25.0):
        t = point_edits.edit_target(bpy.context)
        return SimpleNamespace(
            _region=SimpleNamespace(x=0, y=0, width=200, height=100),
            _rv3d=SimpleNamespace(perspective_matrix=VIEW),
            _area=SimpleNamespace(header_text_set=lambda *_: None, tag_redraw=lambda: None),
            _gesture=Gesture(shape, radius),
            _stroke=False,
            _target=t,
            _initial=point_edits.selected(t),
            _handle=None,
            report=lambda *a: reports.append(a),
        )

    def send(h, type_, value, x, y, shift=False, ctrl=False):
        h._finish = lambda r: Op._finish(h, r)  # the operator's own methods on the stand-in
        h._undo_stroke = lambda: Op._undo_stroke(h)
        ev = SimpleNamespace(type=type_, value=value, mouse_x=x, mouse_y=y, shift=shift, ctrl=ctrl)
        return Op.modal(h, bpy.context, ev)

    h = harness("BOX")
    assert send(h, "LEFTMOUSE", "PRESS", 50, 25) == {"RUNNING_MODAL"}
    send(h, "MOUSEMOVE", "NOTHING", 110, 55)
    assert send(h, "LEFTMOUSE", "RELEASE", 110, 55) == {"FINISHED"}
    assert _sel(name) == [6, 7, 11, 12]
    h = harness("BOX")
    send(h, "LEFTMOUSE", "PRESS", 0, 0, shift=True)
    send(h, "MOUSEMOVE", "NOTHING", 200, 15)
    send(h, "LEFTMOUSE", "RELEASE", 200, 15)
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 7, 11, 12]  # extended by the bottom row
    # a brush stroke (Ctrl: subtract) over (60, 30) then (100, 30), radius 5 px
    h = harness("CIRCLE", 5.0)
    send(h, "LEFTMOUSE", "PRESS", 60, 30, ctrl=True)
    assert _sel(name) == [0, 1, 2, 3, 4, 7, 11, 12]  # 6 gone while dragging
    send(h, "MOUSEMOVE", "NOTHING", 100, 30)
    assert send(h, "LEFTMOUSE", "RELEASE", 100, 30) == {"FINISHED"}
    assert _sel(name) == [0, 1, 2, 3, 4, 11, 12]
    bpy.ops.ed.undo()  # the whole stroke is one step
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 7, 11, 12]
    # Esc mid-stroke: back to the selection before the stroke
    h = harness("CIRCLE", 5.0)
    send(h, "LEFTMOUSE", "PRESS", 20, 10, ctrl=True)
    assert 0 not in _sel(name)
    assert send(h, "ESC", "PRESS", 20, 10) == {"CANCELLED"}
    assert _sel(name) == [0, 1, 2, 3, 4, 6, 7, 11, 12]
    assert reports == []
