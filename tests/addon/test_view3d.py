"""Click → camera pixel through Blender's own frame and projection (a stand-in region:
headless Blender has no 3D viewport, so the region/rv3d pair a viewport looking through
the camera would have is built from the camera's projection matrix)."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from bpy_extras import view3d_utils
from mathutils import Matrix, Vector

from blender_addon import camera_objects
from blender_addon.view3d import camera_frame_in_region, click_to_camera_pixel
from divas_engine.camera import Camera


class FakeRegion:
    def __init__(self, width, height):
        self.width, self.height = width, height


class FakeRV3D:
    def __init__(self, perspective_matrix):
        self.perspective_matrix = perspective_matrix
        self.is_perspective = True


def _setup(cam: Camera):
    scene = bpy.context.scene
    obj = camera_objects.create_camera_object(cam, scene.collection)
    camera_objects.apply_render_settings(scene, obj)
    r = scene.render
    proj = obj.calc_matrix_camera(
        bpy.context.evaluated_depsgraph_get(),
        x=r.resolution_x,
        y=r.resolution_y,
        scale_x=r.pixel_aspect_x,
        scale_y=r.pixel_aspect_y,
    )
    return scene, obj, proj @ obj.matrix_world.normalized().inverted()


@pytest.mark.parametrize(
    "spec",
    [
        (640, 480, 500, 500, 320, 240),
        (800, 600, 700, 650, 390.5, 310.25),
        (480, 640, 450, 530, 250, 300),
    ],
)
@pytest.mark.parametrize("letterbox", [False, True])
def test_click_lands_on_projected_pixel(spec, letterbox):
    w, h, fx, fy, cx, cy = spec
    rng = np.random.default_rng(0)
    cam = Camera.look_at(
        rng.normal(size=3) * 4,
        np.zeros(3),
        [0, 0, 1],
        width=w,
        height=h,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
    )
    scene, obj, pm = _setup(cam)
    disp_w, disp_h = w * scene.render.pixel_aspect_x, h * scene.render.pixel_aspect_y
    if letterbox:  # region twice as wide as the frame, frame centred: squeeze NDC x by half
        region = FakeRegion(round(2 * disp_w / 2), round(disp_h / 2))
        pm = Matrix.Diagonal((0.5, 1.0, 1.0, 1.0)) @ pm
    else:
        region = FakeRegion(round(disp_w / 2), round(disp_h / 2))
    rv3d = FakeRV3D(pm)
    frame = camera_frame_in_region(region, rv3d, scene, obj)
    x0 = region.width / 4 if letterbox else 0.0
    x1 = 3 * region.width / 4 if letterbox else region.width
    np.testing.assert_allclose(
        frame, [(x1, region.height), (x1, 0), (x0, 0), (x0, region.height)], atol=1e-3
    )
    # a 3D point's region position, clicked at that region pixel, gives its camera pixel
    uv = rng.uniform([0.05 * w, 0.05 * h], [0.95 * w, 0.95 * h], (30, 2))
    pts = cam.unproject(uv, rng.uniform(1.0, 10.0, 30))
    for p, expect in zip(pts, uv):
        reg = view3d_utils.location_3d_to_region_2d(region, rv3d, Vector(p))
        mouse = (int(np.floor(reg.x)), int(np.floor(reg.y)))
        got = click_to_camera_pixel(region, rv3d, scene, obj, mouse)
        # the click is quantised to a region pixel: 1 region px = 2 image px (x: /aspect)
        tol = 2.0 * max(1.0, 1.0 / scene.render.pixel_aspect_x) + 1e-3
        assert got is not None and np.abs(np.array(got) - expect).max() <= tol
    if letterbox:
        assert click_to_camera_pixel(region, rv3d, scene, obj, (2, region.height // 2)) is None
