"""Engine cameras ↔ Blender camera objects (the math is in ``divas_engine.blender_convention``).

Resolution and pixel aspect are *scene* settings in Blender, not camera settings, so
cameras of different image sizes cannot all be exact at once. Each camera object
created here stores its own ``divas_resolution`` (W, H) and ``divas_pixel_aspect``
(x, y) custom properties; :func:`apply_render_settings` copies them into
``scene.render`` when that camera becomes the active one (the "Look Through" operator
and the DivAS session do this), and :func:`engine_camera` always rebuilds the engine
camera from the camera's *own* stored size, whatever the scene currently holds.
Lens, sensor, fit and shift live on the camera data and are exact per camera.

Frames: a camera is made in the frame of the splats it belongs to — its
world matrix is ``frame @ pose``, with ``frame`` the splat import's axis conversion
(kept as the ``divas_frame`` custom property) or, for a camera parented to the splat
object, the object itself. :func:`engine_camera` undoes exactly that, so it always
returns the camera in the scene file's own frame, the one the engine works in.
"""

from __future__ import annotations

from dataclasses import replace

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
    "frame_of",
    "FRAME_PROP",
    "is_divas_camera",
]

RESOLUTION_PROP, PIXEL_ASPECT_PROP = "divas_resolution", "divas_pixel_aspect"
FRAME_PROP = "divas_frame"


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
    frame: np.ndarray | None = None,
) -> bpy.types.Object:
    """A Blender camera reproducing ``cam`` exactly (when its render settings are applied);
    ``frame``: the ``[4,4]`` axis conversion of the splats ``cam`` belongs to (module
    docstring)."""
    name = name or cam.name or "DivAS Camera"
    data = bpy.data.cameras.new(name)
    data.display_size = display_size
    data.clip_start, data.clip_end = clip
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    p = camera_to_blender(cam)
    if frame is not None:
        frame = np.asarray(frame, np.float64)
        p = replace(p, matrix_world=frame @ p.matrix_world)
        obj[FRAME_PROP] = frame.ravel().tolist()
    apply_params(obj, p)
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


def frame_of(obj: bpy.types.Object) -> np.ndarray:
    """``[4,4]`` world matrix of the frame ``obj`` was made in (module docstring): its
    parent's world matrix, else its ``divas_frame``, else the identity."""
    if obj.parent is not None:
        return np.array(obj.parent.matrix_world, np.float64) @ np.array(
            obj.matrix_parent_inverse, np.float64
        )
    if FRAME_PROP in obj:
        return np.asarray(obj[FRAME_PROP], np.float64).reshape(4, 4)
    return np.eye(4)


def engine_camera(scene: bpy.types.Scene, obj: bpy.types.Object) -> Camera:
    """The engine :class:`Camera` of a Blender camera object, in the frame of the splats
    it was made for (:func:`frame_of`)."""
    p = blender_params(scene, obj)
    p = replace(p, matrix_world=np.linalg.inv(frame_of(obj)) @ p.matrix_world)
    return camera_from_blender(p)
