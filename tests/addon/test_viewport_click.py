"""A click in a free 3D view. The view's camera is reconstructed from the
region's view and window matrices and size (given to the operator, as a 3D view would
give them; float32 like Blender's), the view becomes an anchor, and the click spawns the
same centroid view as the same click on the equivalent anchor camera — with the object
moved, rotated and scaled."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from bpy_extras import view3d_utils
from mathutils import Euler, Matrix, Vector

from blender_addon import session_registry
from blender_addon.preferences import get_preferences
from divas_engine.camera import Camera
from divas_engine.viewport import region_matrices

SCALE = 0.5
UNDO = ("EXEC_DEFAULT", True)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_viewport")
    sc = generate_scene("ribs", out, size=8000, seed=4, grid_resolution=24)
    return out, sc


def _start(scene_dir, matrix=None):
    out, _ = scene_dir
    bpy.ops.divas.import_splats(*UNDO, filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    if matrix is not None:
        obj.matrix_world = matrix
        bpy.context.view_layer.update()
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(
        *UNDO, segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy")
    ) == {"FINISHED"}
    return obj, session_registry.get(obj)


def _world_camera(obj, cam: Camera) -> Camera:
    """A scene-frame camera in the world (the object's rotation and uniform scale)."""
    m = np.array(obj.matrix_world, np.float64)
    c2w = m @ cam.c2w
    c2w[:3, :3] /= np.linalg.norm(c2w[:3, :3], axis=0, keepdims=True)
    return cam.with_pose(c2w)


def _region_click(live, k, sc):
    """A region pixel over the object in anchor ``k``'s full camera, and the anchor
    pixel at that pixel's centre."""
    a = live.session.anchors[k]
    full, work = a.full_camera, a.camera
    for c in sc.metadata["clicks"]:
        uv, z = full.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < full.width and 0 <= uv[0, 1] < full.height:
            mx, my = int(uv[0, 0]), int(full.height - uv[0, 1])
            xy = full.pixels_to(work, (mx + 0.5, full.height - (my + 0.5)))
            return (mx, my), (float(xy[0]), float(xy[1]))
    pytest.skip("no click point visible")


@pytest.mark.parametrize("moved", [False, True])
def test_viewport_click_equals_the_anchor_click(scene_dir, moved):
    out, sc = scene_dir
    m = None
    if moved:
        m = Matrix.LocRotScale(Vector((0.4, -0.3, 0.2)), Euler((0.3, -0.2, 0.5)), Vector([1.7] * 3))
    obj, live = _start(scene_dir, m)
    name, s, k = obj.name, live.session, 1
    (mx, my), xy = _region_click(live, k, sc)
    # the reference: the same click on anchor k
    assert bpy.ops.divas.session_click(*UNDO, anchor=k, xy=f"{xy[0]!r} {xy[1]!r}") == {"FINISHED"}
    ref = s.views[-1]
    assert bpy.ops.ed.undo() == {"FINISHED"}
    assert s.views == []
    # the same view, seen as a free 3D view of the anchor's full size
    full = s.anchors[k].full_camera
    world = _world_camera(bpy.data.objects[name], full)
    vm, wm = region_matrices(world, near=0.01, far=100.0)
    vm32, wm32 = vm.astype(np.float32), wm.astype(np.float32)
    # independent check of the matrices: Blender's own projection puts the clicked 3D
    # point where the engine's camera does
    region = type("R", (), {"width": full.width, "height": full.height})()
    rv3d = type("V", (), {"perspective_matrix": Matrix((wm @ vm).tolist()),
                          "is_perspective": True})()  # fmt: skip
    p_world = world.unproject(np.array([[mx + 0.5, full.height - my - 0.5]]), [2.0])[0]
    reg = view3d_utils.location_3d_to_region_2d(region, rv3d, Vector(p_world))
    assert (reg.x, reg.y) == pytest.approx((mx + 0.5, my + 0.5), abs=1e-3)
    assert bpy.ops.divas.session_viewport_click(
        *UNDO,
        view_matrix=vm32.ravel(),
        window_matrix=wm32.ravel(),
        region_size=(full.width, full.height),
        mouse=(mx, my),
    ) == {"FINISHED"}
    a = s.anchors[-1]
    assert a.source == "viewport" and len(s.anchors) == len(live.anchor_cameras)
    assert (a.camera.width, a.camera.height) == (s.anchors[k].camera.width,
                                                 s.anchors[k].camera.height)  # fmt: skip
    np.testing.assert_allclose(a.camera.c2w, s.anchors[k].camera.c2w, atol=2e-5)
    np.testing.assert_allclose(
        [a.camera.fx, a.camera.fy, a.camera.cx, a.camera.cy],
        [s.anchors[k].camera.fx, s.anchors[k].camera.fy, s.anchors[k].camera.cx,
         s.anchors[k].camera.cy], rtol=1e-5)  # fmt: skip
    got = s.views[-1]
    c0, c1 = ref.centroid, got.centroid
    assert c1.click == pytest.approx(c0.click, abs=1e-4)
    np.testing.assert_allclose(c1.target, c0.target, atol=1e-4)
    assert c1.d_cam == pytest.approx(c0.d_cam, rel=1e-4)
    np.testing.assert_allclose(c1.camera.c2w, c0.camera.c2w, atol=1e-4)
    assert (c1.camera.width, c1.camera.fx) == (c0.camera.width, pytest.approx(c0.camera.fx))
    # the mask previews agree (the same view, segmented the same way)
    m0, m1 = ref.preview.mask > 0.5, got.preview.mask > 0.5
    assert (m0 & m1).sum() / max((m0 | m1).sum(), 1) > 0.99


def test_viewport_anchor_follows_the_anchor_resolution(scene_dir):
    get_preferences().anchor_resolution = 200
    obj, live = _start(scene_dir)
    s = live.session
    assert all(max(a.camera.width, a.camera.height) == 200 for a in s.anchors)
    cam = Camera.look_at([0, -4, 1], [0, 0, 0], [0, 0, 1], width=900, height=500, fx=700)
    vm, wm = region_matrices(cam)
    for _ in range(2):  # the same view twice: one anchor
        assert bpy.ops.divas.session_viewport_click(
            view_matrix=vm.ravel(), window_matrix=wm.ravel(), region_size=(900, 500),
            mouse=(450, 250)) == {"FINISHED"}  # fmt: skip
    assert sum(a.source == "viewport" for a in s.anchors) == 1
    a = s.anchors[-1]
    assert (a.camera.width, a.camera.height) == (200, 111)
    assert a.camera.fx == pytest.approx(700 * 200 / 900)


def test_negative_click_in_a_free_view_removes_at_once(scene_dir):
    """A Shift-click (negative) in a free 3D view on the selection takes
    the spot out of the points' selection in the same step."""
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    s, k = live.session, 1
    (mx, my), xy = _region_click(live, k, sc)
    assert bpy.ops.divas.session_click(*UNDO, anchor=k, xy=f"{xy[0]!r} {xy[1]!r}") == {"FINISHED"}
    assert bpy.ops.divas.session_accept(*UNDO) == {"FINISHED"}
    before = s.selection.copy()
    world = _world_camera(bpy.data.objects[obj.name], s.anchors[k].full_camera)
    vm, wm = region_matrices(world, near=0.01, far=100.0)
    full = s.anchors[k].full_camera
    assert bpy.ops.divas.session_viewport_click(
        *UNDO,
        view_matrix=vm.astype(np.float32).ravel(),
        window_matrix=wm.astype(np.float32).ravel(),
        region_size=(full.width, full.height),
        mouse=(mx, my),
        positive=False,
    ) == {"FINISHED"}
    res = s.last_correction
    assert res.correction.positive is False and before[res.correction.patch].any()
    assert not s.selection[res.correction.patch].any()
    from blender_addon import bridge
    from divas_engine.point_attributes import INDEX, SELECTED, scene_selection

    geom = bpy.data.objects[obj.name].data
    mapped = scene_selection(
        s.scene, bridge.read_attribute(geom, INDEX), bridge.read_attribute(geom, SELECTED)
    )
    np.testing.assert_array_equal(mapped, s.selection)


def test_negative_click_no_view_sees_gets_a_camera(scene_dir):
    """A Shift-click on an anchor on a selected spot that no fused view shows fuses the
    click's own view (:mod:`divas_engine.session.negative_views`): the points'
    selection follows in the same step and the new view gets its camera."""
    from divas_engine.kinds import ViewStatus
    from divas_engine.session import negative_views

    out, sc = scene_dir
    obj, live = _start(scene_dir)
    s, k = live.session, 1
    _, xy = _region_click(live, k, sc)
    assert bpy.ops.divas.session_click(*UNDO, anchor=k, xy=f"{xy[0]!r} {xy[1]!r}") == {"FINISHED"}
    assert bpy.ops.divas.session_accept(*UNDO) == {"FINISHED"}
    # a pixel of another anchor on a selected surfel there whose point no view sees
    hit = None
    for j in (j for j in range(len(s.anchors)) if j != k):
        a = s.anchors[j]
        b = s.render(a)
        rows = np.flatnonzero(s.selection)
        uv, z = a.camera.project(s.scene.means[rows])
        for i in np.argsort(z):
            x, y = uv[i]
            if not (0 <= x < a.camera.width and 0 <= y < a.camera.height):
                continue
            d = float(b.D_med[int(y), int(x)])
            if d > 0 and abs(d - z[i]) < 0.01 * z[i]:
                p = a.camera.unproject(np.array([[x, y]]), np.array([d]))[0]
                if not negative_views.seen_by_a_view(s, p):
                    hit = (j, float(x), float(y))
                    break
        if hit is not None:
            break
    assert hit is not None, "every selected surfel on the anchors' surfaces is seen by the view"
    j, x, y = hit
    assert bpy.ops.divas.session_click(*UNDO, anchor=j, xy=f"{x!r} {y!r}", positive=False) == {
        "FINISHED"
    }
    res = s.last_correction
    v = res.view
    assert v is not None and v.status == ViewStatus.FUSED and res.views_changed == 1
    assert v.id in live.view_cameras and live.view_cameras[v.id] in bpy.data.objects
    from blender_addon import bridge
    from divas_engine.point_attributes import INDEX, SELECTED, scene_selection

    geom = bpy.data.objects[obj.name].data
    mapped = scene_selection(
        s.scene, bridge.read_attribute(geom, INDEX), bridge.read_attribute(geom, SELECTED)
    )
    np.testing.assert_array_equal(mapped, s.selection)
