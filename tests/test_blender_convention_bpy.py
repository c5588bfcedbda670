"""Cross-check of :mod:`divas_engine.blender_convention` against real Blender (``bpy``).

A camera object is built in ``bpy`` from :func:`camera_to_blender`, and
``bpy_extras.object_utils.world_to_camera_view`` is compared with the engine's
``Camera.project`` (and the NumPy twin) for random points; reading the settings back
from ``bpy`` through :func:`camera_from_blender` must give the camera again.
"""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.blender_convention import (
    BlenderCameraParams,
    camera_from_blender,
    camera_to_blender,
    project_blender,
)
from divas_engine.camera import Camera

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

# (width, height, fx, fy, cx, cy): square pixels, fx≠fy both ways, off-centre principal
# points, landscape, portrait, and a case where pixel aspect flips the fitted side
SPECS = [
    (640, 480, 500, 500, 320, 240),
    (640, 480, 520, 480, 300.5, 250.25),
    (480, 640, 450, 530, 250, 300),
    (300, 900, 400, 700, 120, 500),
    (1000, 900, 800, 600, 480, 530),
    (900, 1000, 500, 800, 470, 520),
]


@pytest.fixture(scope="module")
def scene_and_camera():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    data = bpy.data.cameras.new("divas_test_cam")
    obj = bpy.data.objects.new("divas_test_cam", data)
    scene.collection.objects.link(obj)
    return scene, obj


def _apply(scene, obj, p: BlenderCameraParams) -> None:
    d = obj.data
    d.type = "PERSP"
    d.lens, d.sensor_width, d.sensor_height = p.lens_mm, p.sensor_width_mm, p.sensor_height_mm
    d.sensor_fit, d.shift_x, d.shift_y = p.sensor_fit, p.shift_x, p.shift_y
    r = scene.render
    r.resolution_x, r.resolution_y = p.resolution_x, p.resolution_y
    r.resolution_percentage = p.resolution_percentage
    r.pixel_aspect_x, r.pixel_aspect_y = p.pixel_aspect_x, p.pixel_aspect_y
    obj.matrix_world = Matrix(p.matrix_world.tolist())


def _read_back(scene, obj) -> BlenderCameraParams:
    d, r = obj.data, scene.render
    return BlenderCameraParams(
        np.array(obj.matrix_world),
        d.lens,
        d.sensor_width,
        d.sensor_height,
        d.sensor_fit,
        d.shift_x,
        d.shift_y,
        r.resolution_x,
        r.resolution_y,
        r.pixel_aspect_x,
        r.pixel_aspect_y,
        r.resolution_percentage,
    )


def _bpy_project(scene, obj, pts: np.ndarray) -> np.ndarray:
    ndc = np.array([tuple(world_to_camera_view(scene, obj, Vector(q))) for q in pts])
    w = scene.render.resolution_x * scene.render.resolution_percentage // 100
    h = scene.render.resolution_y * scene.render.resolution_percentage // 100
    return np.stack([ndc[:, 0] * w, (1.0 - ndc[:, 1]) * h, ndc[:, 2]], -1)


@pytest.mark.parametrize("spec", SPECS)
def test_engine_camera_matches_bpy(scene_and_camera, spec):
    scene, obj = scene_and_camera
    w, h, fx, fy, cx, cy = spec
    rng = np.random.default_rng(SPECS.index(spec))
    cam = Camera.look_at(
        rng.normal(size=3) * 4,
        rng.normal(size=3) * 0.3,
        [0, 0, 1],
        width=w,
        height=h,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
    )
    p = camera_to_blender(cam)
    _apply(scene, obj, p)
    # random points in (and around) the frustum, at varied depths
    uv = rng.uniform([-0.25 * w, -0.25 * h], [1.25 * w, 1.25 * h], (64, 2))
    pts = cam.unproject(uv, rng.uniform(0.3, 25.0, 64))
    got = _bpy_project(scene, obj, pts)
    # Blender computes in float32: agreement is ~1e-4 px, far inside the 0.5 px budget
    np.testing.assert_allclose(got[:, :2], cam.project(pts)[0], atol=0.01)
    np.testing.assert_allclose(got[:, 2], cam.project(pts)[1], rtol=1e-5)
    np.testing.assert_allclose(project_blender(p, pts)[0], got[:, :2], atol=0.01)
    back = camera_from_blender(_read_back(scene, obj))  # settings as Blender stored them
    assert (back.width, back.height) == (w, h)
    np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [fx, fy, cx, cy], rtol=1e-5)
    np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-5)


@pytest.mark.parametrize(
    "fit,res,pct,shift",
    [
        ("AUTO", (500, 1000), 100, (0.1, -0.05)),
        ("AUTO", (1000, 500), 50, (-0.07, 0.12)),
        ("VERTICAL", (800, 600), 100, (0.2, 0.1)),
        ("HORIZONTAL", (600, 800), 100, (0.05, 0.3)),
    ],
)
def test_blender_settings_to_engine_camera(scene_and_camera, fit, res, pct, shift):
    """Arbitrary Blender settings (AUTO fit, portrait, percentage) read into the engine."""
    scene, obj = scene_and_camera
    rng = np.random.default_rng(5)
    cam0 = Camera.look_at(
        rng.normal(size=3) * 4, np.zeros(3), [0, 0, 1], width=10, height=10, fx=10
    )
    m = cam0.c2w @ np.diag([1.0, -1, -1, 1]) @ np.diag([1.5, 1.5, 1.5, 1])  # with object scale
    p = BlenderCameraParams(
        m,
        42.0,
        30.0,
        20.0,
        fit,
        shift[0],
        shift[1],
        res[0],
        res[1],
        pixel_aspect_x=1.0,
        pixel_aspect_y=1.3,
        resolution_percentage=pct,
    )
    _apply(scene, obj, p)
    cam = camera_from_blender(p)
    uv = rng.uniform([0, 0], [cam.width, cam.height], (64, 2))
    pts = cam.unproject(uv, rng.uniform(0.5, 10.0, 64))
    got = _bpy_project(scene, obj, pts)
    np.testing.assert_allclose(got[:, :2], uv, atol=0.01)
    np.testing.assert_allclose(project_blender(p, pts)[0], uv, atol=1e-6)
