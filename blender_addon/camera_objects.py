"""Engine cameras ↔ Blender camera objects (the math is in ``divas_engine.blender_convention``).

Resolution and pixel aspect are *scene* settings in Blender, not camera settings, so
cameras of different image sizes cannot all be exact at once. Each camera object
created here stores its own ``divas_resolution`` (W, H) and ``divas_pixel_aspect``
(x, y) custom properties; :func:`apply_render_settings` copies them into
``scene.render`` when that camera becomes the active one (the "Look Through" operator
and the DivAS session do this), and :func:`engine_camera` always rebuilds the engine
camera from the camera's *own* stored size, whatever the scene currently holds.
Lens, sensor, fit and shift live on the camera data and are exact per camera.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from divas_engine.blender_convention import (
    BlenderCameraParams,
    camera_from_blender,
    camera_to_blender,
)
from divas_engine.camera import Camera

__all__ = [
    "RESOLUTION_PROP",
    "PIXEL_ASPECT_PROP",
    "create_camera_object",
    "apply_params",
    "apply_render_settings",
    "blender_params",
    "engine_camera",
    "is_divas_camera",
]

RESOLUTION_PROP, PIXEL_ASPECT_PROP = "divas_resolution", "divas_pixel_aspect"


def apply_params(obj: bpy.types.Object, p: BlenderCameraParams) -> None:
    """Write lens, sensor, fit, shift and pose to ``obj``; size and aspect as custom props."""
    d = obj.data
    d.type, d.lens_unit = "PERSP", "MILLIMETERS"
    d.sensor_fit = p.sensor_fit
    d.sensor_width, d.sensor_height = p.sensor_width_mm, p.sensor_height_mm
    d.lens = p.lens_mm
    d.shift_x, d.shift_y = p.shift_x, p.shift_y
    obj.matrix_world = Matrix(p.matrix_world.tolist())
    obj[RESOLUTION_PROP] = [int(p.resolution_x), int(p.resolution_y)]
    obj[PIXEL_ASPECT_PROP] = [float(p.pixel_aspect_x), float(p.pixel_aspect_y)]


def create_camera_object(
    cam: Camera,
    collection,
    *,
    name: str | None = None,
    display_size: float = 0.25,
    clip: tuple[float, float] = (0.01, 1000.0),
) -> bpy.types.Object:
    """A Blender camera reproducing ``cam`` exactly (when its render settings are applied)."""
    name = name or cam.name or "DivAS Camera"
    data = bpy.data.cameras.new(name)
    data.display_size = display_size
    data.clip_start, data.clip_end = clip
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    apply_params(obj, camera_to_blender(cam))
    return obj


def is_divas_camera(obj) -> bool:
    return obj is not None and obj.type == "CAMERA" and RESOLUTION_PROP in obj


def apply_render_settings(scene: bpy.types.Scene, obj: bpy.types.Object) -> None:
    """Make ``obj`` the scene camera and set the render size/aspect it was made for."""
    scene.camera = obj
    if not is_divas_camera(obj):
        return
    r = scene.render
    r.resolution_x, r.resolution_y = (int(v) for v in obj[RESOLUTION_PROP])
    r.resolution_percentage = 100
    r.pixel_aspect_x, r.pixel_aspect_y = (float(v) for v in obj[PIXEL_ASPECT_PROP])


def blender_params(
    scene: bpy.types.Scene, obj: bpy.types.Object, *, own_resolution: bool = True
) -> BlenderCameraParams:
    """What Blender holds for ``obj``; with ``own_resolution`` the camera's stored size wins."""
    d, r = obj.data, scene.render
    res, pct = (r.resolution_x, r.resolution_y), r.resolution_percentage
    aspect = (r.pixel_aspect_x, r.pixel_aspect_y)
    if own_resolution and is_divas_camera(obj):
        res, pct, aspect = tuple(obj[RESOLUTION_PROP]), 100, tuple(obj[PIXEL_ASPECT_PROP])
    return BlenderCameraParams(
        np.array(obj.matrix_world),
        d.lens,
        d.sensor_width,
        d.sensor_height,
        d.sensor_fit,
        d.shift_x,
        d.shift_y,
        int(res[0]),
        int(res[1]),
        float(aspect[0]),
        float(aspect[1]),
        int(pct),
        obj.name,
    )


def engine_camera(scene: bpy.types.Scene, obj: bpy.types.Object) -> Camera:
    """The engine :class:`Camera` of a Blender camera object."""
    return camera_from_blender(blender_params(scene, obj))
