"""Camera import: for every created camera, Blender's ``world_to_camera_view`` of random
3D points equals the engine's projection within 0.5 px (with that camera's own
resolution and pixel aspect applied). Points are made in the file's frame and placed in
the world through the frame the camera was imported in (the splats' axis
conversion, or the splat object it is parented to)."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from blender_addon import camera_objects
from divas_engine.blender_convention import axis_conversion
from divas_engine.camera import Camera
from divas_engine.io.cameras import load_cameras, save_cameras


def _bpy_pixels(scene, obj, pts: np.ndarray) -> np.ndarray:
    ndc = np.array([tuple(world_to_camera_view(scene, obj, Vector(p))) for p in pts])
    r = scene.render
    w = r.resolution_x * r.resolution_percentage // 100
    h = r.resolution_y * r.resolution_percentage // 100
    return np.stack([ndc[:, 0] * w, (1.0 - ndc[:, 1]) * h], -1)


def _check_all(objs, cams, seed=0):
    scene = bpy.context.scene
    rng = np.random.default_rng(seed)
    assert len(objs) == len(cams)
    for obj, cam in zip(objs, cams):
        camera_objects.apply_render_settings(scene, obj)
        assert scene.camera == obj
        uv = rng.uniform([0, 0], [cam.width, cam.height], (40, 2))
        pts = cam.unproject(uv, rng.uniform(0.5, 20.0, 40))
        frame = camera_objects.frame_of(obj)
        got = _bpy_pixels(scene, obj, pts @ frame[:3, :3].T + frame[:3, 3])
        err = np.abs(got - cam.project(pts)[0]).max()
        assert err < 0.5, f"{obj.name}: {err:.4f} px"
        back = camera_objects.engine_camera(scene, obj)
        np.testing.assert_allclose(
            [back.fx, back.fy, back.cx, back.cy],
            [cam.fx, cam.fy, cam.cx, cam.cy],
            rtol=1e-5,
            atol=1e-3,
        )
        assert (back.width, back.height) == (cam.width, cam.height)


def _varied_cameras() -> list[Camera]:
    rng = np.random.default_rng(3)
    specs = [
        (640, 480, 500, 500, 320, 240),
        (800, 600, 700, 650, 390.5, 310.25),
        (480, 640, 450, 530, 250, 300),
        (1024, 256, 900, 800, 500, 140),
    ]
    return [
        Camera.look_at(
            rng.normal(size=3) * 5,
            rng.normal(size=3) * 0.2,
            [0, 0, 1],
            width=w,
            height=h,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            name=f"img_{i:02d}.png",
        )
        for i, (w, h, fx, fy, cx, cy) in enumerate(specs)
    ]


def _imported():
    coll = bpy.data.collections["DivAS Cameras"]
    return list(coll.objects)


def test_import_cameras_json(ribs):
    path = ribs / "cameras.json"
    assert bpy.ops.divas.import_cameras(filepath=str(path)) == {"FINISHED"}
    cams = load_cameras(path)
    objs = _imported()
    assert [o.name for o in objs] == [c.name for c in cams]
    assert all(o.type == "CAMERA" for o in objs)
    assert bpy.context.scene.camera == objs[0]
    r = bpy.context.scene.render
    assert (r.resolution_x, r.resolution_y) == (cams[0].width, cams[0].height)
    _check_all(objs, cams)
    # default frame: COLMAP's (forward +Z, up -Y), the splat import's default convention
    conv = axis_conversion("Z", "-Y")
    for o, c in zip(objs, cams):
        np.testing.assert_allclose(camera_objects.frame_of(o)[:3, :3], conv)
        np.testing.assert_allclose(np.array(o.matrix_world.translation), conv @ c.center, atol=1e-5)


def test_cameras_parented_to_the_active_splats_follow_them(ribs):
    assert bpy.ops.divas.import_splats(filepath=str(ribs / "scene.ply")) == {"FINISHED"}
    splats = bpy.context.active_object
    splats.location = (1.0, -2.0, 0.5)
    splats.rotation_euler = (0.3, 0.1, -0.7)
    bpy.context.view_layer.update()
    assert bpy.ops.divas.import_cameras(filepath=str(ribs / "cameras.json")) == {"FINISHED"}
    cams = load_cameras(ribs / "cameras.json")
    objs = _imported()
    assert all(o.parent == splats for o in objs)
    _check_all(objs, cams)  # through the object's frame, and back to the file frame
    mw = np.array(splats.matrix_world)
    np.testing.assert_allclose(
        np.array(objs[0].matrix_world.translation), (mw @ [*cams[0].center, 1])[:3], atol=1e-5
    )
    back = camera_objects.engine_camera(bpy.context.scene, objs[0])
    np.testing.assert_allclose(back.c2w, cams[0].c2w, atol=1e-5)


@pytest.mark.parametrize("up", ["X", "Y", "Z", "-X", "-Y", "-Z"])
def test_axis_conversion_is_blenders(up):
    from bpy_extras.io_utils import axis_conversion as bpy_axis_conversion

    for fwd in ("X", "Y", "Z", "-X", "-Y", "-Z"):
        if fwd[-1] == up[-1]:
            continue
        ours = axis_conversion(fwd, up)
        theirs = np.array(bpy_axis_conversion(from_forward=fwd, from_up=up))
        np.testing.assert_allclose(ours, theirs, atol=1e-12, err_msg=f"{fwd} {up}")


@pytest.mark.parametrize("fmt", ["colmap", "colmap_text", "transforms_json"])
def test_import_varied_intrinsics(tmp_path, fmt):
    """Different sizes, fx ≠ fy (pixel aspect) and off-centre principal points (shift)."""
    cams = _varied_cameras()
    if fmt == "transforms_json":  # one set of intrinsics per file in the common layout
        cams = [cams[1].with_pose(c.c2w, c.name) for c in cams]
    target = tmp_path / ("transforms.json" if fmt == "transforms_json" else "model")
    written = save_cameras(target, cams, fmt=fmt)
    pick = written / "cameras.bin" if fmt == "colmap" else written
    if fmt == "colmap_text":
        pick = written / "images.txt"
    loaded = load_cameras(pick)
    assert bpy.ops.divas.import_cameras(filepath=str(pick)) == {"FINISHED"}
    objs = _imported()
    by_name = {o.name: o for o in objs}
    _check_all([by_name[c.name] for c in loaded], loaded, seed=1)


def test_per_camera_resolution_survives_scene_changes(tmp_path):
    cams = _varied_cameras()
    save_cameras(tmp_path / "cams", cams, fmt="colmap")
    bpy.ops.divas.import_cameras(filepath=str(tmp_path / "cams"))
    scene = bpy.context.scene
    objs = {o.name: o for o in _imported()}
    scene.render.resolution_x, scene.render.resolution_y = 111, 77  # user changes the scene
    for cam in cams:
        back = camera_objects.engine_camera(scene, objs[cam.name])
        assert (back.width, back.height) == (cam.width, cam.height)
        np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-5)


def test_activate_camera_operator(tmp_path):
    cams = _varied_cameras()
    save_cameras(tmp_path / "cams", cams, fmt="colmap")
    bpy.ops.divas.import_cameras(filepath=str(tmp_path / "cams"))
    obj = {o.name: o for o in _imported()}[cams[3].name]
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.divas.activate_camera() == {"FINISHED"}
    r = bpy.context.scene.render
    assert bpy.context.scene.camera == obj
    assert (r.resolution_x, r.resolution_y) == (1024, 256)
    assert r.pixel_aspect_x == pytest.approx(1.0) and r.pixel_aspect_y == pytest.approx(900 / 800)


def test_bad_camera_file(tmp_path):
    bad = tmp_path / "weird.json"
    bad.write_text('{"hello": 1}')
    with pytest.raises(RuntimeError, match="weird.json"):
        bpy.ops.divas.import_cameras(filepath=str(bad))
    assert "DivAS Cameras" not in bpy.data.collections
