"""The feedback drawn over the viewport. Headless Blender cannot draw
(the ``gpu`` module refuses in background mode), so these tests check what *would* be
drawn where: the items :mod:`blender_addon.draw` collects for a region looking through
a DivAS camera (mask preview over the camera frame, prompt markers on the clicked
pixels — checked against Blender's own projection of the clicked 3D point), for a free
view (nothing in region space; the selection tint, the clicked points and the preview
in 3D in world space), and the triangle / outline geometry handed to the GPU."""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import pytest
from bpy_extras import view3d_utils
from mathutils import Vector

from blender_addon import bridge, draw, handlers, overlays, session_registry
from blender_addon.modal_logic import Target
from blender_addon.session_actions import add_prompt
from blender_addon.view3d import camera_frame_in_region
from divas_engine.point_attributes import SELECTED

SCALE = 0.5


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_draw")
    sc = generate_scene("ribs", out, size=8000, seed=6, grid_resolution=24)
    return out, sc


def _start(scene_dir):
    out, _ = scene_dir
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"))
    obj = bpy.context.active_object
    obj.location = (0.3, 0.1, -0.2)  # world ≠ scene frame
    bpy.context.scene.divas.render_scale = SCALE
    bpy.context.scene.divas.autosave = False
    bpy.ops.divas.start_session(segmenter="oracle", device="cpu", gt_labels=str(out / "labels.npy"))
    return obj, session_registry.get(obj)


def _click(live, i, sc):
    cam = live.session.anchors[i].camera
    for c in sc.metadata["clicks"]:
        uv, z = cam.project(np.array([c["xyz"]]))
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            xy = f"{float(uv[0, 0])!r} {float(uv[0, 1])!r}"
            assert bpy.ops.divas.session_click(anchor=i, xy=xy) == {"FINISHED"}
            return np.array(c["xyz"])
    pytest.skip("no click point visible")


def _looking_through(cam_obj, width, height, perspective="CAMERA"):
    """A stand-in context: a region of the camera's render size whose view is exactly
    the camera's projection (what a 3D view in camera view at zoom 1 would hold)."""
    scene = bpy.context.scene
    bpy.context.view_layer.update()
    r = scene.render
    proj = cam_obj.calc_matrix_camera(
        bpy.context.evaluated_depsgraph_get(),
        x=r.resolution_x,
        y=r.resolution_y,
        scale_x=r.pixel_aspect_x,
        scale_y=r.pixel_aspect_y,
    )
    pm = proj @ cam_obj.matrix_world.normalized().inverted()
    region = SimpleNamespace(width=width, height=height, type="WINDOW")
    rv3d = SimpleNamespace(perspective_matrix=pm, is_perspective=True, view_perspective=perspective)
    return SimpleNamespace(
        region=region, region_data=rv3d, scene=scene, preferences=bpy.context.preferences
    )


def test_handlers_are_registered():
    assert len(draw._handles) == 2  # POST_VIEW and POST_PIXEL, on SpaceView3D
    for name in ("undo_post", "redo_post", "save_post", "save_pre", "load_post", "load_pre"):
        assert any(getattr(f, "__module__", "").startswith("blender_addon") for f in
                   getattr(bpy.app.handlers, name)), name  # fmt: skip
    assert handlers.on_undo_redo in bpy.app.handlers.undo_post


def test_pixel_items_over_a_view_camera(scene_dir):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    _click(live, 0, sc)
    s = live.session
    v = s.views[-1]
    cam = bpy.context.scene.camera
    ctx = _looking_through(cam, v.camera.width, v.camera.height)
    items = draw.pixel_items(ctx)
    quads = [it for it in items if isinstance(it, overlays.ImageQuad)]
    markers = [it for it in items if isinstance(it, overlays.Markers)]
    assert len(quads) == 1 and len(markers) == 1
    # the mask preview fills the camera frame (here the whole region), blue, alpha ∝ mask
    frame = camera_frame_in_region(ctx.region, ctx.region_data, ctx.scene, cam)
    np.testing.assert_allclose(quads[0].corners, frame)
    w, h = v.camera.width, v.camera.height
    np.testing.assert_allclose(frame, [(w, h), (w, 0), (0, 0), (0, h)], atol=1e-3)
    rgba = quads[0].rgba
    np.testing.assert_allclose(rgba[..., 3], overlays.PREVIEW_ALPHA * np.clip(v.preview.mask, 0, 1))
    np.testing.assert_allclose(rgba[0, 0, :3], overlays.PREVIEW_COLOR)
    # the default prompt's marker sits where Blender projects the clicked 3D point
    world = np.array(obj.matrix_world) @ np.r_[v.centroid.target, 1.0]
    reg = view3d_utils.location_3d_to_region_2d(ctx.region, ctx.region_data, Vector(world[:3]))
    assert markers[0].xy[0] == pytest.approx((reg.x, reg.y), abs=0.05)
    assert tuple(markers[0].colors[0][:3]) == pytest.approx(overlays.POSITIVE_COLOR)
    # a negative point added on the view: a red marker at its pixel (y flipped)
    add_prompt(bpy.context, obj, live, v.id, (10.5, 20.5), positive=False)  # the modal's step
    m = [it for it in draw.pixel_items(ctx) if isinstance(it, overlays.Markers)][0]
    assert m.xy[-1] == pytest.approx((10.5, h - 20.5), abs=1e-3)  # float32 matrices
    assert tuple(m.colors[-1][:3]) == pytest.approx(overlays.NEGATIVE_COLOR)
    # the engine render under it, when the preference asks
    bpy.context.preferences.addons["blender_addon"].preferences.show_render = True
    quads = [it for it in draw.pixel_items(ctx) if isinstance(it, overlays.ImageQuad)]
    bpy.context.preferences.addons["blender_addon"].preferences.show_render = False
    assert len(quads) == 2 and np.allclose(quads[0].rgba[..., :3], v.rgb)
    # a free view (not through the camera): nothing in region space
    assert draw.pixel_items(_looking_through(cam, w, h, perspective="PERSP")) == []


def test_pixel_items_over_an_anchor_and_view_items(scene_dir):
    out, sc = scene_dir
    obj, live = _start(scene_dir)
    s = live.session
    _click(live, 0, sc)
    bpy.ops.divas.session_accept()
    anchor_cam = bpy.context.scene.camera
    assert anchor_cam.name == live.anchor_cameras[0]
    a = s.anchors[0]
    ctx = _looking_through(anchor_cam, 2 * a.camera.width, 2 * a.camera.height)
    (m,) = [it for it in draw.pixel_items(ctx) if isinstance(it, overlays.Markers)]
    click = s.current.clicks[0][0]
    assert m.xy[0] == pytest.approx((2 * click.xy[0], 2 * (a.camera.height - click.xy[1])))
    # world-space items: the selection tint is exactly the selected points, in object
    # space with the object's matrix; the clicked point as a marker
    items = draw.view_items(bpy.context)
    tint = [it for mw, it in items if it.key[-1] == "tint"]
    assert len(tint) == 1
    pos = bridge.read_attribute(obj.data, "position")
    sel = bridge.read_attribute(obj.data, SELECTED)
    np.testing.assert_allclose(tint[0].positions, pos[sel])
    assert all(np.allclose(mw, np.array(obj.matrix_world)) for mw, _ in items)
    clicks = [it for _, it in items if it.key[0] == "clicks"]
    np.testing.assert_allclose(clicks[0].positions, [click.point], atol=1e-6)
    # an open view with a preview: its mask's points on the surface, in 3D (blue)
    _click(live, 1, sc)
    prev = [it for _, it in draw.view_items(bpy.context) if it.key[0] == "preview"]
    assert len(prev) == 1 and len(prev[0].positions) > 10
    # cached: the same objects until something changes
    again = draw.view_items(bpy.context)
    assert [id(it.positions) for _, it in again if it.key[0] == "preview"] == [
        id(prev[0].positions)
    ]
    # no tint while the preference is off
    bpy.context.preferences.addons["blender_addon"].preferences.show_selection = False
    assert not [it for _, it in draw.view_items(bpy.context) if it.key[-1] == "tint"]
    bpy.context.preferences.addons["blender_addon"].preferences.show_selection = True


def test_gpu_geometry():
    mk = overlays.Markers(np.array([[10.0, 20.0], [50.0, 5.0]]),
                          np.array([[0, 1, 0, 1], [1, 0, 0, 1]], np.float32), 4.0)  # fmt: skip
    pos, col = overlays.disc_triangles(mk, segments=8)
    assert pos.shape == (2 * 2 * 8 * 3, 2) and col.shape == (len(pos), 4)
    first = pos[: 2 * 8 * 3]
    assert np.linalg.norm(first - [10, 20], axis=1).max() <= 4.0 + 1.5 + 1e-4
    assert (col[2 * 8 * 3 - 1] == [0, 1, 0, 1]).all()  # the disc after its rim
    box = overlays.gesture_outline("BOX", [(1, 2), (5, 7)], 0)
    assert box.tolist() == [[1, 2], [5, 2], [5, 7], [1, 7]]
    ring = overlays.gesture_outline("CIRCLE", [(10, 10)], 3.0, segments=12)
    np.testing.assert_allclose(np.linalg.norm(ring - [10, 10], axis=1), 3.0, rtol=1e-6)
    rows = overlays.texture_rows(np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4))
    assert rows[:4].tolist() == [12, 13, 14, 15]  # bottom image row first
    quad = overlays.camera_items(
        SimpleNamespace(session=SimpleNamespace(anchors=[]), coverage={}),
        Target(),
        np.zeros((4, 2)),
    )
    assert quad == []
